#include "scan/range_image.hpp"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <functional>
#include <limits>
#include <memory>
#include <stdexcept>
#include <type_traits>

#include "common/simd.hpp"

#ifdef LINE_ODOM_X86_DISPATCH
#include <immintrin.h>
#endif

namespace line_odom {

namespace {

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
inline double fast_atan2(double y, double x) {
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

// Points for column_and_range: three arrays, or xyz at p[i * stride].
struct PointArrays {
  const double *X, *Y, *Z;
  double x(size_t i) const { return X[i]; }
  double y(size_t i) const { return Y[i]; }
  double z(size_t i) const { return Z[i]; }
};
template <typename T>
struct StridedPoints {
  const T* p;
  size_t stride;
  double x(size_t i) const { return p[i * stride]; }
  double y(size_t i) const { return p[i * stride + 1]; }
  double z(size_t i) const { return p[i * stride + 2]; }
};

// Column coordinate u = (pi - azimuth) cols / 2pi (azimuth = fast_atan2 stored as a float, as always) and range
// |p| of points [begin, begin + n): the same IEEE operations per element as fast_atan2 and Vec3::norm, as selects.
template <typename Points>
void column_and_range_scalar(const Points& pts, size_t begin, int n, double cols_per_rad, double* U, double* R) {
  for (int i = 0; i < n; ++i) {
    const double x = pts.x(begin + i), y = pts.y(begin + i), z = pts.z(begin + i);
    R[i] = std::sqrt(x * x + y * y + z * z);
    const double ax = std::abs(x), ay = std::abs(y);
    const double hi = ax < ay ? ay : ax, lo = ay < ax ? ay : ax;
    const double a = lo / hi, s = a * a;
    double r = a * (0.99997722 + s * (-0.33262284 + s * (0.1935404 + s * (-0.11642649 + s * (0.05264734 +
                                                                                          s * -0.01171912)))));
    r = ay > ax ? 0.5 * kPi - r : r;
    r = x < 0.0 ? kPi - r : r;
    r = y < 0.0 ? -r : r;
    r = hi == 0.0 ? 0.0 : r;
    const double azimuth = static_cast<float>(r);
    U[i] = (kPi - azimuth) * cols_per_rad;
  }
}

#ifdef LINE_ODOM_X86_DISPATCH
bool have_avx2() {
  static const bool yes = (__builtin_cpu_init(), __builtin_cpu_supports("avx2") != 0);
  return yes;
}

// Points i .. i + 3 as doubles (exact for float input).
__attribute__((target("avx2"))) inline void load4(const PointArrays& pts, size_t i, __m256d* x, __m256d* y,
                                                  __m256d* z) {
  *x = _mm256_loadu_pd(pts.X + i);
  *y = _mm256_loadu_pd(pts.Y + i);
  *z = _mm256_loadu_pd(pts.Z + i);
}
__attribute__((target("avx2"))) inline __m256d load4(const double* a, size_t s1, size_t s2, size_t s3) {
  return _mm256_set_pd(a[s3], a[s2], a[s1], a[0]);
}
__attribute__((target("avx2"))) inline __m256d load4(const float* a, size_t s1, size_t s2, size_t s3) {
  return _mm256_cvtps_pd(_mm_set_ps(a[s3], a[s2], a[s1], a[0]));
}
template <typename T>
__attribute__((target("avx2"))) inline void load4(const StridedPoints<T>& pts, size_t i, __m256d* x, __m256d* y,
                                                  __m256d* z) {
  const T* a = pts.p + i * pts.stride;
  const size_t s1 = pts.stride, s2 = 2 * pts.stride, s3 = 3 * pts.stride;
  *x = load4(a, s1, s2, s3);
  *y = load4(a + 1, s1, s2, s3);
  *z = load4(a + 2, s1, s2, s3);
}

// column_and_range_scalar four points at a time (AVX2, no FMA): operation for operation, so the same values.
template <typename Points>
__attribute__((target("avx2"))) void column_and_range_avx2(const Points& pts, size_t begin, int n,
                                                           double cols_per_rad, double* U, double* R) {
  const __m256d zero = _mm256_setzero_pd();
  const __m256d sign = _mm256_set1_pd(-0.0);
  const __m256d pi = _mm256_set1_pd(kPi), half_pi = _mm256_set1_pd(0.5 * kPi), scale = _mm256_set1_pd(cols_per_rad);
  const __m256d c0 = _mm256_set1_pd(0.99997722), c1 = _mm256_set1_pd(-0.33262284), c2 = _mm256_set1_pd(0.1935404),
                c3 = _mm256_set1_pd(-0.11642649), c4 = _mm256_set1_pd(0.05264734), c5 = _mm256_set1_pd(-0.01171912);
  int i = 0;
  for (; i + 4 <= n; i += 4) {
    __m256d x, y, z;
    load4(pts, begin + static_cast<size_t>(i), &x, &y, &z);
    _mm256_storeu_pd(
        R + i, _mm256_sqrt_pd(_mm256_add_pd(_mm256_add_pd(_mm256_mul_pd(x, x), _mm256_mul_pd(y, y)),
                                            _mm256_mul_pd(z, z))));
    const __m256d ax = _mm256_andnot_pd(sign, x), ay = _mm256_andnot_pd(sign, y);
    const __m256d hi = _mm256_blendv_pd(ax, ay, _mm256_cmp_pd(ax, ay, _CMP_LT_OQ));
    const __m256d lo = _mm256_blendv_pd(ax, ay, _mm256_cmp_pd(ay, ax, _CMP_LT_OQ));
    const __m256d a = _mm256_div_pd(lo, hi), s = _mm256_mul_pd(a, a);
    __m256d t = _mm256_add_pd(c4, _mm256_mul_pd(s, c5));
    t = _mm256_add_pd(c3, _mm256_mul_pd(s, t));
    t = _mm256_add_pd(c2, _mm256_mul_pd(s, t));
    t = _mm256_add_pd(c1, _mm256_mul_pd(s, t));
    t = _mm256_add_pd(c0, _mm256_mul_pd(s, t));
    __m256d r = _mm256_mul_pd(a, t);
    r = _mm256_blendv_pd(r, _mm256_sub_pd(half_pi, r), _mm256_cmp_pd(ay, ax, _CMP_GT_OQ));
    r = _mm256_blendv_pd(r, _mm256_sub_pd(pi, r), _mm256_cmp_pd(x, zero, _CMP_LT_OQ));
    r = _mm256_blendv_pd(r, _mm256_xor_pd(r, sign), _mm256_cmp_pd(y, zero, _CMP_LT_OQ));
    r = _mm256_andnot_pd(_mm256_cmp_pd(hi, zero, _CMP_EQ_OQ), r);
    const __m256d azimuth = _mm256_cvtps_pd(_mm256_cvtpd_ps(r));
    _mm256_storeu_pd(U + i, _mm256_mul_pd(_mm256_sub_pd(pi, azimuth), scale));
  }
  column_and_range_scalar(pts, begin + static_cast<size_t>(i), n - i, cols_per_rad, U + i, R + i);
}
#endif

template <typename Points>
void column_and_range(const Points& pts, size_t begin, int n, double cols_per_rad, double* U, double* R) {
#ifdef LINE_ODOM_X86_DISPATCH
  if (have_avx2()) return column_and_range_avx2(pts, begin, n, cols_per_rad, U, R);
#endif
  column_and_range_scalar(pts, begin, n, cols_per_rad, U, R);
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

// Azimuth in [0, 2pi) as the ring-wrap test has always read it: fast_atan2 stored as a float.
double wrap_azimuth(double x, double y) {
  double az = static_cast<float>(fast_atan2(y, x));
  if (az < 0.0) az += 2.0 * kPi;
  return az;
}

// ring_wraps' margin: a point with |y| below it (relative to |x| + |y|) is "near the x axis".
constexpr double kWrapMarginSine = 1e-5;

// Does the ring wrap between the previous point p and the current point a, i.e. is azimuth(a) < azimuth(p) - pi?
// With azimuths in [0, 2pi) that holds exactly when p is below the x axis, a above it and a -> p turns clockwise
// (cross product < 0). Those signs decide unless a point or the angle between them is within ~1e-5 rad of a
// boundary; then the azimuths themselves decide (fast_atan2's 2e-6 rad error and the float rounding are far
// inside that margin), so the rings are exactly those of the azimuth test.
bool ring_wraps(double px, double py, double ax, double ay) {
  constexpr double kMarginSine = kWrapMarginSine;
  const double sp = std::abs(px) + std::abs(py), sa = std::abs(ax) + std::abs(ay);
  // a clearly below the axis (azimuth > pi) or p clearly above it (< pi): no wrap, the common case
  if (ay < -kMarginSine * sa || py > kMarginSine * sp) return false;
  const double cross = ax * py - ay * px;
  if (std::abs(py) > kMarginSine * sp && std::abs(ay) > kMarginSine * sa && std::abs(cross) > kMarginSine * sp * sa)
    return py < 0.0 && ay > 0.0 && cross < 0.0;
  return wrap_azimuth(ax, ay) < wrap_azimuth(px, py) - kPi;
}

// Rows of an unorganized cloud. Either ring by ring in input order (ring k = points [ring_start[k],
// ring_start[k + 1]), KITTI), or one row per point (row_of, -1 = none). Invalid points have ok = 0.
struct PointRows {
  std::vector<std::uint8_t> ok;
  std::vector<size_t> ring_start;  // rings.size() + 1 entries when rows come from the input order
  std::vector<int> row_of;
  bool flipped = false;            // row = rows - 1 - ring
};

// Mean sine of the elevation over rows [0, rows/2) and [rows/2, rows), summed in point order.
struct HalfElevations {
  double sum_lo = 0.0, sum_hi = 0.0;
  size_t n_lo = 0, n_hi = 0;
  void add(bool low_half, double x, double y, double z) {
    const double el = z / std::sqrt(x * x + y * y + z * z);
    if (low_half) {
      sum_lo += el;
      ++n_lo;
    } else {
      sum_hi += el;
      ++n_hi;
    }
  }
  // Ring indices may count from the bottom beam (Velodyne drivers) or the top one (Ouster, KITTI order):
  // flip when the first half of the rows is on average lower than the second.
  bool upside_down() const { return n_lo > 0 && n_hi > 0 && sum_lo / n_lo < sum_hi / n_hi; }
};

// Points per block of the ring-order scan (its per-point arrays stay in L1).
constexpr int kScanBlock = 256;

// What scan_block found in a block of points.
struct BlockScan {
  bool all_ok = true;       // every point finite and not all zero
  bool maybe_wrap = false;  // some consecutive pair fails ring_wraps' early exit (the ring may wrap there)
  std::uint64_t wrap_bits[kScanBlock / 64] = {};  // bit j: the pair (point j - 1, point j) may wrap
  bool last_above = false;  // the last point is clearly above the x axis
  double sum_el = 0.0, sum_abs_el = 0.0;  // of el over the block (any order)
};

// One block of n points (xyz at p[j * stride]) of the ring-order scan: ok[j] (finite and not all zero, as
// finite_nonzero), el[j] = z / |p| (as HalfElevations::add), and whether ring_wraps' early exit holds for each
// consecutive pair (the first point pairs with the point before the block when check_first; prev_above is that
// point's "clearly above"), with the same expressions as ring_wraps: below = y < -m (|x| + |y|), above = y > m (..).
template <typename T>
BlockScan scan_block_scalar(const T* p, int n, size_t stride, bool check_first, bool prev_above, std::uint8_t* ok,
                            double* el) {
  BlockScan out;
  bool above_before = check_first ? prev_above : true;
  for (int j = 0; j < n; ++j) {
    const T* a = p + static_cast<size_t>(j) * stride;
    const double x = a[0], y = a[1], z = a[2];
    ok[j] = finite_nonzero(x, y, z);
    out.all_ok &= ok[j] != 0;
    el[j] = z / std::sqrt(x * x + y * y + z * z);
    out.sum_el += el[j];
    out.sum_abs_el += std::abs(el[j]);
    const double s = std::abs(x) + std::abs(y);
    const bool below = y < -kWrapMarginSine * s, above = y > kWrapMarginSine * s;
    const bool maybe = !(below || above_before);
    out.maybe_wrap |= maybe;
    out.wrap_bits[j >> 6] |= static_cast<std::uint64_t>(maybe) << (j & 63);
    above_before = above;
  }
  out.last_above = above_before;
  return out;
}

#ifdef LINE_ODOM_X86_DISPATCH
// Bytes 0/1 of a 4-bit mask, lowest bit first in memory (little-endian).
constexpr std::uint32_t kMaskBytes[16] = {
    0x00000000, 0x00000001, 0x00000100, 0x00000101, 0x00010000, 0x00010001, 0x00010100, 0x00010101,
    0x01000000, 0x01000001, 0x01000100, 0x01000101, 0x01010000, 0x01010001, 0x01010100, 0x01010101};

// Four consecutive points (xyz at a[k * stride], stride = S when S > 0) as x, y, z doubles (exact). Packed
// layouts (float stride 3 and 4, double stride 3) load whole vectors and shuffle them apart.
template <int S, typename T>
__attribute__((target("avx2"))) inline void load_points4(const T* a, size_t stride, __m256d* x, __m256d* y,
                                                         __m256d* z) {
  const size_t s1 = stride, s2 = 2 * stride, s3 = 3 * stride;
  *x = load4(a, s1, s2, s3);
  *y = load4(a + 1, s1, s2, s3);
  *z = load4(a + 2, s1, s2, s3);
}
template <>
__attribute__((target("avx2"))) inline void load_points4<4, float>(const float* a, size_t, __m256d* x, __m256d* y,
                                                                   __m256d* z) {
  __m128 r0 = _mm_loadu_ps(a), r1 = _mm_loadu_ps(a + 4), r2 = _mm_loadu_ps(a + 8), r3 = _mm_loadu_ps(a + 12);
  _MM_TRANSPOSE4_PS(r0, r1, r2, r3);
  *x = _mm256_cvtps_pd(r0);
  *y = _mm256_cvtps_pd(r1);
  *z = _mm256_cvtps_pd(r2);
}
// Four packed xyz points v0 = x0 y0 z0 x1, v1 = y1 z1 x2 y2, v2 = z2 x3 y3 z3 apart into x, y, z.
__attribute__((target("avx2"))) inline void deinterleave_xyz4(__m256d v0, __m256d v1, __m256d v2, __m256d* x,
                                                              __m256d* y, __m256d* z) {
  const __m256d bx = _mm256_blend_pd(_mm256_blend_pd(v0, v1, 0x4), v2, 0x2);  // x0 x3 x2 x1
  const __m256d by = _mm256_blend_pd(_mm256_blend_pd(v0, v1, 0x9), v2, 0x4);  // y1 y0 y3 y2
  const __m256d bz = _mm256_blend_pd(_mm256_blend_pd(v0, v1, 0x2), v2, 0x9);  // z2 z1 z0 z3
  *x = _mm256_permute4x64_pd(bx, _MM_SHUFFLE(1, 2, 3, 0));
  *y = _mm256_permute4x64_pd(by, _MM_SHUFFLE(2, 3, 0, 1));
  *z = _mm256_permute4x64_pd(bz, _MM_SHUFFLE(3, 0, 1, 2));
}
template <>
__attribute__((target("avx2"))) inline void load_points4<3, float>(const float* a, size_t, __m256d* x, __m256d* y,
                                                                   __m256d* z) {
  // float -> double is exact: widen the three packed vectors, then take them apart as doubles.
  deinterleave_xyz4(_mm256_cvtps_pd(_mm_loadu_ps(a)), _mm256_cvtps_pd(_mm_loadu_ps(a + 4)),
                    _mm256_cvtps_pd(_mm_loadu_ps(a + 8)), x, y, z);
}
template <>
__attribute__((target("avx2"))) inline void load_points4<3, double>(const double* a, size_t, __m256d* x, __m256d* y,
                                                                    __m256d* z) {
  deinterleave_xyz4(_mm256_loadu_pd(a), _mm256_loadu_pd(a + 4), _mm256_loadu_pd(a + 8), x, y, z);
}

// scan_block_scalar four points at a time (AVX2, no FMA): ok, el and the flags are the same values; the sums are
// added in another order, which their use allows. S: the stride when known at compile time, else 0.
template <int S, typename T>
__attribute__((target("avx2"))) BlockScan scan_block_avx2(const T* p, int n, size_t stride, bool check_first,
                                                          bool prev_above, std::uint8_t* ok, double* el) {
  BlockScan out;
  const __m256d zero = _mm256_setzero_pd(), margin = _mm256_set1_pd(kWrapMarginSine),
                neg_margin = _mm256_set1_pd(-kWrapMarginSine);
  const __m256d abs_mask = _mm256_castsi256_pd(_mm256_set1_epi64x(0x7fffffffffffffffLL));
  __m256d sum = zero, sum_abs = zero;
  int ok_bits = 0xF;
  std::uint64_t wrap_words[kScanBlock / 64] = {};
  unsigned above_before = check_first ? (prev_above ? 1u : 0u) : 1u;
  int j = 0;
  if (S > 0) stride = S;
  for (; j + 4 <= n; j += 4) {
    __m256d x, y, z;
    load_points4<S>(p + static_cast<size_t>(j) * stride, stride, &x, &y, &z);
    const __m256d ax = _mm256_and_pd(x, abs_mask), ay = _mm256_and_pd(y, abs_mask);
    const __m256d sxy = _mm256_add_pd(ax, ay);
    // finite: (x - x) + (y - y) + (z - z) is 0, NaN when any is inf or NaN; not all zero (given finite): the sum
    // of the magnitudes is > 0 (a sum of non-negative numbers rounds to 0 only when all are 0)
    const __m256d finite =
        _mm256_cmp_pd(_mm256_add_pd(_mm256_add_pd(_mm256_sub_pd(x, x), _mm256_sub_pd(y, y)), _mm256_sub_pd(z, z)),
                      zero, _CMP_EQ_OQ);
    const __m256d nonzero = _mm256_cmp_pd(_mm256_add_pd(sxy, _mm256_and_pd(z, abs_mask)), zero, _CMP_GT_OQ);
    const int okm = _mm256_movemask_pd(_mm256_and_pd(finite, nonzero));
    ok_bits &= okm;
    const std::uint32_t ok4 = kMaskBytes[okm];
    std::memcpy(ok + j, &ok4, 4);
    const __m256d norm2 = _mm256_add_pd(_mm256_add_pd(_mm256_mul_pd(x, x), _mm256_mul_pd(y, y)), _mm256_mul_pd(z, z));
    const __m256d e = _mm256_div_pd(z, _mm256_sqrt_pd(norm2));
    _mm256_storeu_pd(el + j, e);
    sum = _mm256_add_pd(sum, e);
    sum_abs = _mm256_add_pd(sum_abs, _mm256_and_pd(e, abs_mask));
    const unsigned below = static_cast<unsigned>(_mm256_movemask_pd(_mm256_cmp_pd(y, _mm256_mul_pd(neg_margin, sxy), _CMP_LT_OQ)));
    const unsigned above = static_cast<unsigned>(_mm256_movemask_pd(_mm256_cmp_pd(y, _mm256_mul_pd(margin, sxy), _CMP_GT_OQ)));
    const unsigned maybe = ~(below | ((above << 1) | above_before)) & 0xFu;
    wrap_words[j >> 6] |= static_cast<std::uint64_t>(maybe) << (j & 63);
    above_before = (above >> 3) & 1u;
  }
  bool any_wrap = false;
  for (int w = 0; w < kScanBlock / 64; ++w) out.wrap_bits[w] = wrap_words[w], any_wrap |= wrap_words[w] != 0;
  alignas(32) double lanes[4], lanes_abs[4];
  _mm256_store_pd(lanes, sum);
  _mm256_store_pd(lanes_abs, sum_abs);
  out.sum_el = (lanes[0] + lanes[1]) + (lanes[2] + lanes[3]);
  out.sum_abs_el = (lanes_abs[0] + lanes_abs[1]) + (lanes_abs[2] + lanes_abs[3]);
  out.all_ok = ok_bits == 0xF;
  out.maybe_wrap = any_wrap;
  out.last_above = above_before != 0;
  if (j < n) {
    const BlockScan tail = scan_block_scalar(p + static_cast<size_t>(j) * stride, n - j, stride, true,
                                             above_before != 0, ok + j, el + j);
    // the tail (< 4 points) starts at a multiple of 4: its bits shift into place within one word
    out.wrap_bits[j >> 6] |= tail.wrap_bits[0] << (j & 63);
    out.all_ok &= tail.all_ok;
    out.maybe_wrap |= tail.maybe_wrap;
    out.last_above = tail.last_above;
    out.sum_el += tail.sum_el;
    out.sum_abs_el += tail.sum_abs_el;
  }
  return out;
}
#endif

template <typename T>
BlockScan scan_block(const T* p, int n, size_t stride, bool check_first, bool prev_above, std::uint8_t* ok,
                     double* el) {
#ifdef LINE_ODOM_X86_DISPATCH
  if (have_avx2()) {
    if (stride == 3) return scan_block_avx2<3>(p, n, stride, check_first, prev_above, ok, el);
    if (stride == 4 && std::is_same<T, float>::value)
      return scan_block_avx2<4>(p, n, stride, check_first, prev_above, ok, el);
    return scan_block_avx2<0>(p, n, stride, check_first, prev_above, ok, el);
  }
#endif
  return scan_block_scalar(p, n, stride, check_first, prev_above, ok, el);
}

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

template <typename T>
PointRows assign_rows(const T* data, size_t count, size_t stride, const std::int32_t* ring, const SensorModel& model,
                      OrganizeStats* st) {
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
    for (size_t i = 0; i < count; ++i) {
      if (ring[i] < 0 || ring[i] >= rows)
        throw std::invalid_argument("ring: value " + std::to_string(ring[i]) + " at point " + std::to_string(i) +
                                    " outside [0, " + std::to_string(rows) + ") of sensor model '" + model.name +
                                    (ring[i] >= rows ? "' (a sensor with more beams: set the preset or sensor.model / "
                                                       "sensor.rows to it)"
                                                     : "'"));
      out.row_of[i] = ring[i];
      const T* p = data + i * stride;
      if (out.ok[i]) half.add(ring[i] < rows / 2, p[0], p[1], p[2]);
    }
    st->row_method = "ring";
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

// Organizes the rows r with r % step == 0 and, of those, keeps the columns c with c % step == 0: the points of
// other rows never meet those cells (a point takes its own cell or a free neighbour in its row), so the image
// equals downsample(full image, step) without the work for the dropped rows.
template <typename T>
RangeImage organize_points_impl(const T* data, size_t count, size_t stride, const std::int32_t* ring,
                                const SensorModel& model, const RangeLimits& limits, int step, OrganizeStats* stats) {
  validate_model(model);
  validate_limits(limits);
  if (step < 1) throw std::invalid_argument("downsample: step must be >= 1");
  if (stride < 3) throw std::invalid_argument("points: stride must be >= 3 (x, y, z per point)");
  if (count > static_cast<size_t>(std::numeric_limits<std::int32_t>::max()))
    throw std::invalid_argument("points: too many points");
  if (count > 0 && data == nullptr) throw std::invalid_argument("points: null data");

  OrganizeStats st;
  st.input_points = count;
  const int rows = model.rows, cols = model.cols;
  const PointRows point_rows = assign_rows(data, count, stride, ring, model, &st);
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

// The kept pixels (every step-th row and column) of a depth image, back-projected; each written once.
RangeImage organize_depth_impl(const float* depth, int rows, int cols, const Mat3& K, const RangeLimits& limits,
                               int step, OrganizeStats* stats) {
  validate_limits(limits);
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
  return organize_depth_impl(depth, rows, cols, K, limits, 1, stats);
}
RangeImage organize_depth_downsampled(const float* depth, int rows, int cols, const Mat3& K,
                                      const RangeLimits& limits, int step, OrganizeStats* stats) {
  return organize_depth_impl(depth, rows, cols, K, limits, step, stats);
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
