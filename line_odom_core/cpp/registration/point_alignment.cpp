#include "registration/point_alignment.hpp"

#include <Eigen/Cholesky>
#include <cmath>

#include "registration/refine.hpp"

namespace line_odom {

PointAlignment align_points(const VoxelPointMap& map, const std::vector<Vec3>& points,
                            const RigidTransform& initial_pose, double sigma, const PointAlignmentOptions& options) {
  PointAlignment out;
  out.pose = initial_pose;
  if (map.empty() || points.empty() || !(sigma > 0.0)) return out;
  const double max_distance = 3.0 * sigma;
  const double kernel = (sigma / 3.0) * (sigma / 3.0);  // m^2
  for (int it = 0; it < options.max_iterations; ++it) {
    Mat6 H = Mat6::Zero();
    Vec6 g = Vec6::Zero();
    int matched = 0;
    for (const Vec3& p : points) {
      const Vec3 q = out.pose.apply(p);
      Vec3 m;
      if (!map.nearest(q, max_distance, &m)) continue;
      const Vec3 r = q - m;
      const double d2 = r.squaredNorm();
      const double w = kernel * kernel / ((kernel + d2) * (kernel + d2));
      // d q / d xi for q' = exp(xi) q: [I, -[q]x]
      Eigen::Matrix<double, 3, 6> J;
      J.leftCols<3>().setIdentity();
      J.rightCols<3>() << 0.0, q.z(), -q.y(), -q.z(), 0.0, q.x(), q.y(), -q.x(), 0.0;
      H.noalias() += w * J.transpose() * J;
      g.noalias() += w * J.transpose() * r;
      ++matched;
    }
    out.matched = matched;
    out.information = H;
    out.iterations = it + 1;
    if (matched < 6) return out;
    const Vec6 step = -H.ldlt().solve(g);
    if (!step.allFinite()) return out;
    out.pose = se3_exp(step) * out.pose;
    if (step.norm() < options.convergence) {
      out.converged = true;
      break;
    }
  }
  return out;
}

void MotionModelError::add(const RigidTransform& predicted, const RigidTransform& registered) {
  if (registered.t.norm() < min_motion_) return;
  const RigidTransform deviation = predicted.inverse() * registered;
  const double theta = rotation_angle(deviation.R);
  const double d = deviation.t.norm() + 2.0 * std::sin(0.5 * theta) * range_;
  sum_ += d * d;
  ++count_;
}

double MotionModelError::sigma() const { return count_ > 0 ? std::sqrt(sum_ / count_) : initial_; }

}  // namespace line_odom
