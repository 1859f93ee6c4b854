// The candidate pairs a motion is estimated from (estimate_motion) and refined on (refine_motion).
#pragma once

#include <vector>

#include "common/types.hpp"

namespace line_odom {

// Row i of lines_a is a candidate intersection with row i of lines_b (frame a = previous, b = current).
struct Correspondences {
  std::vector<PluckerLine> lines_a, lines_b;
  std::vector<Segment> segments_a, segments_b;  // optional (empty or same size as lines): 7L uses them
  std::vector<double> weights;                  // optional: inlier weight per line pair (default 1)
  std::vector<int> clusters;                    // optional: normal cluster 0..2 of the pair (-1 = none)
  std::vector<int> lines_b_index;               // optional: which line of b (its V-lines, then its H-lines)
  std::vector<Plane> planes_a, planes_b;        // candidate plane correspondences
};

}  // namespace line_odom
