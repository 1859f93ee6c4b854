#include "odometry/point_map_tracker.hpp"

namespace line_odom {

namespace {

constexpr double kAlignedVoxel = 1.5;  // map voxels: the scan thinned to one point per 1.5 voxels to be aligned, and
constexpr double kMapVoxel = 0.5;      // to one per half voxel to enter the map (KISS-ICP's choices)
constexpr int kMinMatched = 50;        // fewer matched points place no scan

}  // namespace

PointMapTracker::PointMapTracker(const PointMapOptions& options, double max_range)
    : options_(options),
      max_range_(max_range),
      voxel_(options.voxel > 0.0 ? options.voxel : max_range / 100.0),
      map_(voxel_, options.max_points_per_voxel),
      model_error_(options.alignment.initial_threshold, options.alignment.min_motion, max_range) {}

bool PointMapTracker::align(const std::vector<Vec3>& points, const RigidTransform& previous_pose,
                            const RigidTransform& prediction, RigidTransform* motion, int* matched) const {
  if (!ready()) return false;
  const PointAlignment aligned = align_points(map_, voxel_downsample(points, kAlignedVoxel * voxel_),
                                              previous_pose * prediction, model_error_.sigma(), options_.alignment);
  *matched = aligned.matched;
  if (aligned.matched < kMinMatched || !aligned.pose.is_finite()) return false;
  *motion = previous_pose.inverse() * aligned.pose;
  return true;
}

void PointMapTracker::add(const std::vector<Vec3>& points, const RigidTransform& pose,
                          const RigidTransform& predicted, const RigidTransform& registered, bool had_model) {
  if (!options_.enabled) return;
  if (had_model) model_error_.add(predicted, registered);
  map_.add(voxel_downsample(points, kMapVoxel * voxel_), pose, max_range_);
}

void PointMapTracker::reset() {
  map_.clear();
  model_error_.clear();
}

}  // namespace line_odom
