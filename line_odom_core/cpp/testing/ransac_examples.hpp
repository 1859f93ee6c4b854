// Two small estimators over ransac.hpp, so the RANSAC loop itself can be tested with known answers
// (reached from Python through _testing.ransac_fit_line_2d and _testing.ransac_translation_2d):
//   generic form: a 2D line a x + b y + c = 0 (a^2 + b^2 = 1) from weighted points, sample size 2;
//   hybrid form:  a 2D translation t from two data types — point pairs (p_a = p_b + t) and scalar
//                 projections (u_i . t = o_i) — with two solvers: {1 pair, 0 projections} and {0, 2}.
#pragma once

#include <Eigen/Core>
#include <vector>

#include "registration/ransac.hpp"

namespace line_odom {

// weights empty = all 1. Returns false when no line was found.
bool ransac_fit_line_2d(const std::vector<Eigen::Vector2d>& points, const std::vector<double>& weights,
                        double threshold, const RansacOptions& options, Eigen::Vector3d* line, RansacStats* stats);

// Inliers: |p_a - p_b - t| < threshold, |u . t - o| < threshold; score = their count.
bool ransac_translation_2d(const std::vector<Eigen::Vector2d>& points_a, const std::vector<Eigen::Vector2d>& points_b,
                           const std::vector<Eigen::Vector2d>& directions, const std::vector<double>& projections,
                           double threshold, const RansacOptions& options, Eigen::Vector2d* t, RansacStats* stats);

}  // namespace line_odom
