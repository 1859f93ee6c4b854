// Point-to-plane refinement of the registered motion (beyond the paper; docs/RESULTS.md, "Preset choices"): this scan's
// voxel means against the planes of the previous scan's voxels (surface_map.hpp), jointly with the lines' estimate
// taken as a Gaussian of its covariance (the frame keeps that covariance: odometry.cpp). Dense scans add many
// surfaces the lines see little of; on sparse ones the voxels' planes are poor, and the presets keep it off there.
#pragma once

#include "common/types.hpp"
#include "registration/surface_map.hpp"

namespace line_odom {

struct PointRefineOptions {
  double weight = 0.0;          // information of one point-to-plane residual (1/m^2) beside the lines'; 0: off
  int max_downsample = 1;       // runs only while the scans are downsampled by at most this step
  double voxel = 1.0;           // m: both scans binned in cubes of this size
  int stride = 1;               // of the range image's rows and columns binned
  int min_points = 6;           // a voxel's plane, and a voxel's mean, needs this many points
  double min_planarity = 0.1;   // (l1 - l0) / l2 of their scatter
  double huber = 0.1;           // m
  int iterations = 10;
  double max_translation = 0.1;    // m: a refinement moving the estimate further is not taken
  double max_rotation_deg = 0.5;
};

struct PointRefineResult {
  bool applied = false;  // T moved within max_translation / max_rotation_deg; else T is the lines' estimate
  RigidTransform T;
  int matched = 0;       // this scan's voxel means on a planar voxel of the previous scan, at the last iteration
};

// Minimises x' C^-1 x + weight * sum huber(n . (exp(x) T p - m)) over the left perturbation x of T (the lines'
// estimate, covariance C, order x y z rx ry rz) by Gauss-Newton; p: `scan`'s voxel means, (n, m): the plane of the
// `previous` voxel exp(x) T p falls in, found again every iteration.
PointRefineResult refine_with_points(const SurfaceMap& scan, SurfaceMap& previous, const RigidTransform& T,
                                     const Mat6& covariance, const PointRefineOptions& options);

}  // namespace line_odom
