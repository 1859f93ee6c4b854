// The sensor models that map an unorganized LiDAR cloud onto rows (beams) and columns (azimuth bins), and the presets.
#pragma once

#include <string>
#include <vector>

namespace line_odom {

// How an unorganized LiDAR cloud maps onto rows and columns.
struct SensorModel {
  std::string name;
  int rows = 64;
  int cols = 2048;
  // Beam elevations in radians, one per row, strictly decreasing (row 0 = top beam); empty -> uniform
  // spacing between max_elevation (row 0) and min_elevation (last row).
  std::vector<double> beam_elevations;
  double max_elevation = 0.0;
  double min_elevation = 0.0;
  // Points arrive ring by ring, each ring one azimuth revolution (KITTI .bin): a new ring starts where the
  // azimuth, measured in [0, 2pi) from the +x axis, wraps around. Used only when it yields exactly `rows`
  // rings, else elevation decides.
  bool ring_order_from_azimuth_wrap = false;
};

// Presets: "hdl64" / "kitti" (Velodyne HDL-64E as in KITTI, beam table measured on the KITTI scans,
// ring-by-ring order), "vlp16" (Velodyne VLP-16, +-15 deg, 1800 columns), "os128" (Ouster OS1-128,
// +-22.5 deg uniform, 1024 columns). Throws std::invalid_argument for unknown names.
SensorModel sensor_preset(const std::string& name);
std::vector<std::string> sensor_preset_names();

// Throws std::invalid_argument naming the model and what is wrong (rows, cols, beam_elevations, the elevation span).
void validate_sensor_model(const SensorModel& model);

}  // namespace line_odom
