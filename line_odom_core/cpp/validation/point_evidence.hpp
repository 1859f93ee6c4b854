// Evidence for a frame's motion that does not come from the line intersections (beyond the paper): this scan's points
// against the planes of the local map's voxels (local_map.hpp). An H-line and a V-line on one wall meet for any shift
// within that wall, so a wrong motion along a street can collect intersection inliers; the points on the surfaces
// across the street, the ground and the poles do not follow it.
#pragma once

#include <cstdint>
#include <vector>

#include "common/types.hpp"
#include "registration/surface_map.hpp"

namespace line_odom {

struct EvidenceOptions {
  bool enabled = false;
  double voxel = 1.0;            // m: the local map's cubes
  int map_scans = 10;            // registered scans in the local map
  int map_points = 40000;        // points the map keeps, spread over its scans
  int max_points = 4000;         // of this scan's points checked, spread over the scan
  int min_points = 5;            // a map voxel's plane needs this many points
  double min_planarity = 0.1;    // (l1 - l0) / l2 of their scatter
  double inlier_distance = 0.1;  // m: a point this close to its voxel's plane supports the motion
  int iterations = 10;           // Gauss-Newton steps from each start, the partners found again in each
  double significance = 3.0;     // z of McNemar's test: a motion replaces another when its points' support is
                                 // this many standard deviations larger
  int min_matches = 200;         // fewer points on map planes: no evidence either way
  double search_range = 3.0;     // m searched along the translations the lines leave unobserved
};

// This scan's points at a motion T_prev_curr against the map (in the previous scan's frame).
struct PointSupport {
  RigidTransform T;
  int matched = 0;   // on a planar map voxel
  int inliers = 0;   // ... within inlier_distance of its plane
  double rms = 0.0;  // of the inliers' residuals
  std::vector<std::uint8_t> inlier;  // per point
  std::vector<Vec3> normal;          // per point: its map voxel's plane normal, 0 when unmatched
  Mat6 information = Mat6::Zero();   // J^T J of the inliers (x y z rx ry rz, left perturbation)
};

PointSupport point_support(SurfaceMap& map, const std::vector<Vec3>& points, const RigidTransform& T,
                           const EvidenceOptions& options);
// Gauss-Newton on the Huber point-to-plane residuals from `start` (damped: directions the planes leave open stay at
// the start); the support at the result.
PointSupport fit_points(SurfaceMap& map, const std::vector<Vec3>& points, const RigidTransform& start,
                        const EvidenceOptions& options);
// McNemar's z for "b supports more of the points than a": (n_b - n_a) / sqrt(n_b + n_a) over the points exactly one
// of the two supports (0 when none). Only points that can tell the two motions apart count: those whose plane (at a
// or at b) faces the point's displacement from a to b within 60 deg; a point on a plane along its displacement keeps
// its residual whichever motion is right, and the ground and the walls along a street would otherwise outvote the few
// surfaces across it.
double support_gain(const std::vector<Vec3>& points, const PointSupport& a, const PointSupport& b);

}  // namespace line_odom
