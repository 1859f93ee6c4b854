#include "validation/point_evidence.hpp"

#include <Eigen/Cholesky>
#include <algorithm>
#include <cmath>

#include "registration/refine.hpp"

namespace line_odom {

PointSupport point_support(SurfaceMap& map, const std::vector<Vec3>& points, const RigidTransform& T,
                           const EvidenceOptions& options) {
  PointSupport out;
  out.T = T;
  out.inlier.assign(points.size(), 0);
  out.normal.assign(points.size(), Vec3::Zero());
  double squares = 0.0;
  for (std::size_t i = 0; i < points.size(); ++i) {
    PlaneResidual res;
    if (!map.residual(T.apply(points[i]), options.min_points, options.min_planarity, &res)) continue;
    ++out.matched;
    out.normal[i] = res.normal;
    if (std::abs(res.r) > options.inlier_distance) continue;
    ++out.inliers;
    out.inlier[i] = 1;
    squares += res.r * res.r;
    out.information.noalias() += res.J * res.J.transpose();
  }
  out.rms = out.inliers > 0 ? std::sqrt(squares / out.inliers) : 0.0;
  return out;
}

PointSupport fit_points(SurfaceMap& map, const std::vector<Vec3>& points, const RigidTransform& start,
                        const EvidenceOptions& options) {
  RigidTransform T = start;
  for (int it = 0; it < options.iterations; ++it) {
    Mat6 H = Mat6::Zero();
    Vec6 g = Vec6::Zero();
    for (const Vec3& p : points) {
      PlaneResidual res;
      if (!map.residual(T.apply(p), options.min_points, options.min_planarity, &res)) continue;
      const double w = huber_weight(std::abs(res.r), options.inlier_distance);
      H.noalias() += w * res.J * res.J.transpose();
      g.noalias() += (w * res.r) * res.J;
    }
    // Levenberg damping relative to the strongest direction: one the planes leave open does not move.
    const double damping = 1e-6 * H.diagonal().maxCoeff() + 1e-9;
    const Vec6 step = -(H + damping * Mat6::Identity()).ldlt().solve(g);
    if (!step.allFinite()) break;
    T = apply_motion_difference(step, T);
    if (step.head<3>().norm() < 1e-5 && step.tail<3>().norm() < 1e-6) break;
  }
  return point_support(map, points, T, options);
}

double support_gain(const std::vector<Vec3>& points, const PointSupport& a, const PointSupport& b) {
  constexpr double kFacing = 0.5;  // cos 60 deg
  int only_a = 0, only_b = 0;
  const std::size_t n = std::min({points.size(), a.inlier.size(), b.inlier.size()});
  for (std::size_t i = 0; i < n; ++i) {
    if (a.inlier[i] == b.inlier[i]) continue;
    const Vec3 d = b.T.apply(points[i]) - a.T.apply(points[i]);
    const double reach = kFacing * d.norm();
    if (!(std::abs(a.normal[i].dot(d)) >= reach || std::abs(b.normal[i].dot(d)) >= reach)) continue;
    only_a += a.inlier[i];
    only_b += b.inlier[i];
  }
  return only_a + only_b > 0 ? (only_b - only_a) / std::sqrt(static_cast<double>(only_a + only_b)) : 0.0;
}

}  // namespace line_odom
