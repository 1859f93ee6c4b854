// Organizing scans into range images (paper §6.2 "Organized point-clouds") and downsampling them by keeping
// every s-th row and column (s = 6 -> 1/36, 8 -> 1/64, 10 -> 1/100).
//
// Rows are beams (row 0 = highest elevation) or pixel rows; columns are azimuth bins (LiDAR; column 0 is
// straight behind the sensor, columns run clockwise seen from above, so the image reads left to right like
// a panorama) or pixel columns. Holes (NaN/inf/zero/out-of-range points, empty cells) have valid = 0.
//
// Implemented in organize_points.cpp (unorganized clouds; their rows from point_rows, the per-point loops in
// organize_kernels), depth_image.cpp (depth back-projection), range_image.cpp (organized clouds, downsampling) and
// sensor_model (the presets).
#pragma once

#include <cstddef>
#include <cstdint>
#include <string>
#include <vector>

#include "common/scan_features.hpp"
#include "scan/sensor_model.hpp"

namespace line_odom {

struct RangeLimits {
  double min_range = 0.0;    // metres; closer points are holes (LiDAR: distance, depth camera: depth z)
  double max_range = 1e9;    // metres; farther points are holes
};

// Throws std::invalid_argument unless 0 <= min_range < max_range.
void validate_range_limits(const RangeLimits& limits);

struct OrganizeStats {
  std::size_t input_points = 0;
  std::size_t kept_points = 0;         // points stored in a cell
  std::size_t invalid_points = 0;      // NaN / inf / all-zero
  std::size_t out_of_range = 0;        // outside RangeLimits
  std::size_t outside_rows = 0;        // elevation outside the sensor's beams (elevation mode)
  std::size_t cell_collisions = 0;     // two points in one cell (and no free neighbour): the farther dropped
  std::string row_method;              // "ring", "ring_by_elevation", "azimuth_wrap", "elevation", "organized", "depth"
};

// Unorganized points: xyz at data[i * stride + 0..2] (stride in elements, >= 3, e.g. 4 for KITTI x,y,z,r).
// `ring` (nullable): one beam index per point in [0, model.rows); ring 0 may be the top or the bottom beam
// (rows are flipped so that row 0 is the highest). Throws std::invalid_argument on bad model/ring/stride.
RangeImage organize_points(const float* data, std::size_t count, std::size_t stride, const std::int32_t* ring,
                           const SensorModel& model, const RangeLimits& limits, OrganizeStats* stats = nullptr);
RangeImage organize_points(const double* data, std::size_t count, std::size_t stride, const std::int32_t* ring,
                           const SensorModel& model, const RangeLimits& limits, OrganizeStats* stats = nullptr);

// Organizing and downsampling in one pass: the image equals downsample(organize_points(...), step), but only
// the rows that downsampling keeps are binned into columns. Stats count the points of the kept rows (and of no
// row) only; input_points and invalid_points still count every point.
RangeImage organize_points_downsampled(const float* data, std::size_t count, std::size_t stride,
                                       const std::int32_t* ring, const SensorModel& model, const RangeLimits& limits,
                                       int step, OrganizeStats* stats = nullptr);
RangeImage organize_points_downsampled(const double* data, std::size_t count, std::size_t stride,
                                       const std::int32_t* ring, const SensorModel& model, const RangeLimits& limits,
                                       int step, OrganizeStats* stats = nullptr);

// An organized cloud (rows x cols points, row-major, `stride` elements per point) used as it is.
RangeImage organize_cloud(const float* data, int rows, int cols, std::size_t stride, const RangeLimits& limits,
                          OrganizeStats* stats = nullptr);
RangeImage organize_cloud(const double* data, int rows, int cols, std::size_t stride, const RangeLimits& limits,
                          OrganizeStats* stats = nullptr);

// A depth image in metres (row-major rows x cols) back-projected with the pinhole intrinsics
// K = [fx 0 cx; 0 fy cy; 0 0 1]: x = (u - cx) z / fx, y = (v - cy) z / fy (camera optical frame).
RangeImage organize_depth(const float* depth, int rows, int cols, const Mat3& K, const RangeLimits& limits,
                          OrganizeStats* stats = nullptr);
// downsample(organize_depth(...), step) back-projecting only the kept pixels; stats count the kept pixels
// (input_points still counts every pixel).
RangeImage organize_depth_downsampled(const float* depth, int rows, int cols, const Mat3& K,
                                      const RangeLimits& limits, int step, OrganizeStats* stats = nullptr);

// Keeps rows 0, s, 2s, ... and columns 0, s, 2s, ... (ceil(rows/s) x ceil(cols/s)); s = 1 returns a copy.
RangeImage downsample(const RangeImage& image, int step);

// Number of valid cells.
std::size_t count_valid(const RangeImage& image);

}  // namespace line_odom
