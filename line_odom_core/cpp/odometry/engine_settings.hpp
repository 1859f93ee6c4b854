// The engine's settings, one row each (common/settings_table.hpp): the dotted names of the ROS parameters and the
// YAML presets, their ranges, units and descriptions. A new setting is a member with its default in its options
// struct and a row in engine_settings.cpp; the bindings, the Python schema, the ROS parameters and docs/NODE.md
// follow from the row.
#pragma once

#include "common/settings_table.hpp"
#include "features/feature_extraction.hpp"
#include "odometry/odometry_config.hpp"
#include "registration/motion_estimation.hpp"

namespace line_odom {

// Every setting of the odometry: downsample, seed, threads, sensor.*, lines.*, normals.*, planes.*, candidates.*,
// ransac.*, registration.*, points.*, point_map.*, validation.*.
const SettingsTable<OdometryConfig>& odometry_settings();
// lines.*, normals.*, planes.* (extract_features).
const SettingsTable<FeatureConfig>& feature_settings();
// The options of one motion estimation (estimate_motion): those the odometry exposes as ransac.*, and those it sets
// itself per pass (seed, min_inliers, the sampling and 7L solver details).
const SettingsTable<MotionOptions>& motion_settings();

}  // namespace line_odom
