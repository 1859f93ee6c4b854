// Plane fitting (paper §6.2 "Plane Fitting": at least the ground for LiDAR, walls when present).
//
// The paper uses RANSAC on the points. Here planes grow over the line-crossing graph instead, which is
// linear in the number of lines and reuses what line fitting already established: H- and V-lines that
// cross, whose normals agree, lie on one surface. A region starts at the unassigned line with the largest
// support and takes crossing lines whose normal agrees with the region's plane within max_normal_angle_deg
// and whose end points lie within max_distance of it (the plane is refitted by least squares as the region
// grows). A region becomes a plane when its points (each counted once) pass the support / line count /
// extent / rms tests. Normals point towards the sensor (delta > 0).
#pragma once

#include <vector>

#include "common/scan_features.hpp"
#include "features/line_fit.hpp"
#include "features/line_normals.hpp"

namespace line_odom {

struct PlaneFitConfig {
  bool enabled = true;                 // planes.enabled
  double max_distance = 0.10;          // planes.max_distance (m at range 0, grows like the line thresholds)
  double max_normal_angle_deg = 10.0;  // planes.max_normal_angle_deg: line normal vs plane normal
  int min_points = 30;                 // planes.min_points: range-image points on the plane
  int min_lines = 3;                   // planes.min_lines: H- and V-lines on the plane
  double min_extent = 1.0;             // planes.min_extent (m): shorter side of the equal-moment rectangle
  double max_rms = 0.06;               // planes.max_rms (m): point-to-plane rms
  int max_planes = 20;                 // planes.max_planes: the largest ones are kept
};

// Fits planes to the lines (with normals) of one range image; sets LineFeature::plane of the member lines.
std::vector<PlaneFeature> fit_planes(const RangeImage& image, const std::vector<LineCrossing>& crossings,
                                     const PlaneFitConfig& config, const LineFitConfig& line_config,
                                     ScanLines* lines);

}  // namespace line_odom
