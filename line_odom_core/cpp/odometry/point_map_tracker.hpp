// The scan's points against the local map of the last scans' points (voxel_points.hpp, point_alignment.hpp), beyond
// the paper: asked where the line intersections leave a direction of the motion open. Its own state: the map, where the
// last scan sits on it, and how far the motion model has recently been off.
#pragma once

#include <vector>

#include "common/types.hpp"
#include "odometry/odometry_config.hpp"
#include "registration/point_alignment.hpp"
#include "registration/voxel_points.hpp"

namespace line_odom {

class PointMapTracker {
 public:
  PointMapTracker(const PointMapOptions& options, double max_range);

  bool enabled() const { return options_.enabled; }
  bool ready() const { return options_.enabled && !map_.empty(); }
  // Whether the last scan has a place on the map: it entered it. Without one, the map's place relative to the next
  // scan is unknown.
  bool holds_last_scan() const { return holds_last_scan_; }
  // The axes of xi (bits) along which the last scan's place on the map is its lines' motion that nothing confirmed
  // (add's `unconfirmed`): there the next scan's alignment agreeing with its lines may only repeat that motion.
  int last_scan_unconfirmed() const { return holds_last_scan_ ? last_scan_unconfirmed_ : 0; }
  // The width of the alignment's kernel now (alignment_kernel_scale): the basin of a start.
  double alignment_kernel_scale() const;
  // Where a scan at odometry pose `pose` sits on the map: the map is the odometry frame until a scan whose motion was
  // partly held at the prediction enters where its points put it (reanchor).
  RigidTransform place_of(const RigidTransform& pose) const { return map_from_odometry_ * pose; }
  // The motion T_prev_curr that aligns `points` (this scan, sensor frame) to the map, from `prediction` after the
  // previous scan at `previous_pose`; false when too few points found a map point.
  // `covariance` (nullable): of the motion, in its own chart (motion_difference; x y z rx ry rz of the previous frame).
  bool align(const std::vector<Vec3>& points, const RigidTransform& previous_pose, const RigidTransform& prediction,
             RigidTransform* motion, int* matched, Mat6* covariance = nullptr) const;
  // align from several starts: `prediction`, and along each of `directions` (unit) the shift of `prediction` the points
  // fit best (point_cost) of those every alignment kernel width (a start within it of the right motion falls into its
  // basin) out to `reach` either side. An alignment from a shift replaces the prediction's only where the points fit
  // it better by `significance` standard errors (point_cost_advantage): along a corridor they fit every shift alike;
  // or where they fit its start better than the start's mirror image about the prediction by as much and it ends
  // outside the prediction's basin: then `travelled` (nullable) is set.
  bool align_from_starts(const std::vector<Vec3>& points, const RigidTransform& previous_pose,
                         const RigidTransform& prediction, const std::vector<Vec3>& directions, double reach,
                         double significance, RigidTransform* motion, int* matched, Mat6* covariance = nullptr,
                         bool* travelled = nullptr) const;
  // Whether `points` fit the map at least as well at motion `a` as at `b` (point_cost; both after `previous_pose`).
  bool fits_as_well(const std::vector<Vec3>& points, const RigidTransform& previous_pose, const RigidTransform& a,
                    const RigidTransform& b) const;
  // How many standard errors better `points` fit the map at motion `a` than at `b` (point_cost_advantage).
  double fit_advantage(const std::vector<Vec3>& points, const RigidTransform& previous_pose, const RigidTransform& a,
                       const RigidTransform& b) const;
  // A frame done: its points at odometry pose `pose` (at place_of(pose) on the map), measured over `ground` (nullable,
  // sensor frame; kept unless point_map.ground_planes is never); `predicted` against `registered` tells the motion
  // model's error; `unconfirmed`: the axes (bits) along which nothing confirmed `pose`'s motion.
  void add(const std::vector<Vec3>& points, const Plane* ground, const RigidTransform& pose,
           const RigidTransform& predicted, const RigidTransform& registered, int unconfirmed = 0);
  // The scan at odometry pose `pose` sits at `place` on the map, and the scans after it relative to it.
  void reanchor(const RigidTransform& pose, const RigidTransform& place) { map_from_odometry_ = place * pose.inverse(); }
  // A frame that stays out of the map.
  void leave_out() { holds_last_scan_ = false; }
  void reset();

 private:
  // The scan's points as they are aligned: thinned to one per 1.5 voxels, at most a budget of them.
  std::vector<Vec3> thinned(const std::vector<Vec3>& points) const;
  // The motion of an alignment after `previous_pose`, when enough points matched.
  bool accept(const PointAlignment& aligned, const RigidTransform& previous_pose, RigidTransform* motion, int* matched,
              Mat6* covariance) const;

  PointMapOptions options_;
  // point_map.ground_planes: the cubes on the ground matched to its plane in every alignment and cost, or in the first
  // motion's (align_from_starts) alone, where the map holds one scan sampled by the same lasers from where standing
  // still puts this one and its rings hold the scan there most.
  bool ground_always_, ground_first_motion_;
  double max_range_;
  double voxel_;
  VoxelPointMap map_;
  MotionModelError model_error_;
  bool holds_last_scan_ = false;
  int last_scan_unconfirmed_ = 0;
  RigidTransform map_from_odometry_;
};

}  // namespace line_odom
