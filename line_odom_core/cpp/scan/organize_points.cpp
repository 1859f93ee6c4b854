// organize_points and organize_points_downsampled (range_image.hpp): an unorganized cloud binned into its rows
// (point_rows.hpp) and azimuth columns.
#include <algorithm>
#include <cstddef>
#include <cstdint>
#include <limits>
#include <memory>
#include <stdexcept>
#include <vector>

#include "scan/organize_kernels.hpp"
#include "scan/point_rows.hpp"
#include "scan/range_image.hpp"

namespace line_odom {

namespace {

using organize_detail::column_and_range;
using organize_detail::PointArrays;
using organize_detail::PointRows;
using organize_detail::StridedPoints;

// Organizes the rows r with r % step == 0 and, of those, keeps the columns c with c % step == 0: the points of
// other rows never meet those cells (a point takes its own cell or a free neighbour in its row), so the image
// equals downsample(full image, step) without the work for the dropped rows.
template <typename T>
RangeImage organize_points_impl(const T* data, size_t count, size_t stride, const std::int32_t* ring,
                                const SensorModel& model, const RangeLimits& limits, int step, OrganizeStats* stats) {
  validate_sensor_model(model);
  validate_range_limits(limits);
  if (step < 1) throw std::invalid_argument("downsample: step must be >= 1");
  if (stride < 3) throw std::invalid_argument("points: stride must be >= 3 (x, y, z per point)");
  if (count > static_cast<size_t>(std::numeric_limits<std::int32_t>::max()))
    throw std::invalid_argument("points: too many points");
  if (count > 0 && data == nullptr) throw std::invalid_argument("points: null data");

  OrganizeStats st;
  st.input_points = count;
  const int rows = model.rows, cols = model.cols;
  const PointRows point_rows = organize_detail::assign_rows(data, count, stride, ring, model, &st);
  const std::uint8_t* ok = point_rows.ok.data();

  // Cells of the kept rows at full column resolution: the input point in each (-1 = free). Rings one at a time
  // (a point only meets cells of its own row), else all kept rows at once.
  const bool by_ring = !point_rows.ring_start.empty();
  const int out_rows = (rows + step - 1) / step, out_cols = (cols + step - 1) / step;
  std::vector<std::int32_t> cell_point(static_cast<size_t>(by_ring ? 1 : out_rows) * cols, -1);
  const double cols_per_rad = cols / (2.0 * kPi);
  auto range_of = [&](size_t i) {
    const T* p = data + i * stride;
    return Vec3(p[0], p[1], p[2]).norm();
  };
  // Point i (valid, column coordinate u, range) into the cells of its row (nullptr: in no row, only counted).
  auto place = [&](size_t i, std::int32_t* row_cells, double u, double range) {
    if (range < limits.min_range || range > limits.max_range) {
      ++st.out_of_range;
      return;
    }
    if (row_cells == nullptr) return;
    int c = static_cast<int>(u);  // u in [0, cols] up to the float rounding of pi
    const double floor_u = static_cast<double>(c) - (static_cast<double>(c) > u ? 1.0 : 0.0);  // std::floor(u)
    // Azimuths of one ring are not exactly on a grid: a taken cell sends the point to the free neighbour on
    // its side, then to the other; with all three taken the nearer point keeps the cell. Selects, not
    // branches: which cells are taken is unpredictable.
    const int side = (u - floor_u < 0.5) ? -1 : 1;
    int n1, n2;
    if (c >= 1 && c <= cols - 2) {  // neither c nor its neighbours wrap around (all but the edge columns)
      n1 = c + side;
      n2 = c - side;
    } else {
      if (c >= cols) c -= cols;
      if (c < 0) c += cols;
      n1 = c + side;
      n2 = c - side;
      n1 += n1 < 0 ? cols : 0;
      n1 -= n1 >= cols ? cols : 0;
      n2 += n2 < 0 ? cols : 0;
      n2 -= n2 >= cols ? cols : 0;
    }
    const bool free_c = row_cells[c] < 0, free_1 = row_cells[n1] < 0, free_2 = row_cells[n2] < 0;
    const int cell = free_c ? c : free_1 ? n1 : free_2 ? n2 : c;
    if (!(free_c | free_1 | free_2)) {
      ++st.cell_collisions;
      if (range >= range_of(static_cast<size_t>(row_cells[c]))) return;
    }
    row_cells[cell] = static_cast<std::int32_t>(i);
  };

  // Valid points of a span in input order as arrays, their columns and ranges in one vectorized pass.
  size_t capacity = 0;
  if (by_ring) {
    for (int row = 0; row < rows; row += step) {
      const int k = point_rows.flipped ? rows - 1 - row : row;
      capacity = std::max(capacity, point_rows.ring_start[k + 1] - point_rows.ring_start[k]);
    }
  } else {
    capacity = count;
  }
  // (written before read: no zeroing)
  const std::unique_ptr<std::int32_t[]> index(new std::int32_t[std::max<size_t>(capacity, 1)]);
  const std::unique_ptr<double[]> columns(new double[std::max<size_t>(5 * capacity, 1)]);
  double* const X = columns.get();
  double* const Y = X + capacity;
  double* const Z = Y + capacity;
  double* const U = Z + capacity;
  double* const R = U + capacity;
  size_t gathered = 0;
  auto gather = [&](size_t begin, size_t end, auto keep) {
    gathered = 0;
    for (size_t i = begin; i < end; ++i) {
      if (!ok[i] || !keep(i)) continue;
      const T* p = data + i * stride;
      index[gathered] = static_cast<std::int32_t>(i);
      X[gathered] = p[0], Y[gathered] = p[1], Z[gathered] = p[2];
      ++gathered;
    }
    column_and_range(PointArrays{X, Y, Z}, 0, static_cast<int>(gathered), cols_per_rad, U, R);
  };

  RangeImage img;
  img.rows = out_rows;
  img.cols = out_cols;
  const size_t n_out = static_cast<size_t>(out_rows) * out_cols;
  img.points.resize(n_out);
  img.valid.resize(n_out);
  img.source_index.resize(n_out);
  // Row `out_row` of the image from its cells (every step-th column).
  auto fill_row = [&](int out_row, const std::int32_t* row_cells) {
    for (int c = 0; c < out_cols; ++c) {
      const size_t cell = static_cast<size_t>(out_row) * out_cols + c;
      const std::int32_t i = row_cells[static_cast<size_t>(c) * step];
      img.source_index[cell] = i;
      img.valid[cell] = i >= 0;
      if (i >= 0) {
        const T* p = data + static_cast<size_t>(i) * stride;
        img.points[cell] = Vec3(p[0], p[1], p[2]);
        ++st.kept_points;
      } else {
        img.points[cell] = Vec3::Zero();
      }
    }
  };

  if (by_ring) {
    std::int32_t* const row_cells = cell_point.data();
    for (int out_row = 0; out_row < out_rows; ++out_row) {
      const int row = out_row * step;
      const int k = point_rows.flipped ? rows - 1 - row : row;
      if (out_row > 0) std::fill(cell_point.begin(), cell_point.end(), -1);
      // the ring's points straight from the input (no gather; invalid ones get columns that are not used)
      const size_t begin = point_rows.ring_start[k], end = point_rows.ring_start[k + 1];
      column_and_range(StridedPoints<T>{data, stride}, begin, static_cast<int>(end - begin), cols_per_rad, U, R);
      for (size_t i = begin; i < end; ++i)
        if (ok[i]) place(i, row_cells, U[i - begin], R[i - begin]);
      fill_row(out_row, row_cells);
    }
  } else {
    const std::vector<int>& row_of = point_rows.row_of;
    gather(0, count, [&](size_t i) { return row_of[i] < 0 || row_of[i] % step == 0; });
    for (size_t j = 0; j < gathered; ++j) {
      const int r = row_of[index[j]];
      place(index[j], r < 0 ? nullptr : cell_point.data() + static_cast<size_t>(r / step) * cols, U[j], R[j]);
    }
    for (int out_row = 0; out_row < out_rows; ++out_row)
      fill_row(out_row, cell_point.data() + static_cast<size_t>(out_row) * cols);
  }
  if (stats) *stats = st;
  return img;
}

}  // namespace

RangeImage organize_points(const float* data, size_t count, size_t stride, const std::int32_t* ring,
                           const SensorModel& model, const RangeLimits& limits, OrganizeStats* stats) {
  return organize_points_impl(data, count, stride, ring, model, limits, 1, stats);
}
RangeImage organize_points(const double* data, size_t count, size_t stride, const std::int32_t* ring,
                           const SensorModel& model, const RangeLimits& limits, OrganizeStats* stats) {
  return organize_points_impl(data, count, stride, ring, model, limits, 1, stats);
}
RangeImage organize_points_downsampled(const float* data, size_t count, size_t stride, const std::int32_t* ring,
                                       const SensorModel& model, const RangeLimits& limits, int step,
                                       OrganizeStats* stats) {
  return organize_points_impl(data, count, stride, ring, model, limits, step, stats);
}
RangeImage organize_points_downsampled(const double* data, size_t count, size_t stride, const std::int32_t* ring,
                                       const SensorModel& model, const RangeLimits& limits, int step,
                                       OrganizeStats* stats) {
  return organize_points_impl(data, count, stride, ring, model, limits, step, stats);
}

}  // namespace line_odom
