// Frame-to-frame motion from candidate line intersections and plane correspondences:
// hybrid RANSAC over {7L, 3L1P, 1L2P} (paper §6.3) with weighted inlier counting, then a robust
// least-squares refinement on all inliers that also yields the 6x6 covariance.
#pragma once

#include <array>
#include <cstdint>
#include <vector>

#include "common/types.hpp"
#include "registration/correspondences.hpp"
#include "solvers/solve_7l.hpp"

namespace line_odom {

enum class SolverMode { kAuto, k7L, k3L1P, k1L2P };

struct MotionOptions {
  SolverMode solver = SolverMode::kAuto;
  int max_iterations = 1000;          // RANSAC hypotheses per pass
  int min_iterations = 50;
  double confidence = 0.999;
  double inlier_threshold = 0.02;     // |signed line distance| in metres (2 cm KITTI, 5 mm TUM)
  double plane_angle_threshold_deg = 3.0;     // plane pair inlier: normal angle
  double plane_distance_threshold = 0.05;     // plane pair inlier: |delta_a - delta_b'|
  int refine_iterations = 10;
  double huber_delta = 0.0;           // 0: use inlier_threshold
  std::uint64_t seed = 0;
  int min_inliers = 10;               // success needs at least this many line-pair inliers after refinement
  double degeneracy_threshold = 1e-3;  // degenerate when the scaled J^T W J is worse conditioned than this
  bool local_optimisation = true;     // refine every new best hypothesis on its inliers (LO-RANSAC)
  bool pretest = true;                // score a random subset first and drop clearly worse hypotheses
  double min_inlier_contrast = 3.0;   // success needs inlier weight >= this * chance + 3 sqrt(chance), chance =
                                      // mean inlier weight of the estimate pushed 20 thresholds 8 generic ways
  Solve7LMethod solve_7l_method = Solve7LMethod::kGaussNewton;
  int solve_7l_max_iterations = 0;    // 0: 12 for Gauss-Newton (a good sample converges in < 8), 30000 for AP
};

struct MotionStats {
  int inliers = 0;
  double inlier_weight = 0.0;
  int plane_inliers = 0;
  int iterations = 0;
  std::array<int, 3> solver_counts{};  // hypotheses that won per solver: 7L, 3L1P, 1L2P
  int best_solver = -1;                // 0 = 7L, 1 = 3L1P, 2 = 1L2P, -2 = the incumbent, -1 = none
  Mat6 covariance = Mat6::Identity();  // order (x y z rx ry rz), REP-103; perturbation T = exp(xi) T_hat
  double residual_rms = 0.0;
  bool degenerate = false;             // refinement normal matrix badly conditioned
  bool success = false;                // what estimate_motion returned
  std::array<int, 3> solver_iterations{};  // samples drawn per solver: 7L, 3L1P, 1L2P
  int models = 0;                      // hypotheses scored
  double condition = 0.0;              // smallest / largest eigenvalue of the scaled J^T W J
  double perturbed_inlier_weight = 0.0;  // mean inlier weight of the 8 pushed estimates (chance agreement)
  int dropped_line_pairs = 0;          // non-finite or zero-direction lines, negative weights
  int dropped_plane_pairs = 0;         // non-finite or zero-normal planes
  std::vector<std::uint8_t> line_inlier_mask;   // per input line pair under the best motion found (1 = inlier)
  std::vector<std::uint8_t> plane_inlier_mask;  // per input plane pair
};

// Returns true and writes T_ab when a model with enough support was found. Never throws on bad geometry:
// insufficient or degenerate data returns false, writes T_ab = init and fills stats describing why.
// Pairs whose lines are closer to parallel than ~3 deg neither count as inliers nor enter the refinement.
// 7L without segments: each pair gets two 2 m segments centred on the points where the lines come closest
// under init. An `incumbent` motion (e.g. the refined prediction) is scored before any sample; when no sample
// beats it, the result is false with stats.best_solver -2 (the caller has the incumbent).
bool estimate_motion(const Correspondences& data, const RigidTransform& init, const MotionOptions& options,
                     RigidTransform* T_ab, MotionStats* stats, const RigidTransform* incumbent = nullptr);

}  // namespace line_odom
