// The row of every point of an unorganized cloud: from its ring field, from the order of the points (KITTI: ring by
// ring, a new ring where the azimuth wraps) or from its elevation against the sensor model's beams. Rings may count
// from the top or the bottom beam: row 0 is always the highest.
#pragma once

#include <cstddef>
#include <cstdint>
#include <vector>

#include "scan/range_image.hpp"

namespace line_odom::organize_detail {

// Rows of an unorganized cloud. Either ring by ring in input order (ring k = points [ring_start[k],
// ring_start[k + 1]), KITTI), or one row per point (row_of, -1 = none). Invalid points have ok = 0.
struct PointRows {
  std::vector<std::uint8_t> ok;
  std::vector<size_t> ring_start;  // rings.size() + 1 entries when rows come from the input order
  std::vector<int> row_of;
  bool flipped = false;            // row = rows - 1 - ring
};

// Throws std::invalid_argument on a ring value outside [0, model.rows), naming the point. Counts invalid points and
// points outside the beams in `st` and sets st->row_method. T: float or double.
template <typename T>
PointRows assign_rows(const T* data, std::size_t count, std::size_t stride, const std::int32_t* ring,
                      const SensorModel& model, OrganizeStats* st);

}  // namespace line_odom::organize_detail
