// The arithmetic of the scan-line fitter (scan_line_fitter.cpp), inlined into it: scalar squared norms and
// distances in the operation order of Eigen's, and the loops over four points at a time (the farthest point from a
// chord, a merge's clear accept / reject cases, the breaks between neighbouring points). Each decides on squared
// quantities the cases that are clear by a relative margin, with the same IEEE operations as the scalar tests, and
// leaves the close ones to the caller's exact test: the decisions are the same bit for bit.
#pragma once

#include <cstdint>
#include <cstring>

#include "common/simd.hpp"
#include "common/types.hpp"
#include "features/line_least_squares.hpp"
#include "features/scan_line_buffer.hpp"

namespace line_odom::line_fit_detail {

using simd::any;
using simd::F4;
using simd::I4;
using simd::kLanes;
using simd::load4;

// Scalar forms of |v|^2 and |(p - c) x d|^2 with the same operations, in the same order, as Eigen's
// squaredNorm() and cross() on Vec3 (which pack a temporary through memory, a store-forwarding stall).
inline double squared_norm(double x, double y, double z) { return x * x + y * y + z * z; }
inline double squared_norm(const Vec3& v) { return squared_norm(v.x(), v.y(), v.z()); }
inline double cross_squared_norm(double rx, double ry, double rz, const Vec3& d) {
  return squared_norm(ry * d.z() - rz * d.y(), rz * d.x() - rx * d.z(), rx * d.y() - ry * d.x());
}
inline double distance2(const Vec3& p, const Vec3& c, const Vec3& d) {  // |(p - c) x d|^2
  return cross_squared_norm(p.x() - c.x(), p.y() - c.y(), p.z() - c.z(), d);
}

// Index (1..n) of the largest ratio above 1 of the squared distances of points 1..n of X/Y/Z to the chord from
// point 0 to point n+1 over their squared thresholds (times W), -1 if none; ties: the first. The ratios are >= +0
// (squares times positive factors; a NaN from absurd scales counts by its bits), so they order as their bit
// patterns do: each lane keeps its largest bits and their first index. Reads up to kPad - 1 elements past
// X0[n+1] / W[n-1] (masked out).
inline __attribute__((always_inline)) int farthest_from_chord(const double* __restrict X0,
                                                              const double* __restrict Y0,
                                                              const double* __restrict Z0,
                                                              const double* __restrict W, int n) {
  const double ax = X0[0], ay = Y0[0], az = Z0[0];
  const double cx = X0[n + 1] - ax, cy = Y0[n + 1] - ay, cz = Z0[n + 1] - az;
  const double len2 = cx * cx + cy * cy + cz * cz;
  const double* __restrict X = X0 + 1;
  const double* __restrict Y = Y0 + 1;
  const double* __restrict Z = Z0 + 1;
  std::int64_t top = 0;
  int at = 0;
  if (!(len2 > 1e-24)) {  // degenerate chord: distances to its first point
    for (int i = 0; i < n; ++i) {
      const double rx = X[i] - ax, ry = Y[i] - ay, rz = Z[i] - az;
      const double r = (rx * rx + ry * ry + rz * rz) * W[i];
      std::int64_t b;
      std::memcpy(&b, &r, sizeof b);
      if (b > top) top = b, at = i;
    }
  } else {
    const double inv_len2 = 1.0 / len2;
    I4 best = {0, 0, 0, 0}, best_at = {0, 0, 0, 0}, index = {0, 1, 2, 3};
    const I4 count = {n, n, n, n};
    // whole groups of four, then the last partial group with its lanes past n masked to 0
    auto step = [&](int i, bool partial) __attribute__((always_inline)) {
      const F4 rx = load4(X + i) - ax, ry = load4(Y + i) - ay, rz = load4(Z + i) - az;
      const F4 ux = ry * cz - rz * cy, uy = rz * cx - rx * cz, uz = rx * cy - ry * cx;
      const F4 r = (ux * ux + uy * uy + uz * uz) * (inv_len2 * load4(W + i));
      I4 bits;
      std::memcpy(&bits, &r, sizeof bits);
      if (partial) bits &= index < count;
      const I4 more = bits > best;
      best = more ? bits : best;
      best_at = more ? index : best_at;
      index += kLanes;
    };
    const int whole = n - n % kLanes;
    for (int i = 0; i < whole; i += kLanes) step(i, false);
    if (whole < n) step(whole, true);
    std::int64_t one;
    const double one_value = 1.0;
    std::memcpy(&one, &one_value, sizeof one);
    if (!any(best > one)) return -1;  // no ratio above 1: no split (most calls)
    // across the lanes, without branches: the largest bits, at the smallest index among the lanes holding them
    for (const int stride : {2, 1}) {  // lanes exchanged with the lane `stride` away: (2 3 0 1), then (1 0 3 2)
      const I4 other = {best[stride], best[1 ^ stride], best[2 ^ stride], best[3 ^ stride]};
      const I4 other_at = {best_at[stride], best_at[1 ^ stride], best_at[2 ^ stride], best_at[3 ^ stride]};
      const I4 take = (other > best) | ((other == best) & (other_at < best_at));
      best = take ? other : best;
      best_at = take ? other_at : best_at;
    }
    top = best[0];
    at = static_cast<int>(best_at[0]);
  }
  double worst;
  std::memcpy(&worst, &top, sizeof worst);
  return worst > 1.0 ? 1 + at : -1;
}

constexpr double kMargin = 1e-9;  // relative margin of the squared decision tests (ScanLineFitter::breaks_between)

// The clear cases of try_merge's test of points k..k+len-1 (len <= 4) against the prefit line (centroid c,
// unnormalized direction u): e = |(p - c) x u|^2 / tau^2 against |u|^2 (1 +- kMargin), the same IEEE operations as
// distance2 and excess2 lane by lane. 1: a point is clearly outside; 2: a point is close to the margin (the caller
// decides exactly); 0: all clearly inside.
inline __attribute__((always_inline)) int prefit_verdict(const ScanBuffer& buf, int k, int len, const LinePrefit& pre) {
  const double cx = pre.centroid.x(), cy = pre.centroid.y(), cz = pre.centroid.z();
  const double ux = pre.u.x(), uy = pre.u.y(), uz = pre.u.z();
  const F4 rx = load4(buf.x.data() + k) - cx, ry = load4(buf.y.data() + k) - cy, rz = load4(buf.z.data() + k) - cz;
  const F4 vx = ry * uz - rz * uy, vy = rz * ux - rx * uz, vz = rx * uy - ry * ux;
  const F4 e = (vx * vx + vy * vy + vz * vz) * load4(buf.inv_tau2.data() + k);
  const I4 lane = {0, 1, 2, 3};
  const I4 valid = lane < len;
  const I4 out = e > pre.norm2 * (1.0 + kMargin);
  const I4 in = e < pre.norm2 * (1.0 - kMargin);
  if (any(out & valid)) return 1;
  return any(~(out | in) & valid) ? 2 : 0;
}

// The clear cases of ScanLineFitter::breaks_between for every pair of neighbouring points (j - 1, j), j = 1..n-1,
// in one vectorizable pass (the same IEEE operations): code[j] 1 = break, 0 = none, 2 = close to a margin (the
// caller decides it exactly).
inline void break_codes(const double* __restrict X, const double* __restrict Y, const double* __restrict Z,
                 const double* __restrict T, const int* __restrict P, int n, int max_gap, double sin2,
                 std::int32_t* __restrict code) {
  for (int j = 1; j < n; ++j) {
    const double sx = X[j] - X[j - 1], sy = Y[j] - Y[j - 1], sz = Z[j] - Z[j - 1];
    const double len2 = sx * sx + sy * sy + sz * sz;
    const double tau = T[j - 1] < T[j] ? T[j] : T[j - 1];
    const double tau2 = tau * tau;
    const double wx = X[j - 1] + X[j], wy = Y[j - 1] + Y[j], wz = Z[j - 1] + Z[j];
    const double cx = sy * wz - sz * wy, cy = sz * wx - sx * wz, cz = sx * wy - sy * wx;
    const double lhs = cx * cx + cy * cy + cz * cz;
    const double rhs = sin2 * len2 * (wx * wx + wy * wy + wz * wz);
    // gap ? 1 : quiet ? 0 : near_tau ? 2 : jump ? 1 : smooth ? 0 : 2, without branches
    const int gap = P[j] - P[j - 1] - 1 > max_gap;
    const int quiet = len2 < tau2 * (1.0 - kMargin);
    const int near_tau = len2 <= tau2 * (1.0 + kMargin);
    const int jump = lhs < rhs * (1.0 - kMargin);
    const int smooth = lhs > rhs * (1.0 + kMargin);
    const int far = jump | ((1 - jump) & (1 - smooth)) << 1;
    const int loud = near_tau << 1 | (1 - near_tau) * far;
    code[j] = gap | (1 - gap) * (1 - quiet) * loud;
  }
}

}  // namespace line_odom::line_fit_detail
