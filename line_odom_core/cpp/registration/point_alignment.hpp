// A scan's points aligned to the local map of the last scans' points (voxel_points.hpp), beyond the paper: the
// registration of KISS-ICP (Vizzo et al., RA-L 2023), its robust kernel and its threshold adapted to how far the motion
// model has recently been off, with point-to-plane residuals where the map's voxel holds a plane. The odometry asks it where the line intersections leave a direction
// of the motion open (a first motion from standing still, a street along which every pair meets): there the points of
// poles, trees and cars still place the scan.
#pragma once

#include <vector>

#include "common/types.hpp"
#include "registration/voxel_points.hpp"

namespace line_odom {

struct PointAlignmentOptions {
  int max_iterations = 100;
  double convergence = 5e-3;        // |step| (m, rad) under which the alignment has converged: a fraction of what
                                    // validation.tolerance asks of it
  double initial_threshold = 2.0;   // m: the motion model's error assumed before any was measured
  double min_motion = 0.1;          // m: a frame moving less than this says nothing about the model's error
};

struct PointAlignment {
  RigidTransform pose;               // T_world_sensor of the scan
  Mat6 information = Mat6::Zero();   // J^T W J at the result (x y z rx ry rz, left perturbation in the world frame)
  Mat6 covariance = Mat6::Identity() * 1e6;  // s^2 (J^T W J)^-1, s^2 the weighted residuals' variance (same frame)
  int matched = 0;                   // points with a map point within the threshold at the last iteration
  int iterations = 0;
  bool converged = false;
};

// Gauss-Newton from `initial_pose` on the Geman-McClure-weighted distances of `points` (sensor frame) to their nearest
// map points within 3 sigma (kernel scale sigma / 3, at least a quarter of the map's voxel): to the plane of that
// point's voxel where its points lie on one (or, with `ground`, on the ground: VoxelPointMap::plane), else to the point.
PointAlignment align_points(const VoxelPointMap& map, const std::vector<Vec3>& points,
                            const RigidTransform& initial_pose, double sigma, const PointAlignmentOptions& options,
                            bool ground);

// The kernel scale of align_points and point_cost: how far a point may lie off the map and still pull the pose.
double alignment_kernel_scale(const VoxelPointMap& map, double sigma);

// The mean Geman-McClure cost (each point's in [0, 1), 1 without a map point within 3 sigma) of `points` at `pose`,
// with the residuals of align_points: what the points say of a motion found elsewhere.
double point_cost(const VoxelPointMap& map, const std::vector<Vec3>& points, const RigidTransform& pose, double sigma,
                  bool ground);

// How much better `points` fit the map at `better` than at `worse` (point_cost's per-point terms): the mean of the
// paired differences in standard errors (a z; 0 for fewer than two points).
double point_cost_advantage(const VoxelPointMap& map, const std::vector<Vec3>& points, const RigidTransform& better,
                            const RigidTransform& worse, double sigma, bool ground);

// How far off the motion model has been (KISS-ICP's adaptive threshold): the rms over the frames that moved of the
// distance a point at `range` metres moves between the predicted and the registered motion.
class MotionModelError {
 public:
  MotionModelError() = default;
  MotionModelError(double initial_sigma, double min_motion, double range)
      : initial_(initial_sigma), min_motion_(min_motion), range_(range) {}
  void add(const RigidTransform& predicted, const RigidTransform& registered);
  double sigma() const;
  void clear() { sum_ = 0.0, count_ = 0; }

 private:
  double initial_ = 2.0, min_motion_ = 0.1, range_ = 100.0;
  double sum_ = 0.0;
  int count_ = 0;
};

}  // namespace line_odom
