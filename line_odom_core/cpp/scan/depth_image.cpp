// organize_depth and organize_depth_downsampled (range_image.hpp): a depth image back-projected with the pinhole
// intrinsics, pixel rows and columns as the image's.
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <stdexcept>

#include "scan/range_image.hpp"

namespace line_odom {

namespace {

// The kept pixels (every step-th row and column) of a depth image, back-projected; each written once.
RangeImage organize_depth_impl(const float* depth, int rows, int cols, const Mat3& K, const RangeLimits& limits,
                               int step, OrganizeStats* stats) {
  validate_range_limits(limits);
  if (rows < 1 || cols < 1) throw std::invalid_argument("depth: rows and cols must be >= 1");
  if (depth == nullptr) throw std::invalid_argument("depth: null data");
  if (step < 1) throw std::invalid_argument("downsample: step must be >= 1");
  const double fx = K(0, 0), fy = K(1, 1), cx = K(0, 2), cy = K(1, 2);
  if (!K.allFinite() || !(fx > 0.0) || !(fy > 0.0))
    throw std::invalid_argument("K: expected finite intrinsics with fx > 0 and fy > 0");
  OrganizeStats st;
  st.row_method = "depth";
  const int out_rows = (rows + step - 1) / step, out_cols = (cols + step - 1) / step;
  RangeImage img;
  img.rows = out_rows;
  img.cols = out_cols;
  img.points.resize(static_cast<size_t>(out_rows) * out_cols);
  img.valid.resize(img.points.size());
  st.input_points = static_cast<size_t>(rows) * cols;
  for (int r = 0; r < out_rows; ++r) {
    const int v = r * step;
    const double ry = (v - cy) / fy;
    const float* depth_row = depth + static_cast<size_t>(v) * cols;
    Vec3* points = img.points.data() + static_cast<size_t>(r) * out_cols;
    std::uint8_t* valid = img.valid.data() + static_cast<size_t>(r) * out_cols;
    for (int c = 0; c < out_cols; ++c) {
      const int u = c * step;
      const double z = depth_row[u];
      points[c] = Vec3::Zero();
      valid[c] = 0;
      if (!std::isfinite(z) || z <= 0.0) {
        ++st.invalid_points;
        continue;
      }
      if (z < limits.min_range || z > limits.max_range) {
        ++st.out_of_range;
        continue;
      }
      points[c] = Vec3((u - cx) / fx * z, ry * z, z);
      valid[c] = 1;
      ++st.kept_points;
    }
  }
  if (stats) *stats = st;
  return img;
}

}  // namespace

RangeImage organize_depth(const float* depth, int rows, int cols, const Mat3& K, const RangeLimits& limits,
                          OrganizeStats* stats) {
  return organize_depth_impl(depth, rows, cols, K, limits, 1, stats);
}
RangeImage organize_depth_downsampled(const float* depth, int rows, int cols, const Mat3& K,
                                      const RangeLimits& limits, int step, OrganizeStats* stats) {
  return organize_depth_impl(depth, rows, cols, K, limits, step, stats);
}

}  // namespace line_odom
