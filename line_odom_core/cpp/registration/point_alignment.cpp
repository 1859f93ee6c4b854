#include "registration/point_alignment.hpp"

#include <Eigen/Cholesky>
#include <algorithm>
#include <cmath>
#include <limits>

#include "registration/refine.hpp"

namespace line_odom {

namespace {

// The residual of q against the map: to the plane of its nearest point's voxel where that voxel holds a plane (sampled
// surfaces slide under point-to-point matching: a ring of points keeps its place relative to the sensor, so its nearest
// point would hold the scan back), else to that point. False without a map point within max_distance.
struct Residual {
  bool planar = false;
  double distance = 0.0;  // plane: signed distance; point: 0 (use offset)
  Vec3 normal = Vec3::Zero();
  Vec3 offset = Vec3::Zero();
  double squared() const { return planar ? distance * distance : offset.squaredNorm(); }
};

bool residual_of(const VoxelPointMap& map, const Vec3& q, double max_distance, bool ground, Residual* out) {
  Vec3 nearest;
  int voxel = -1;
  if (!map.nearest(q, max_distance, &nearest, &voxel)) return false;
  Vec3 mean;
  out->planar = map.plane(voxel, &mean, &out->normal, ground);
  if (out->planar) out->distance = out->normal.dot(q - mean);
  else out->offset = q - nearest;
  return true;
}

}  // namespace

// Geman-McClure scale: sigma / 3, but never below a quarter voxel: the map keeps a point per half voxel, so the
// nearest one is up to that far from a point placed right.
double alignment_kernel_scale(const VoxelPointMap& map, double sigma) {
  return std::max(sigma / 3.0, 0.25 * map.voxel());
}

PointAlignment align_points(const VoxelPointMap& map, const std::vector<Vec3>& points,
                            const RigidTransform& initial_pose, double sigma, const PointAlignmentOptions& options,
                            bool ground) {
  PointAlignment out;
  out.pose = initial_pose;
  if (map.empty() || points.empty() || !(sigma > 0.0)) return out;
  const double max_distance = 3.0 * sigma;
  const double scale = alignment_kernel_scale(map, sigma);
  const double kernel = scale * scale;  // m^2
  for (int it = 0; it < options.max_iterations; ++it) {
    Mat6 H = Mat6::Zero();
    Vec6 g = Vec6::Zero();
    int matched = 0;
    double weighted_squares = 0.0, weights = 0.0, dimensions = 0.0;
    for (const Vec3& p : points) {
      const Vec3 q = out.pose.apply(p);
      Residual r;
      if (!residual_of(map, q, max_distance, ground, &r)) continue;
      const double d2 = r.squared();
      const double w = kernel * kernel / ((kernel + d2) * (kernel + d2));
      weighted_squares += w * d2;
      weights += w * (r.planar ? 1.0 : 3.0);
      dimensions += r.planar ? 1.0 : 3.0;
      // d q / d xi for q' = exp(xi) q: [I, -[q]x]
      Eigen::Matrix<double, 3, 6> J;
      J.leftCols<3>().setIdentity();
      J.rightCols<3>() << 0.0, q.z(), -q.y(), -q.z(), 0.0, q.x(), q.y(), -q.x(), 0.0;
      if (r.planar) {
        const Eigen::Matrix<double, 1, 6> Jn = r.normal.transpose() * J;
        H.noalias() += w * Jn.transpose() * Jn;
        g.noalias() += w * r.distance * Jn.transpose();
      } else {
        H.noalias() += w * J.transpose() * J;
        g.noalias() += w * J.transpose() * r.offset;
      }
      ++matched;
    }
    out.matched = matched;
    out.information = H;
    out.iterations = it + 1;
    if (matched < 6) return out;
    if (dimensions > 6.0 && weights > 0.0) {
      // The residuals' variance per dimension, from their weighted mean square over the degrees of freedom left.
      const double variance = weighted_squares / weights * dimensions / (dimensions - 6.0);
      const Mat6 covariance = variance * H.ldlt().solve(Mat6::Identity());
      if (covariance.allFinite()) out.covariance = covariance;
    }
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

namespace {

// One point's term of point_cost: its Geman-McClure cost, 1 without a map point within 3 sigma.
double point_term(const VoxelPointMap& map, const Vec3& q, double sigma, double scale, bool ground) {
  Residual r;
  if (!residual_of(map, q, 3.0 * sigma, ground, &r)) return 1.0;
  const double d2 = r.squared();
  return d2 / (scale * scale + d2);
}

}  // namespace

double point_cost(const VoxelPointMap& map, const std::vector<Vec3>& points, const RigidTransform& pose, double sigma,
                  bool ground) {
  if (points.empty()) return 1.0;
  const double scale = alignment_kernel_scale(map, sigma);
  double cost = 0.0;
  for (const Vec3& p : points) cost += point_term(map, pose.apply(p), sigma, scale, ground);
  return cost / static_cast<double>(points.size());
}

double point_cost_advantage(const VoxelPointMap& map, const std::vector<Vec3>& points, const RigidTransform& better,
                            const RigidTransform& worse, double sigma, bool ground) {
  const double n = static_cast<double>(points.size());
  if (n < 2.0) return 0.0;
  const double scale = alignment_kernel_scale(map, sigma);
  double sum = 0.0, squares = 0.0;
  for (const Vec3& p : points) {
    const double d =
        point_term(map, worse.apply(p), sigma, scale, ground) - point_term(map, better.apply(p), sigma, scale, ground);
    sum += d;
    squares += d * d;
  }
  const double mean = sum / n;
  const double variance = std::max(0.0, (squares - n * mean * mean) / (n - 1.0));
  return variance > 0.0 ? mean / std::sqrt(variance / n) : (mean > 0.0 ? std::numeric_limits<double>::infinity() : 0.0);
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
