// Candidate line intersections and plane correspondences between two scans under a motion guess
// (paper §6.3): H-lines of one frame against V-lines of the other whose segments come within a distance
// threshold once the current scan is moved by the guess; plane pairs with close normals and centroids near
// the other plane. Weights are the inverse size of the pair's normal cluster (1 for pairs without a normal).
#pragma once

#include <cstddef>
#include <limits>
#include <memory>
#include <vector>

#include "common/scan_features.hpp"
#include "common/types.hpp"
#include "registration/motion_estimation.hpp"

namespace line_odom {

class WorkerPool;

struct CandidateOptions {
  double max_distance = 2.0;           // segment-to-segment distance under the guess (2 m KITTI)
  double min_line_angle_deg = 10.0;    // skip near-parallel pairs: their intersection constrains little
  double max_normal_angle_deg = 30.0;  // both surface normals known: they must agree within this
  double plane_max_angle_deg = 20.0;   // plane pairs: normals within this
  double plane_max_distance = 2.0;     // plane pairs: centroid-to-other-plane distance
  int max_pairs_per_line = 0;          // keep only the closest k partners of each line (0 = all)
};

// The lines and planes of frame a that a search takes: all, or the first h_lines, v_lines and planes (a scan merged
// ahead of older ones, feature_window.hpp: that scan's own).
struct CandidateSubset {
  std::size_t h_lines = std::numeric_limits<std::size_t>::max();
  std::size_t v_lines = std::numeric_limits<std::size_t>::max();
  std::size_t planes = std::numeric_limits<std::size_t>::max();
};

struct CandidateStats {
  int line_pairs = 0;
  int plane_pairs = 0;
  std::array<int, 4> cluster_pairs{};  // pairs per normal cluster 0..2 and unknown (index 3)
};

// Closest distance between two 3D segments.
double segment_distance(const Segment& s1, const Segment& s2);

// The lines of frame a (the previous scan, never moved) indexed once for every pass matched against it: records,
// carriers, box columns, the segment grids the passes ask for (a grid is reused by any later pass that needs
// the same cells) and the lines listed near the current scan's. `a` must outlive the index, unchanged.
class CandidateIndex {
 public:
  explicit CandidateIndex(const ScanFeatures& a);
  ~CandidateIndex();
  CandidateIndex(const CandidateIndex&) = delete;
  CandidateIndex& operator=(const CandidateIndex&) = delete;

  struct Lines;  // one kind (H or V) of frame a's lines (candidates.cpp)

 private:
  friend void build_candidates(CandidateIndex&, const ScanFeatures&, const RigidTransform&, const CandidateOptions&,
                               Correspondences*, CandidateStats*, WorkerPool*, const CandidateSubset&);
  const ScanFeatures* a_;
  std::unique_ptr<Lines> h_, v_;
};

// Frame a = previous scan (indexed), b = current scan; T_ab_guess maps b into a. Fills `out` (line pairs with
// segments, weights and clusters; plane pairs) in a deterministic order, the same for a fresh or a reused index.
// Repeated calls with the same b object (unchanged in between, as in the passes of one frame) re-test the lines listed
// near each line of b by an earlier call while its guess moved the line less than the listing's margin: the same
// result.
// With a pool of several threads, the H x V and the V x H pairs are searched on two of them (the same result).
// `subset`: of frame a's lines and planes, only those (the pairs an index of that subset alone gives, listings shared).
void build_candidates(CandidateIndex& a, const ScanFeatures& b, const RigidTransform& T_ab_guess,
                      const CandidateOptions& options, Correspondences* out, CandidateStats* stats = nullptr,
                      WorkerPool* pool = nullptr, const CandidateSubset& subset = CandidateSubset{});

}  // namespace line_odom
