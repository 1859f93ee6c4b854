#include "registration/point_refine.hpp"

#include <Eigen/Cholesky>
#include <cmath>

#include "registration/refine.hpp"

namespace line_odom {

PointRefineResult refine_with_points(const SurfaceMap& scan, SurfaceMap& previous, const RigidTransform& T,
                                     const Mat6& covariance, const PointRefineOptions& options) {
  PointRefineResult out;
  out.T = T;
  if (previous.empty() || scan.empty()) return out;
  Eigen::LDLT<Mat6> lines_ldlt(covariance);
  if (lines_ldlt.info() != Eigen::Success || !covariance.allFinite()) return out;
  const Mat6 lines_information = lines_ldlt.solve(Mat6::Identity());
  Vec6 x = Vec6::Zero();  // apply_motion_difference(x, T)
  for (int it = 0; it < options.iterations; ++it) {
    const RigidTransform current = apply_motion_difference(x, T);
    Mat6 H = Mat6::Zero();
    Vec6 g = Vec6::Zero();
    int matched = 0;
    for (std::size_t i = 0; i < scan.size(); ++i) {
      if (scan.count(static_cast<int>(i)) < options.min_points) continue;  // a mean of a few points is noise
      PlaneResidual res;
      if (!previous.residual(current.apply(scan.mean(static_cast<int>(i))), options.min_points, options.min_planarity,
                             &res))
        continue;
      const double w = huber_weight(std::abs(res.r), options.huber);
      H.noalias() += w * res.J * res.J.transpose();
      g.noalias() += (w * res.r) * res.J;
      ++matched;
    }
    out.matched = matched;
    // The lines' term x' C^-1 x in the accumulated perturbation: its gradient C^-1 x (x and a step compose to
    // first order additively).
    const Mat6 A = lines_information + options.weight * H;
    const Vec6 b = -(options.weight * g + lines_information * x);
    const Vec6 step = A.ldlt().solve(b);
    if (!step.allFinite()) return out;
    x += step;
    if (step.head<3>().norm() < 1e-6 && step.tail<3>().norm() < 1e-7) break;
  }
  if (x.head<3>().norm() > options.max_translation || x.tail<3>().norm() > options.max_rotation_deg * kPi / 180.0)
    return out;  // too far from the lines' estimate
  out.T = apply_motion_difference(x, T);
  out.applied = out.T.is_finite();
  return out;
}

}  // namespace line_odom
