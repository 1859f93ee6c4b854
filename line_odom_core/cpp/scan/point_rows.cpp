#include "scan/point_rows.hpp"

#include <algorithm>
#include <cmath>
#include <functional>
#include <limits>
#include <stdexcept>
#include <string>

#include "scan/organize_kernels.hpp"

namespace line_odom::organize_detail {

namespace {

constexpr double kDeg = kPi / 180.0;

// Row of a point by elevation: nearest beam of the table (cells extend half a spacing beyond the outer
// beams) or of the uniform fan. -1 when outside.
class ElevationToRow {
 public:
  explicit ElevationToRow(const SensorModel& m) : m_(m) {
    if (!m.beam_elevations.empty()) {
      const auto& e = m.beam_elevations;
      for (size_t i = 0; i + 1 < e.size(); ++i) bounds_.push_back(0.5 * (e[i] + e[i + 1]));  // decreasing
      const double top_half = e.size() > 1 ? 0.5 * (e[0] - e[1]) : 1.0 * kDeg;
      const double bottom_half = e.size() > 1 ? 0.5 * (e[e.size() - 2] - e.back()) : 1.0 * kDeg;
      top_ = e.front() + top_half;
      bottom_ = e.back() - bottom_half;
    } else {
      step_ = m.rows > 1 ? (m.max_elevation - m.min_elevation) / (m.rows - 1) : 1.0 * kDeg;
      top_ = m.max_elevation + 0.5 * step_;
      bottom_ = (m.rows > 1 ? m.min_elevation : m.max_elevation) - 0.5 * step_;
    }
  }
  int operator()(double elevation) const {
    if (!(elevation <= top_) || !(elevation >= bottom_)) return -1;
    if (!bounds_.empty()) {
      // first boundary below the elevation = row index
      const auto it = std::lower_bound(bounds_.begin(), bounds_.end(), elevation, std::greater<double>());
      return static_cast<int>(it - bounds_.begin());
    }
    const int r = static_cast<int>(std::lround((m_.max_elevation - elevation) / step_));
    return std::clamp(r, 0, m_.rows - 1);
  }

 private:
  const SensorModel& m_;
  std::vector<double> bounds_;
  double top_ = 0.0, bottom_ = 0.0, step_ = 0.0;
};

// Mean sine of the elevation over rows [0, rows/2) and [rows/2, rows), summed in point order.
struct HalfElevations {
  double sum_lo = 0.0, sum_hi = 0.0;
  size_t n_lo = 0, n_hi = 0;
  // Returns the point's sine of elevation.
  double add(bool low_half, double x, double y, double z) {
    const double el = z / std::sqrt(x * x + y * y + z * z);
    if (low_half) {
      sum_lo += el;
      ++n_lo;
    } else {
      sum_hi += el;
      ++n_hi;
    }
    return el;
  }
  // Ring indices may count from the bottom beam (Velodyne drivers) or the top one (Ouster, KITTI order):
  // flip when the first half of the rows is on average lower than the second.
  bool upside_down() const { return n_lo > 0 && n_hi > 0 && sum_lo / n_lo < sum_hi / n_hi; }
};

// Ring order by azimuth wraps in one pass over the points: validity, ring starts and the elevation sums of the
// orientation check. Blocks of points that are all valid and hold no possible wrap (ring_wraps' early exit holds
// for every consecutive pair) are taken whole; the others point by point as ring_wraps decides. The elevation
// sums here are added in another order than HalfElevations' (blocks, lanes), so they differ from its sums by
// rounding only: the orientation they give is taken when it clears that rounding bound by far, else the exact
// point-order sums decide (HalfElevations over the found rings), so `flipped` is always HalfElevations' answer.
// Returns the number of rings found (ring_start gets their starts and the end).
template <typename T>
int ring_order_scan(const T* data, size_t count, size_t stride, int rows, PointRows* out, OrganizeStats* st) {
  alignas(64) double el[kScanBlock];
  double sum_lo = 0.0, sum_hi = 0.0, sum_abs_lo = 0.0, sum_abs_hi = 0.0;
  size_t n_lo = 0, n_hi = 0;
  int r = 0;
  const T* prev = nullptr;
  bool prev_above = false;  // the point just before the block is clearly above the x axis
  out->ring_start.reserve(static_cast<size_t>(rows) + 2);
  out->ring_start.push_back(0);
  std::uint8_t* ok = out->ok.data();
  for (size_t b = 0; b < count; b += kScanBlock) {
    const int n = static_cast<int>(std::min<size_t>(kScanBlock, count - b));
    const T* p = data + b * stride;
    // prev is the point just before the block (valid) or there is none
    const bool prev_is_last = prev != nullptr && prev == p - stride;
    const BlockScan scan = scan_block(p, n, stride, prev_is_last, prev_above, ok + b, el);
    if (scan.all_ok && (prev == nullptr || prev_is_last)) {
      // Only the flagged pairs can wrap; the elevations of each stretch between wraps go to its ring's half.
      int stretch = 0;  // first point of the current stretch
      auto add_stretch = [&](int end, double sum, double sum_abs) {
        if (r < rows / 2) {
          sum_lo += sum, sum_abs_lo += sum_abs, n_lo += static_cast<size_t>(end - stretch);
        } else {
          sum_hi += sum, sum_abs_hi += sum_abs, n_hi += static_cast<size_t>(end - stretch);
        }
      };
      auto add_points = [&](int end) {
        double sum = 0.0, sum_abs = 0.0;
        for (int j = stretch; j < end; ++j) sum += el[j], sum_abs += std::abs(el[j]);
        add_stretch(end, sum, sum_abs);
      };
      bool wrapped = false;
      for (int w = 0; w < kScanBlock / 64 && scan.maybe_wrap; ++w)
        for (std::uint64_t bits = scan.wrap_bits[w]; bits != 0; bits &= bits - 1) {
          const int j = w * 64 + __builtin_ctzll(bits);
          const T* a = p + static_cast<size_t>(j) * stride;
          const T* before = j == 0 ? prev : a - stride;
          if (before == nullptr || !ring_wraps(before[0], before[1], a[0], a[1])) continue;
          add_points(j);
          wrapped = true;
          stretch = j;
          ++r;
          out->ring_start.push_back(b + static_cast<size_t>(j));
        }
      if (wrapped) add_points(n);
      else add_stretch(n, scan.sum_el, scan.sum_abs_el);
      prev = p + static_cast<size_t>(n - 1) * stride;
    } else {
      for (int j = 0; j < n; ++j) {
        const T* a = p + static_cast<size_t>(j) * stride;
        if (!ok[b + j]) {
          ++st->invalid_points;
          continue;
        }
        if (prev != nullptr && ring_wraps(prev[0], prev[1], a[0], a[1])) {
          ++r;
          out->ring_start.push_back(b + static_cast<size_t>(j));
        }
        prev = a;
        if (r < rows / 2) {
          sum_lo += el[j], sum_abs_lo += std::abs(el[j]), ++n_lo;
        } else {
          sum_hi += el[j], sum_abs_hi += std::abs(el[j]), ++n_hi;
        }
      }
    }
    prev_above = scan.last_above;
  }
  out->ring_start.push_back(count);
  if (r + 1 != rows || rows < 2) return r + 1;
  if (n_lo == 0 || n_hi == 0) {
    out->flipped = false;
    return r + 1;
  }
  // The el here are HalfElevations' values, summed in another order. Two summation orders of the same n terms
  // differ by at most 2 n u / (1 - n u) sum|el| (each is within gamma_n sum|el| of the exact sum, Higham
  // Thm 4.4); the divisions by the counts add u |mean| each, for ours and for HalfElevations'. The decision is
  // taken only when the gap of the means exceeds 4x all of that.
  constexpr double u = std::numeric_limits<double>::epsilon() / 2;
  const double nl = static_cast<double>(n_lo), nh = static_cast<double>(n_hi), nu = static_cast<double>(count) * u;
  const double mean_lo = sum_lo / nl, mean_hi = sum_hi / nh;
  const double err_lo = (2.01 * nu + 2.0 * u) * sum_abs_lo / nl;
  const double err_hi = (2.01 * nu + 2.0 * u) * sum_abs_hi / nh;
  const double gap = mean_hi - mean_lo;
  if (nu < 1e-3 && std::isfinite(gap) && std::isfinite(err_lo + err_hi) &&
      std::abs(gap) > 4.0 * (err_lo + err_hi) + 1e-300) {
    out->flipped = gap > 0.0;
    return r + 1;
  }
  HalfElevations half;
  for (int k = 0; k < rows; ++k)
    for (size_t i = out->ring_start[k]; i < out->ring_start[k + 1]; ++i) {
      if (!ok[i]) continue;
      const T* a = data + i * stride;
      half.add(k < rows / 2, a[0], a[1], a[2]);
    }
  out->flipped = half.upside_down();
  return r + 1;
}

// The row of each ring when the rings' numbers do not follow their elevations (a driver numbering its lasers in firing
// order: a VLP-16's interleave -15, +1, -13, +3 ... deg), else empty. The rows' V-lines run down the columns, so rows
// must follow elevation: each ring present takes the row of its rank by mean elevation (highest first) among the
// present rings' numbers. Rings numbered from the top or from the bottom are in order (HalfElevations flips those).
std::vector<int> rows_by_elevation(const std::vector<double>& elevation_sum, const std::vector<std::size_t>& points) {
  std::vector<int> present;
  for (int k = 0; k < static_cast<int>(points.size()); ++k)
    if (points[k] > 0) present.push_back(k);
  auto mean = [&](int k) { return elevation_sum[k] / static_cast<double>(points[k]); };
  bool falling = true, rising = true;
  for (std::size_t j = 1; j < present.size(); ++j) {
    falling = falling && mean(present[j]) <= mean(present[j - 1]);
    rising = rising && mean(present[j]) >= mean(present[j - 1]);
  }
  if (falling || rising) return {};
  std::vector<int> by_height = present;
  std::stable_sort(by_height.begin(), by_height.end(), [&](int a, int b) { return mean(a) > mean(b); });
  std::vector<int> row(points.size());
  for (int k = 0; k < static_cast<int>(row.size()); ++k) row[k] = k;  // rings without a point keep theirs
  for (std::size_t j = 0; j < present.size(); ++j) row[by_height[j]] = present[j];
  return row;
}

}  // namespace

template <typename T>
PointRows assign_rows(const T* data, std::size_t count, std::size_t stride, const std::int32_t* ring,
                      const SensorModel& model, OrganizeStats* st) {
  const int rows = model.rows;
  PointRows out;
  out.ok.resize(count);
  if (ring == nullptr && model.ring_order_from_azimuth_wrap) {
    if (ring_order_scan(data, count, stride, rows, &out, st) == rows) {
      st->row_method = "azimuth_wrap";
      return out;
    }
    out.flipped = false;
    out.ring_start.clear();
  } else {
    for (size_t i = 0; i < count; ++i) {
      const T* p = data + i * stride;
      out.ok[i] = finite_nonzero(p[0], p[1], p[2]);
      if (!out.ok[i]) ++st->invalid_points;
    }
  }

  out.row_of.assign(count, -1);
  if (ring != nullptr) {
    HalfElevations half;
    std::vector<double> elevation_sum(static_cast<std::size_t>(rows), 0.0);
    std::vector<std::size_t> ring_points(static_cast<std::size_t>(rows), 0);
    for (size_t i = 0; i < count; ++i) {
      if (ring[i] < 0 || ring[i] >= rows)
        throw std::invalid_argument("ring: value " + std::to_string(ring[i]) + " at point " + std::to_string(i) +
                                    " outside [0, " + std::to_string(rows) + ") of sensor model '" + model.name +
                                    (ring[i] >= rows ? "' (a sensor with more beams: set the preset or sensor.model / "
                                                       "sensor.rows to it)"
                                                     : "'"));
      out.row_of[i] = ring[i];
      const T* p = data + i * stride;
      if (!out.ok[i]) continue;
      elevation_sum[ring[i]] += half.add(ring[i] < rows / 2, p[0], p[1], p[2]);
      ++ring_points[ring[i]];
    }
    st->row_method = "ring";
    const std::vector<int> row_of_ring = rows_by_elevation(elevation_sum, ring_points);
    if (!row_of_ring.empty()) {
      for (auto& r : out.row_of) r = row_of_ring[r];
      st->row_method = "ring_by_elevation";
      return out;
    }
    if (rows > 1 && half.upside_down())
      for (auto& r : out.row_of) r = rows - 1 - r;
    return out;
  }
  const ElevationToRow to_row(model);
  for (size_t i = 0; i < count; ++i) {
    if (!out.ok[i]) continue;
    const T* p = data + i * stride;
    const double x = p[0], y = p[1], z = p[2];
    out.row_of[i] = to_row(std::atan2(z, std::hypot(x, y)));
    if (out.row_of[i] < 0) ++st->outside_rows;
  }
  st->row_method = "elevation";
  return out;
}

template PointRows assign_rows(const float*, std::size_t, std::size_t, const std::int32_t*, const SensorModel&,
                               OrganizeStats*);
template PointRows assign_rows(const double*, std::size_t, std::size_t, const std::int32_t*, const SensorModel&,
                               OrganizeStats*);

}  // namespace line_odom::organize_detail
