// The per-point loops of organizing an unorganized cloud, each with a scalar copy and an AVX2 copy (no FMA) computing
// the same IEEE operations, picked at run time: the column coordinate and the range of points, and one pass over a
// block of points for validity, elevation and the pairs where a ring may wrap. Also the exact ring-wrap test they
// stand in for.
#pragma once

#include <algorithm>
#include <cmath>
#include <cstddef>
#include <cstdint>

#include "common/types.hpp"

namespace line_odom::organize_detail {

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
// |p| of points [begin, begin + n) into U and R. Points: PointArrays or StridedPoints<float / double>.
template <typename Points>
void column_and_range(const Points& pts, std::size_t begin, int n, double cols_per_rad, double* U, double* R);

inline bool finite_nonzero(double x, double y, double z) {
  return std::isfinite(x) && std::isfinite(y) && std::isfinite(z) && (x != 0.0 || y != 0.0 || z != 0.0);
}

// Azimuth in [0, 2pi) as the ring-wrap test has always read it: fast_atan2 stored as a float.
inline double wrap_azimuth(double x, double y) {
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
inline bool ring_wraps(double px, double py, double ax, double ay) {
  constexpr double kMarginSine = kWrapMarginSine;
  const double sp = std::abs(px) + std::abs(py), sa = std::abs(ax) + std::abs(ay);
  // a clearly below the axis (azimuth > pi) or p clearly above it (< pi): no wrap, the common case
  if (ay < -kMarginSine * sa || py > kMarginSine * sp) return false;
  const double cross = ax * py - ay * px;
  if (std::abs(py) > kMarginSine * sp && std::abs(ay) > kMarginSine * sa && std::abs(cross) > kMarginSine * sp * sa)
    return py < 0.0 && ay > 0.0 && cross < 0.0;
  return wrap_azimuth(ax, ay) < wrap_azimuth(px, py) - kPi;
}

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
// With AVX2 four points at a time, the elevation sums then added in another order (which their use allows).
// T: float or double.
template <typename T>
BlockScan scan_block(const T* p, int n, std::size_t stride, bool check_first, bool prev_above, std::uint8_t* ok,
                     double* el);

}  // namespace line_odom::organize_detail
