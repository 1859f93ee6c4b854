// Least-squares lines from the moment sums of their points (count, sum, sum of outer products): the centroid, the
// principal direction by power iteration and the rms of the orthogonal distances. Public: PointMoments and fit_line.
// line_fit_detail: the same fit from the 6 distinct entries of the outer sum, split in two halves, always inlined into
// the scan-line fitter (scan_line_fitter.cpp), whose hot loop runs it for every candidate merge.
#pragma once

#include <algorithm>
#include <cmath>

#include "common/simd.hpp"
#include "common/types.hpp"

namespace line_odom {

// Least-squares line through points: centroid, unit principal direction, rms of the orthogonal distances.
struct LineLeastSquares {
  Vec3 centroid = Vec3::Zero();
  Vec3 direction = Vec3::UnitX();
  double rms = 0.0;
  int count = 0;
};

// Moment sums of a point set, mergeable: count, sum, sum of outer products.
struct PointMoments {
  int count = 0;
  Vec3 sum = Vec3::Zero();
  Mat3 outer = Mat3::Zero();

  void add(const Vec3& p) {
    ++count;
    sum += p;
    outer.noalias() += p * p.transpose();
  }
  void add(const PointMoments& o) {
    count += o.count;
    sum += o.sum;
    outer += o.outer;
  }
  Vec3 mean() const { return count > 0 ? Vec3(sum / count) : Vec3::Zero(); }
  Mat3 covariance() const;  // (1/n) sum (p - mean)(p - mean)^T
};

// Principal direction by power iteration: scan-line pieces are elongated (second / first eigenvalue ~1e-3),
// so from a seed near the line (the chord) 3 iterations reach ~1e-9 rad, several times faster than the
// closed-form 3x3 eigensolver (acos/cos). A set that is not elongated gets a slightly suboptimal direction
// and hence a larger rms: it is rejected rather than accepted by mistake.
LineLeastSquares fit_line(const PointMoments& moments, const Vec3& seed, int iterations = 3);
LineLeastSquares fit_line(const PointMoments& moments);  // seed: the covariance column of largest variance

namespace line_fit_detail {

using simd::F4;

// PointMoments with only the 6 distinct entries of the symmetric sum of outer products (the same sums,
// entry by entry, in less memory and work: a scan line's prefix sums, scan_line_buffer.hpp, hold one per point).
struct Moments {
  int count = 0;
  Vec3 sum = Vec3::Zero();
  double xx = 0.0, xy = 0.0, xz = 0.0, yy = 0.0, yz = 0.0, zz = 0.0;

  void add(const Moments& o) {
    count += o.count;
    sum += o.sum;
    xx += o.xx, xy += o.xy, xz += o.xz, yy += o.yy, yz += o.yz, zz += o.zz;
  }
  void remove(const Vec3& p) {
    --count;
    sum -= p;
    xx -= p.x() * p.x(), xy -= p.x() * p.y(), xz -= p.x() * p.z();
    yy -= p.y() * p.y(), yz -= p.y() * p.z(), zz -= p.z() * p.z();
  }
};

// fit_upper in two halves, for callers that decide on the direction before its normalization (the square root
// and divisions) and finish the fit only when they keep it: the same operations, so the same fit.
struct LinePrefit {
  Vec3 centroid = Vec3::Zero();
  double xx = 0.0, xy = 0.0, xz = 0.0, yy = 0.0, yz = 0.0, zz = 0.0;  // covariance
  Vec3 u = Vec3::Zero();  // C^3 seed
  double norm2 = 0.0;     // |u|^2
  bool usable() const { return norm2 > 1e-300 && norm2 < 1e300; }  // the normalized path, scale far from overflow
};

// The rare retry of fit_upper from the axis of largest variance, out of line (line_least_squares.cpp), so that the
// hot fit_upper stays inlinable.
__attribute__((cold)) LineLeastSquares refit_from_axis(int count, const Vec3& sum, double oxx, double oxy,
                                                       double oxz, double oyy, double oyz, double ozz, int axis,
                                                       int iterations);

// fit_line from the count, sum and upper triangle of the sum of outer products:
// 1 / n for small n from a table (the same correctly rounded quotients): no division latency at the head of
// every fit.
struct Reciprocals {
  static constexpr int kSize = 256;
  double value[kSize];
  constexpr Reciprocals() : value() {
    for (int n = 1; n < kSize; ++n) value[n] = 1.0 / n;
  }
};
inline constexpr Reciprocals kReciprocals;

inline double reciprocal(int n) { return n < Reciprocals::kSize ? kReciprocals.value[n] : 1.0 / n; }

// Centroid, covariance (from its upper triangle) and the unnormalized power iterations (the scale grows like
// lambda_max^k, harmless in double). Scalar code: the same operations, in the same order, as the Eigen expressions
// C d, |d|^2, d / |d|, d.C d.
inline __attribute__((always_inline)) LinePrefit prefit_upper(int count, const Vec3& sum, double oxx, double oxy,
                                                              double oxz, double oyy, double oyz, double ozz,
                                                              const Vec3& seed, int iterations) {
  LinePrefit p;
  if (count == 0) return p;
  const double inv_n = reciprocal(count);
  p.centroid = sum * inv_n;
  if (count == 1) return p;
  const Vec3& c = p.centroid;
  const double xx = oxx * inv_n - c.x() * c.x(), xy = oxy * inv_n - c.x() * c.y();
  const double xz = oxz * inv_n - c.x() * c.z(), yy = oyy * inv_n - c.y() * c.y();
  const double yz = oyz * inv_n - c.y() * c.z(), zz = ozz * inv_n - c.z() * c.z();
  double dx = seed.x(), dy = seed.y(), dz = seed.z();
  for (int it = 0; it < iterations; ++it) {
    const double nx = xx * dx + xy * dy + xz * dz;
    const double ny = xy * dx + yy * dy + yz * dz;
    const double nz = xz * dx + yz * dy + zz * dz;
    dx = nx, dy = ny, dz = nz;
  }
  p.xx = xx, p.xy = xy, p.xz = xz, p.yy = yy, p.yz = yz, p.zz = zz;
  p.u = Vec3(dx, dy, dz);
  p.norm2 = dx * dx + dy * dy + dz * dz;
  return p;
}

// The normalization, the rms, and the retry from the largest axis when the seed was orthogonal to the spread.
inline __attribute__((always_inline)) LineLeastSquares finish_upper(const LinePrefit& p, int count, const Vec3& sum,
                                                                    double oxx, double oxy, double oxz, double oyy,
                                                                    double oyz, double ozz, const Vec3& seed,
                                                                    int iterations) {
  LineLeastSquares f;
  f.count = count;
  if (count == 0) return f;
  f.centroid = p.centroid;
  if (count == 1) return f;
  const double xx = p.xx, xy = p.xy, xz = p.xz, yy = p.yy, yz = p.yz, zz = p.zz;
  double dx = p.u.x(), dy = p.u.y(), dz = p.u.z();
  const double norm2 = p.norm2;
  const double trace = xx + yy + zz;
  if (!(norm2 > 1e-300) || !std::isfinite(norm2)) {
    if (iterations > 0 && seed.squaredNorm() > 0.0 && trace > 0.0) {  // seed orthogonal to the spread
      const int k = xx >= yy ? (xx >= zz ? 0 : 2) : (yy >= zz ? 1 : 2);
      // one retry: when the axis fails too (overflow or underflow at absurd scales) stop, no endless recursion
      if (seed != Vec3::Unit(k)) return refit_from_axis(count, sum, oxx, oxy, oxz, oyy, oyz, ozz, k, iterations);
    }
    return f;  // all points equal
  }
  const double norm = std::sqrt(norm2);
  const F4 unit = F4{dx, dy, dz, norm} / norm;  // the three quotients in one vector division
  dx = unit[0], dy = unit[1], dz = unit[2];
  f.direction = Vec3(dx, dy, dz);
  const double cx = xx * dx + xy * dy + xz * dz;
  const double cy = xy * dx + yy * dy + yz * dz;
  const double cz = xz * dx + yz * dy + zz * dz;
  f.rms = std::sqrt(std::max(0.0, trace - (dx * cx + dy * cy + dz * cz)));
  return f;
}

inline __attribute__((always_inline)) LineLeastSquares fit_upper(int count, const Vec3& sum, double oxx, double oxy,
                                                                 double oxz, double oyy, double oyz, double ozz,
                                                                 const Vec3& seed, int iterations) {
  return finish_upper(prefit_upper(count, sum, oxx, oxy, oxz, oyy, oyz, ozz, seed, iterations), count, sum, oxx,
                      oxy, oxz, oyy, oyz, ozz, seed, iterations);
}

inline __attribute__((always_inline)) LinePrefit prefit_line(const Moments& m, const Vec3& seed) {
  return prefit_upper(m.count, m.sum, m.xx, m.xy, m.xz, m.yy, m.yz, m.zz, seed, 3);
}

inline __attribute__((always_inline)) LineLeastSquares finish_line(const LinePrefit& p, const Moments& m,
                                                                   const Vec3& seed) {
  return finish_upper(p, m.count, m.sum, m.xx, m.xy, m.xz, m.yy, m.yz, m.zz, seed, 3);
}

inline __attribute__((always_inline)) LineLeastSquares fit_line(const Moments& m, const Vec3& seed) {
  return fit_upper(m.count, m.sum, m.xx, m.xy, m.xz, m.yy, m.yz, m.zz, seed, 3);
}

}  // namespace line_fit_detail

}  // namespace line_odom
