#include "odometry/point_map_tracker.hpp"

#include <cmath>
#include <limits>

namespace line_odom {

namespace {

constexpr double kAlignedVoxel = 1.5;  // map voxels: the scan thinned to one point per 1.5 voxels to be aligned, and
constexpr double kMapVoxel = 0.5;      // to one per half voxel to enter the map (KISS-ICP's choices)
constexpr int kMinMatched = 50;        // fewer matched points place no scan
constexpr std::size_t kAlignedPoints = 1500;  // points aligned at most, spread over the scan: enough to place it to a
                                              // fraction of validation.tolerance

// Every k-th point, at most `budget` of them.
std::vector<Vec3> spread(std::vector<Vec3> points, std::size_t budget) {
  if (points.size() <= budget) return points;
  const std::size_t step = (points.size() + budget - 1) / budget;
  std::size_t kept = 0;
  for (std::size_t i = 0; i < points.size(); i += step) points[kept++] = points[i];
  points.resize(kept);
  return points;
}

}  // namespace

PointMapTracker::PointMapTracker(const PointMapOptions& options, double max_range)
    : options_(options),
      ground_always_(options.ground_planes == "always"),
      ground_first_motion_(options.ground_planes != "never"),
      max_range_(max_range),
      voxel_(options.voxel > 0.0 ? options.voxel : max_range / 100.0),
      map_(voxel_, options.max_points_per_voxel, options.keep == "viewpoints" ? options.alignment.min_motion : -1.0),
      model_error_(options.alignment.initial_threshold, options.alignment.min_motion, max_range) {}

namespace {

// The adjoint of T: a left perturbation xi (translation, rotation) of X becomes Ad(T) xi of T X ... of T^-1-moved poses.
Mat6 adjoint(const RigidTransform& T) {
  Mat6 A = Mat6::Zero();
  Mat3 tx;
  tx << 0.0, -T.t.z(), T.t.y(), T.t.z(), 0.0, -T.t.x(), -T.t.y(), T.t.x(), 0.0;
  A.topLeftCorner<3, 3>() = T.R;
  A.topRightCorner<3, 3>() = tx * T.R;
  A.bottomRightCorner<3, 3>() = T.R;
  return A;
}

}  // namespace

std::vector<Vec3> PointMapTracker::thinned(const std::vector<Vec3>& points) const {
  return spread(voxel_downsample(points, kAlignedVoxel * voxel_), kAlignedPoints);
}

double PointMapTracker::alignment_kernel_scale() const {
  return line_odom::alignment_kernel_scale(map_, model_error_.sigma());
}

bool PointMapTracker::align(const std::vector<Vec3>& points, const RigidTransform& previous_pose,
                            const RigidTransform& prediction, RigidTransform* motion, int* matched,
                            Mat6* covariance) const {
  if (!ready()) return false;
  const PointAlignment aligned =
      align_points(map_, thinned(points), previous_pose * prediction, model_error_.sigma(), options_.alignment,
                   ground_always_);
  return accept(aligned, previous_pose, motion, matched, covariance);
}

bool PointMapTracker::align_from_starts(const std::vector<Vec3>& points, const RigidTransform& previous_pose,
                                        const RigidTransform& prediction, const std::vector<Vec3>& directions,
                                        double reach, double significance, RigidTransform* motion, int* matched,
                                        Mat6* covariance, bool* travelled_out) const {
  if (travelled_out != nullptr) *travelled_out = false;
  if (!ready()) return false;
  const std::vector<Vec3> aligned_points = thinned(points);
  const double sigma = model_error_.sigma();
  const double step = alignment_kernel_scale();
  const int steps = static_cast<int>(reach / step + 1e-9);
  const RigidTransform predicted_pose = previous_pose * prediction;
  const bool ground = ground_first_motion_;
  const PointAlignment from_prediction =
      align_points(map_, aligned_points, predicted_pose, sigma, options_.alignment, ground);
  PointAlignment best = from_prediction;
  double best_cost = point_cost(map_, aligned_points, best.pose, sigma, ground);
  bool shifted = false;  // best is an alignment from a shifted start
  // The one-scan map's points were sampled by the same lasers from where the prediction (standing still) puts this
  // scan: there, and at any alignment ending in its basin, the points' cost is lowered by that coincidence whatever the
  // motion. A start and its mirror image about the prediction lie equally far from it: a start the points fit better
  // than its mirror by `significance` standard errors shows the way the scan travelled, and its alignment is taken
  // where it ends outside the prediction's basin (the one of those the points fit best).
  PointAlignment travelled;
  double travelled_cost = std::numeric_limits<double>::infinity();  // infinite: none
  for (const Vec3& direction : directions) {
    auto shifted_by = [&](double distance) {
      RigidTransform moved = prediction;
      moved.t += distance * direction;
      return moved;
    };
    int start_step = 0;
    double start_cost = std::numeric_limits<double>::infinity();
    for (int k = -steps; k <= steps; ++k) {
      if (k == 0) continue;
      const double c = point_cost(map_, aligned_points, previous_pose * shifted_by(k * step), sigma, ground);
      if (c < start_cost) start_cost = c, start_step = k;
    }
    if (!std::isfinite(start_cost)) continue;
    const RigidTransform start = shifted_by(start_step * step), mirror = shifted_by(-start_step * step);
    const PointAlignment other =
        align_points(map_, aligned_points, previous_pose * start, sigma, options_.alignment, ground);
    if (other.matched < kMinMatched || !other.pose.is_finite()) continue;
    const double cost = point_cost(map_, aligned_points, other.pose, sigma, ground);
    if (cost < best_cost) best_cost = cost, best = other, shifted = true;
    const bool beyond_basin = (other.pose.t - predicted_pose.t).norm() > step;
    if (beyond_basin && cost < travelled_cost &&
        point_cost_advantage(map_, aligned_points, previous_pose * start, previous_pose * mirror, sigma, ground) >=
            significance)
      travelled = other, travelled_cost = cost;
  }
  const bool shift_fits_better =
      shifted &&
      point_cost_advantage(map_, aligned_points, best.pose, from_prediction.pose, sigma, ground) >= significance;
  if (!shift_fits_better) {
    const bool have_travelled = std::isfinite(travelled_cost);
    best = have_travelled ? travelled : from_prediction;
    if (travelled_out != nullptr) *travelled_out = have_travelled;
  }
  return accept(best, previous_pose, motion, matched, covariance);
}

bool PointMapTracker::accept(const PointAlignment& aligned, const RigidTransform& previous_pose,
                             RigidTransform* motion, int* matched, Mat6* covariance) const {
  *matched = aligned.matched;
  if (aligned.matched < kMinMatched || !aligned.pose.is_finite()) return false;
  *motion = previous_pose.inverse() * aligned.pose;
  if (covariance != nullptr) {
    // exp(xi) A seen from the previous pose P: P^-1 exp(xi) A = exp(Ad(P^-1) xi) P^-1 A
    const Mat6 to_previous = adjoint(previous_pose.inverse());
    *covariance = to_previous * aligned.covariance * to_previous.transpose();
  }
  return true;
}

bool PointMapTracker::fits_as_well(const std::vector<Vec3>& points, const RigidTransform& previous_pose,
                                   const RigidTransform& a, const RigidTransform& b) const {
  const std::vector<Vec3> checked = thinned(points);
  const double sigma = model_error_.sigma();
  return point_cost(map_, checked, previous_pose * a, sigma, ground_always_) <=
         point_cost(map_, checked, previous_pose * b, sigma, ground_always_);
}

double PointMapTracker::fit_advantage(const std::vector<Vec3>& points, const RigidTransform& previous_pose,
                                      const RigidTransform& a, const RigidTransform& b) const {
  return point_cost_advantage(map_, thinned(points), previous_pose * a, previous_pose * b, model_error_.sigma(),
                              ground_always_);
}

void PointMapTracker::add(const std::vector<Vec3>& points, const Plane* ground, const RigidTransform& pose,
                          const RigidTransform& predicted, const RigidTransform& registered, int unconfirmed) {
  if (!options_.enabled) return;
  last_scan_unconfirmed_ = unconfirmed;
  model_error_.add(predicted, registered);
  map_.add(voxel_downsample(points, kMapVoxel * voxel_), place_of(pose), max_range_,
           ground_first_motion_ ? ground : nullptr);
  holds_last_scan_ = true;
}

void PointMapTracker::reset() {
  map_.clear();
  model_error_.clear();
  holds_last_scan_ = false;
  map_from_odometry_ = RigidTransform::identity();
}

}  // namespace line_odom
