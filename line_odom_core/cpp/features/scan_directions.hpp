// Where a scan's geometry points: its ground, its up direction, the direction its lines run along, how far its lines
// lie. Read by the searches beyond the prediction's reach and by the first motion's point alignment.
#pragma once

#include <vector>

#include "common/scan_features.hpp"
#include "common/types.hpp"

namespace line_odom {

// The ground of the scan: its best-supported plane within 45 degrees of the sensor's z axis (a LiDAR mounted upright
// or tilted), its normal up; false when there is none.
bool ground_plane(const ScanFeatures& features, Plane* ground);

// The up direction of the scan: the normal of its ground (ground_plane), else the z axis.
Vec3 ground_up(const ScanFeatures& features);

// The horizontal direction (in the plane normal to `up`, ground_up) along which the scan's lines run most, by length
// in 1-degree bins smoothed over three: a road's, whatever the sensor's mounting yaw or tilt. The ground's ring and
// radial lines run every way and only raise the floor.
Vec3 dominant_line_direction(const ScanFeatures& features, const Vec3& up);

// The directions a first motion is searched along: each sensor axis, the sensor's x axis laid onto the ground (a
// sensor tilted forward or back) and the dominant line direction (vehicles move along a sensor axis or the road);
// a direction within 2.6 degrees of one listed before it is left out.
std::vector<Vec3> travel_directions(const ScanFeatures& features);

// The median distance of the scan's line midpoints from the sensor: how far a turn moves a typical line, per radian.
double median_line_range(const ScanFeatures& features);

}  // namespace line_odom
