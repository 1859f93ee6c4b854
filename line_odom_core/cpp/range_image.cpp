#include "range_image.hpp"

#include <algorithm>
#include <cmath>
#include <functional>
#include <limits>
#include <stdexcept>

namespace line_odom {

namespace {

constexpr double kPi = 3.14159265358979323846;
constexpr double kDeg = kPi / 180.0;

// Median elevation (deg) of each HDL-64E ring over the 30 shared KITTI scans, rings recovered from the
// azimuth wrap. KITTI's per-point elevations scatter by more than the beam spacing (intrinsic calibration,
// beam offsets), which is why the ring order is preferred whenever it is available.
constexpr double kKittiHdl64ElevationsDeg[64] = {
    2.630,   2.264,   2.023,   1.580,   1.288,   0.874,   0.605,   0.220,   -0.118,  -0.535,  -0.834,
    -1.174,  -1.548,  -1.875,  -2.171,  -2.525,  -2.833,  -3.228,  -3.512,  -3.906,  -4.204,  -4.576,
    -4.879,  -5.181,  -5.546,  -5.859,  -6.161,  -6.435,  -6.803,  -7.158,  -7.389,  -7.764,  -8.382,
    -8.901,  -9.361,  -9.751,  -10.214, -10.807, -11.301, -11.726, -12.179, -12.600, -13.137, -13.649,
    -14.224, -14.663, -15.152, -15.527, -16.157, -16.677, -17.246, -17.707, -18.202, -18.624, -19.058,
    -19.618, -20.112, -20.766, -21.227, -21.647, -22.071, -22.705, -23.152, -23.682};

// atan2 within 2e-6 rad (an odd degree-11 polynomial for atan on [0, 1], fitted minimax to atan here): the
// azimuth only picks a column (0.18 deg wide) and detects ring wraps, and libm's atan2 was a third of the time.
double fast_atan2(double y, double x) {
  const double ax = std::abs(x), ay = std::abs(y);
  const double hi = std::max(ax, ay), lo = std::min(ax, ay);
  if (hi == 0.0) return 0.0;
  const double a = lo / hi, s = a * a;
  double r = a * (0.99997722 + s * (-0.33262284 + s * (0.1935404 + s * (-0.11642649 + s * (0.05264734 +
                                                                                          s * -0.01171912)))));
  if (ay > ax) r = 0.5 * kPi - r;
  if (x < 0.0) r = kPi - r;
  return y < 0.0 ? -r : r;
}

bool finite_nonzero(double x, double y, double z) {
  return std::isfinite(x) && std::isfinite(y) && std::isfinite(z) && (x != 0.0 || y != 0.0 || z != 0.0);
}

void validate_model(const SensorModel& m) {
  if (m.rows < 1 || m.cols < 1)
    throw std::invalid_argument("sensor model '" + m.name + "': rows and cols must be >= 1");
  if (!m.beam_elevations.empty()) {
    if (static_cast<int>(m.beam_elevations.size()) != m.rows)
      throw std::invalid_argument("sensor model '" + m.name + "': beam_elevations needs one entry per row");
    for (size_t i = 1; i < m.beam_elevations.size(); ++i)
      if (!(m.beam_elevations[i] < m.beam_elevations[i - 1]))
        throw std::invalid_argument("sensor model '" + m.name + "': beam_elevations must strictly decrease");
  } else if (m.rows > 1 && !(m.max_elevation > m.min_elevation)) {
    throw std::invalid_argument("sensor model '" + m.name + "': max_elevation must exceed min_elevation");
  }
}

void validate_limits(const RangeLimits& l) {
  if (!(l.min_range >= 0.0) || !(l.max_range > l.min_range))
    throw std::invalid_argument("range limits: expected 0 <= min_range < max_range");
}

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

template <typename T>
RangeImage organize_points_impl(const T* data, size_t count, size_t stride, const std::int32_t* ring,
                                const SensorModel& model, const RangeLimits& limits, OrganizeStats* stats) {
  validate_model(model);
  validate_limits(limits);
  if (stride < 3) throw std::invalid_argument("points: stride must be >= 3 (x, y, z per point)");
  if (count > static_cast<size_t>(std::numeric_limits<std::int32_t>::max()))
    throw std::invalid_argument("points: too many points");
  if (count > 0 && data == nullptr) throw std::invalid_argument("points: null data");

  OrganizeStats st;
  st.input_points = count;
  const int rows = model.rows, cols = model.cols;

  // Row of every point (-1 = drop). Invalid points are holes regardless of the row method.
  std::vector<int> row_of(count, -1);
  std::vector<std::uint8_t> ok(count, 0);
  std::vector<float> azimuth(count, 0.0f);  // atan2(y, x), computed once
  for (size_t i = 0; i < count; ++i) {
    const T* p = data + i * stride;
    ok[i] = finite_nonzero(p[0], p[1], p[2]);
    if (!ok[i]) {
      ++st.invalid_points;
      continue;
    }
    azimuth[i] = static_cast<float>(fast_atan2(static_cast<double>(p[1]), static_cast<double>(p[0])));
  }

  bool rows_assigned = false;
  bool check_orientation = false;
  if (ring != nullptr) {
    for (size_t i = 0; i < count; ++i) {
      if (ring[i] < 0 || ring[i] >= rows)
        throw std::invalid_argument("ring: value " + std::to_string(ring[i]) + " at point " + std::to_string(i) +
                                    " outside [0, " + std::to_string(rows) + ") of sensor model '" + model.name +
                                    "'");
      row_of[i] = ring[i];
    }
    st.row_method = "ring";
    rows_assigned = true;
    check_orientation = true;
  } else if (model.ring_order_from_azimuth_wrap) {
    int r = 0;
    double prev = -1.0;
    for (size_t i = 0; i < count; ++i) {
      if (!ok[i]) continue;
      double az = azimuth[i];
      if (az < 0.0) az += 2.0 * kPi;
      if (prev >= 0.0 && az < prev - kPi) ++r;
      prev = az;
      row_of[i] = r;
    }
    if (r + 1 == rows) {
      st.row_method = "azimuth_wrap";
      rows_assigned = true;
      check_orientation = true;
    } else {
      std::fill(row_of.begin(), row_of.end(), -1);
    }
  }
  if (!rows_assigned) {
    const ElevationToRow to_row(model);
    for (size_t i = 0; i < count; ++i) {
      if (!ok[i]) continue;
      const T* p = data + i * stride;
      const double x = p[0], y = p[1], z = p[2];
      row_of[i] = to_row(std::atan2(z, std::hypot(x, y)));
      if (row_of[i] < 0) ++st.outside_rows;
    }
    st.row_method = "elevation";
  }

  // Ring indices may count from the bottom beam (Velodyne drivers) or the top one (Ouster, KITTI order):
  // flip when the first half of the rows is on average lower than the second.
  if (check_orientation && rows > 1) {
    double sum_lo = 0.0, sum_hi = 0.0;
    size_t n_lo = 0, n_hi = 0;
    for (size_t i = 0; i < count; ++i) {
      if (!ok[i]) continue;
      const T* p = data + i * stride;
      const double x = p[0], y = p[1], z = p[2];
      const double el = z / std::sqrt(x * x + y * y + z * z);  // sine of the elevation
      if (row_of[i] < rows / 2) {
        sum_lo += el;
        ++n_lo;
      } else {
        sum_hi += el;
        ++n_hi;
      }
    }
    if (n_lo > 0 && n_hi > 0 && sum_lo / n_lo < sum_hi / n_hi)
      for (auto& r : row_of)
        if (r >= 0) r = rows - 1 - r;
  }

  RangeImage img = empty_image(rows, cols, true);
  std::vector<double> cell_range(static_cast<size_t>(rows) * cols, 0.0);
  const double cols_per_rad = cols / (2.0 * kPi);
  for (size_t i = 0; i < count; ++i) {
    if (!ok[i]) continue;
    const T* p = data + i * stride;
    const Vec3 x(p[0], p[1], p[2]);
    const double range = x.norm();
    if (range < limits.min_range || range > limits.max_range) {
      ++st.out_of_range;
      continue;
    }
    const int r = row_of[i];
    if (r < 0) continue;
    const double u = (kPi - azimuth[i]) * cols_per_rad;  // [0, cols]
    int c = static_cast<int>(u);
    if (c >= cols) c -= cols;
    if (c < 0) c += cols;
    size_t cell = static_cast<size_t>(r) * cols + c;
    if (img.valid[cell]) {
      // Azimuths of one ring are not exactly on a grid: use the free neighbour on the point's side, then
      // the other; else keep the nearer point.
      const int first = (u - std::floor(u) < 0.5) ? -1 : 1;
      bool placed = false;
      for (int side : {first, -first}) {
        const int cn = (c + side + cols) % cols;
        const size_t celln = static_cast<size_t>(r) * cols + cn;
        if (!img.valid[celln]) {
          cell = celln;
          placed = true;
          break;
        }
      }
      if (!placed) {
        ++st.cell_collisions;
        if (range >= cell_range[cell]) continue;
        --st.kept_points;  // replaced below
      }
    }
    img.points[cell] = x;
    img.valid[cell] = 1;
    img.source_index[cell] = static_cast<std::int32_t>(i);
    cell_range[cell] = range;
    ++st.kept_points;
  }
  if (stats) *stats = st;
  return img;
}

template <typename T>
RangeImage organize_cloud_impl(const T* data, int rows, int cols, size_t stride, const RangeLimits& limits,
                               OrganizeStats* stats) {
  validate_limits(limits);
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
    if (!finite_nonzero(p[0], p[1], p[2])) {
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

SensorModel sensor_preset(const std::string& name) {
  SensorModel m;
  if (name == "hdl64" || name == "kitti" || name == "kitti_hdl64") {
    m.name = "hdl64";
    m.rows = 64;
    m.cols = 2048;
    for (double e : kKittiHdl64ElevationsDeg) m.beam_elevations.push_back(e * kDeg);
    m.max_elevation = m.beam_elevations.front();
    m.min_elevation = m.beam_elevations.back();
    m.ring_order_from_azimuth_wrap = true;
  } else if (name == "vlp16") {
    m.name = "vlp16";
    m.rows = 16;
    m.cols = 1800;  // 0.2 deg at 10 Hz
    m.max_elevation = 15.0 * kDeg;
    m.min_elevation = -15.0 * kDeg;
  } else if (name == "os128") {
    m.name = "os128";
    m.rows = 128;
    m.cols = 1024;
    m.max_elevation = 22.5 * kDeg;
    m.min_elevation = -22.5 * kDeg;
  } else {
    throw std::invalid_argument("sensor: unknown preset '" + name + "' (expected hdl64, kitti, vlp16, os128)");
  }
  return m;
}

std::vector<std::string> sensor_preset_names() { return {"hdl64", "kitti", "vlp16", "os128"}; }

RangeImage organize_points(const float* data, size_t count, size_t stride, const std::int32_t* ring,
                           const SensorModel& model, const RangeLimits& limits, OrganizeStats* stats) {
  return organize_points_impl(data, count, stride, ring, model, limits, stats);
}
RangeImage organize_points(const double* data, size_t count, size_t stride, const std::int32_t* ring,
                           const SensorModel& model, const RangeLimits& limits, OrganizeStats* stats) {
  return organize_points_impl(data, count, stride, ring, model, limits, stats);
}

RangeImage organize_cloud(const float* data, int rows, int cols, size_t stride, const RangeLimits& limits,
                          OrganizeStats* stats) {
  return organize_cloud_impl(data, rows, cols, stride, limits, stats);
}
RangeImage organize_cloud(const double* data, int rows, int cols, size_t stride, const RangeLimits& limits,
                          OrganizeStats* stats) {
  return organize_cloud_impl(data, rows, cols, stride, limits, stats);
}

RangeImage organize_depth(const float* depth, int rows, int cols, const Mat3& K, const RangeLimits& limits,
                          OrganizeStats* stats) {
  validate_limits(limits);
  if (rows < 1 || cols < 1) throw std::invalid_argument("depth: rows and cols must be >= 1");
  if (depth == nullptr) throw std::invalid_argument("depth: null data");
  const double fx = K(0, 0), fy = K(1, 1), cx = K(0, 2), cy = K(1, 2);
  if (!K.allFinite() || !(fx > 0.0) || !(fy > 0.0))
    throw std::invalid_argument("K: expected finite intrinsics with fx > 0 and fy > 0");
  OrganizeStats st;
  st.row_method = "depth";
  RangeImage img = empty_image(rows, cols, false);
  st.input_points = static_cast<size_t>(rows) * cols;
  for (int v = 0; v < rows; ++v) {
    const double ry = (v - cy) / fy;
    for (int u = 0; u < cols; ++u) {
      const size_t i = static_cast<size_t>(v) * cols + u;
      const double z = depth[i];
      if (!std::isfinite(z) || z <= 0.0) {
        ++st.invalid_points;
        continue;
      }
      if (z < limits.min_range || z > limits.max_range) {
        ++st.out_of_range;
        continue;
      }
      img.points[i] = Vec3((u - cx) / fx * z, ry * z, z);
      img.valid[i] = 1;
      ++st.kept_points;
    }
  }
  if (stats) *stats = st;
  return img;
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
