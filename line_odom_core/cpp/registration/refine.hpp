// Robust least-squares refinement of T_ab on all inlier line intersections and plane pairs (the local
// optimisation of paper §6.3 and the final estimate), on SE(3) with a left perturbation T = exp(xi) T_hat,
// xi = (x y z rx ry rz). Residuals, all in metres:
//   line pair:  signed distance between l_a and T l_b (docs/DESIGN.md §3),
//   plane pair: (n_a - R n_b) * line_threshold / plane_angle_threshold and
//               (delta_a - delta_b') * line_threshold / plane_distance_threshold,
// so a residual at its own threshold weighs like a line residual at the line threshold. Huber IRLS times the
// pair weight; covariance = sigma^2 (J^T W J)^-1 with sigma^2 from the weighted residuals.
#pragma once

#include <array>

#include "common/types.hpp"
#include "registration/correspondences.hpp"
#include "registration/line_pair_table.hpp"

namespace line_odom {

struct MotionStats;  // registration/motion_estimation.hpp

struct RefineOptions {
  int iterations = 10;
  double line_threshold = 0.02;                 // inlier gate: |signed line distance| (m)
  double plane_angle_threshold = 0.0523598776;  // inlier gate: normal angle (rad)
  double plane_distance_threshold = 0.05;       // inlier gate: |delta_a - delta_b'| (m)
  double huber_delta = 0.02;                    // Huber knee on the (metre) residuals
  double min_line_sine = 0.05;                  // pairs closer to parallel give no constraint
  double degeneracy_threshold = 1e-3;           // smallest / largest eigenvalue of the scaled J^T W J
  bool compute_covariance = true;
};

struct RefineResult {
  RigidTransform T;
  Mat6 covariance = Mat6::Identity();
  int line_inliers = 0;
  double line_inlier_weight = 0.0;
  int plane_inliers = 0;
  double residual_rms = 0.0;  // RMS signed line distance over the line inliers (m)
  double condition = 0.0;     // smallest / largest eigenvalue of J^T W J with rotations scaled to metres
  bool degenerate = true;
  int iterations = 0;
  int locked_directions = 0;  // refine_motion_partial: directions held at the prior (covariance zero along them)
  Mat6 locked_basis = Mat6::Zero();  // ... as unit columns 0..locked_directions-1 in xi coordinates
  // ... and how the result moves when the prior does: d xi_result = held_sensitivity * d xi_prior (the held
  // components follow the prior, the free ones their least-squares coupling to them); zero without locking.
  Mat6 held_sensitivity = Mat6::Zero();
};

// IRLS weight of a residual of size r_abs under a Huber loss with knee delta.
inline double huber_weight(double r_abs, double delta) { return r_abs <= delta ? 1.0 : delta / r_abs; }

// Motion of a left perturbation: exp(xi) as a rigid transform, xi = (v, w).
RigidTransform se3_exp(const Vec6& xi);

// Plane inlier test under T (same gates as the refinement; line pairs: LinePairTable::inlier_mask).
bool plane_pair_is_inlier(const Plane& a, const Plane& b_moved, double angle_threshold, double distance_threshold);

// The refinement's support and quality into motion statistics (inliers, weights, rms, condition, degenerate;
// not the covariance, which callers take only from a successful refinement).
void copy_refinement_stats(const RefineResult& refined, MotionStats* stats);

// Largest share of the inlier weight at T that survives a push along a single axis of xi: the translations by
// 20 thresholds, the rotations by the angle that moves the inlier lines as far. Near 1: the intersections do
// not observe that motion (pairs on planes parallel to it, e.g. an endless corridor), however well-conditioned
// the coincidental pairs make J^T W J look. `pair_share` (optional) gets the same for the share of inlier
// pairs, each counted once: the cluster weights can give a handful of pairs without a normal cluster a third of
// the weight, so a few coincidental pairs (two planes' seam) would otherwise pass for an observed axis.
// `per_axis` (optional) gets both shares for each axis (the larger of its two signs).
struct AxisShares {
  std::array<double, 6> weight{}, pairs{};
};
double axis_support(const LinePairTable& pairs, const RigidTransform& T, double threshold, double min_sine,
                    double* pair_share = nullptr, AxisShares* per_axis = nullptr);

// Gauss-Newton / IRLS from T0 over the pairs that are inliers at each iterate: the line pairs of `data` as
// tabled in `pairs`, its planes from `data`. Returns false (result->T = T0) when fewer residuals than unknowns
// remain or a step is not finite; never writes NaN.
bool refine_motion(const Correspondences& data, const LinePairTable& pairs, const RigidTransform& T0,
                   const RefineOptions& options, RefineResult* result);

// Partial refinement for a motion the pairs observe only in part (solution remapping: Zhang, Kaess, Singh, "On
// degeneracy of optimization-based state estimation problems", ICRA 2016): the axes in `locked_axes` (bit k: xi[k])
// and, with lock_weak, the eigen-directions of the scaled J^T W J at T_from under options.degeneracy_threshold of
// its largest stay at `prior`; the other directions start from T_from and are refined. The covariance is zero
// along the locked directions (the refinement says nothing there: the caller supplies what the prior knows);
// the prior's error reaches the free directions through held_sensitivity.
// Returns false when nothing (or everything) would be locked.
// `locked_projector` (nullable): also lock the directions of this projector (xi coordinates).
bool refine_motion_partial(const Correspondences& data, const LinePairTable& pairs, const RigidTransform& T_from,
                           const RigidTransform& prior, int locked_axes, bool lock_weak, const RefineOptions& options,
                           RefineResult* result, const Mat6* locked_projector = nullptr);

// T = step * reference with step = (rotation vector, translation) xi = (t, r): the chart the motion prior uses.
Vec6 motion_difference(const RigidTransform& T, const RigidTransform& reference);
RigidTransform apply_motion_difference(const Vec6& xi, const RigidTransform& reference);

}  // namespace line_odom
