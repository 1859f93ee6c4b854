#include "scan/range_image.hpp"

#include <cstddef>
#include <cstdint>
#include <stdexcept>

#include "scan/organize_kernels.hpp"

namespace line_odom {

namespace {

RangeImage empty_image(int rows, int cols, bool with_source) {
  RangeImage img;
  img.rows = rows;
  img.cols = cols;
  const size_t n = static_cast<size_t>(rows) * cols;
  img.points.assign(n, Vec3::Zero());
  img.valid.assign(n, 0);
  if (with_source) img.source_index.assign(n, -1);
  return img;
}

template <typename T>
RangeImage organize_cloud_impl(const T* data, int rows, int cols, size_t stride, const RangeLimits& limits,
                               OrganizeStats* stats) {
  validate_range_limits(limits);
  if (rows < 1 || cols < 1) throw std::invalid_argument("organized cloud: rows and cols must be >= 1");
  if (stride < 3) throw std::invalid_argument("organized cloud: stride must be >= 3 (x, y, z per point)");
  if (data == nullptr) throw std::invalid_argument("organized cloud: null data");
  OrganizeStats st;
  st.row_method = "organized";
  RangeImage img = empty_image(rows, cols, false);
  const size_t n = static_cast<size_t>(rows) * cols;
  st.input_points = n;
  for (size_t i = 0; i < n; ++i) {
    const T* p = data + i * stride;
    if (!organize_detail::finite_nonzero(p[0], p[1], p[2])) {
      ++st.invalid_points;
      continue;
    }
    const Vec3 x(p[0], p[1], p[2]);
    const double range = x.norm();
    if (range < limits.min_range || range > limits.max_range) {
      ++st.out_of_range;
      continue;
    }
    img.points[i] = x;
    img.valid[i] = 1;
    ++st.kept_points;
  }
  if (stats) *stats = st;
  return img;
}

}  // namespace

void validate_range_limits(const RangeLimits& l) {
  if (!(l.min_range >= 0.0) || !(l.max_range > l.min_range))
    throw std::invalid_argument("range limits: expected 0 <= min_range < max_range");
}

RangeImage organize_cloud(const float* data, int rows, int cols, size_t stride, const RangeLimits& limits,
                          OrganizeStats* stats) {
  return organize_cloud_impl(data, rows, cols, stride, limits, stats);
}
RangeImage organize_cloud(const double* data, int rows, int cols, size_t stride, const RangeLimits& limits,
                          OrganizeStats* stats) {
  return organize_cloud_impl(data, rows, cols, stride, limits, stats);
}

RangeImage downsample(const RangeImage& image, int step) {
  if (step < 1) throw std::invalid_argument("downsample: step must be >= 1");
  if (step == 1) return image;
  const int rows = (image.rows + step - 1) / step, cols = (image.cols + step - 1) / step;
  const bool with_source = !image.source_index.empty();
  RangeImage out = empty_image(rows, cols, with_source);
  for (int r = 0; r < rows; ++r)
    for (int c = 0; c < cols; ++c) {
      const size_t src = static_cast<size_t>(r) * step * image.cols + static_cast<size_t>(c) * step;
      const size_t dst = static_cast<size_t>(r) * cols + c;
      out.points[dst] = image.points[src];
      out.valid[dst] = image.valid[src];
      if (with_source) out.source_index[dst] = image.source_index[src];
    }
  return out;
}

size_t count_valid(const RangeImage& image) {
  size_t n = 0;
  for (auto v : image.valid) n += v != 0;
  return n;
}

}  // namespace line_odom
