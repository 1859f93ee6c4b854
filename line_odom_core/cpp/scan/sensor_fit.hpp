// How well an unorganized cloud fits a sensor model: the drop-in check of a LiDAR against the preset it is read
// with. A cloud read with another sensor's beams falls outside them or leaves most rows empty, and the lines of
// the range image it makes do not describe the scene (a 16-beam cloud in the 64-row HDL-64E model gives no V-lines).
#pragma once

#include <cstddef>
#include <cstdint>
#include <string>

#include "scan/range_image.hpp"

namespace line_odom {

struct SensorFit {
  std::string model;               // the sensor model's name
  int rows = 0;                    // its rows
  double max_elevation_deg = 0.0;  // its top and bottom beams
  double min_elevation_deg = 0.0;
  // How the rows were found ("ring", "ring_by_elevation", "azimuth_wrap", "elevation"); empty if not.
  std::string row_method;
  std::size_t points = 0;          // finite, non-zero points within the range limits
  std::size_t outside_rows = 0;    // of those, outside the model's beams (rows by elevation)
  int filled_rows = 0;             // rows holding a point in at least 1 % of the model's columns
  int band_rows = 0;               // rows from the first filled row to the last (what sky or a lone ground leaves)
  long long ring_rows = 0;         // 1 + the largest ring value (0: no ring field)
  double cloud_high_deg = 0.0;     // the cloud's elevations: 99.5th and 0.5th percentile of its points
  double cloud_low_deg = 0.0;
};

// Organizes the cloud as the odometry would (every row, every column). A ring value beyond the model's rows is
// reported in ring_rows, not thrown (the rows are then not organized). Throws std::invalid_argument on a bad stride.
SensorFit fit_to_sensor(const float* data, std::size_t count, std::size_t stride, const std::int32_t* ring,
                        const SensorModel& model, const RangeLimits& limits);
SensorFit fit_to_sensor(const double* data, std::size_t count, std::size_t stride, const std::int32_t* ring,
                        const SensorModel& model, const RangeLimits& limits);

}  // namespace line_odom
