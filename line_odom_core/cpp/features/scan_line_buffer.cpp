#include "features/scan_line_buffer.hpp"

#include <cstdint>
#include <cstring>

namespace line_odom::line_fit_detail {

using simd::F4;
using simd::kLanes;
using simd::load4;
using simd::transpose4;

LINE_ODOM_VECTOR_CLONES void cell_thresholds(const RangeImage& img, const LineFitConfig& cfg, CellThresholds& t) {
  static_assert(sizeof(Vec3) == 3 * sizeof(double), "Vec3 arrays are read as packed x, y, z");
  const size_t n = img.points.size();
  if (t.tau.size() < 2 * n) t.tau.resize(2 * n);
  const double* __restrict xyz = img.points.empty() ? nullptr : img.points[0].data();
  const std::uint8_t* __restrict valid = img.valid.data();
  double* __restrict pair_out = t.tau.data();
  const double split = cfg.split_distance, a = cfg.threshold_per_m, b = cfg.threshold_per_m2;
  // one pass (-fno-math-errno, setup.py, lets the square root vectorize)
  for (size_t i = 0; i < n; ++i) {
    const double x = xyz[3 * i], y = xyz[3 * i + 1], z = xyz[3 * i + 2];
    const double r = std::sqrt(x * x + y * y + z * z);
    const double scaled = split * (1.0 + a * r + b * r * r);
    // valid ? scaled : 1, as a bit select (a branch would keep the loop from vectorizing)
    const std::uint64_t keep = 0 - static_cast<std::uint64_t>(valid[i] != 0);
    std::uint64_t bits_scaled, bits_one;
    const double one = 1.0;
    std::memcpy(&bits_scaled, &scaled, sizeof scaled);
    std::memcpy(&bits_one, &one, sizeof one);
    const std::uint64_t bits = (bits_scaled & keep) | (bits_one & ~keep);
    double tau;
    std::memcpy(&tau, &bits, sizeof tau);
    pair_out[2 * i] = tau;
    pair_out[2 * i + 1] = 1.0 / (tau * tau);
  }
}

__attribute__((noinline)) LINE_ODOM_VECTOR_CLONES void fill_buffer(const RangeImage& img, const CellThresholds& th,
                                                                  bool horizontal, int index, ScanBuffer* buf) {
  const int n = horizontal ? img.cols : img.rows;
  if (static_cast<int>(buf->pos.size()) < n) {  // grow once; sizes stay at the maximum, `count` is the length
    buf->pos.resize(n);
    buf->x.resize(n + kPad);
    buf->y.resize(n + kPad);
    buf->z.resize(n + kPad);
    buf->tau.resize(n);
    buf->inv_tau2.resize(n + kPad);
    buf->prefix.resize(n + 1);
  }
  const int cell0 = horizontal ? index * img.cols : index;
  const int step = horizontal ? 1 : img.cols;
  buf->cell0 = cell0;
  buf->cell_step = step;
  // The valid points, compacted; then their prefix sums (two loops: one holding every output stream would keep more
  // pointers live than there are registers).
  const std::uint8_t* __restrict valid = img.valid.data();
  const double* __restrict points = img.points.empty() ? nullptr : img.points[0].data();
  const double* __restrict cell_tau = th.tau.data();
  int* __restrict out_pos = buf->pos.data();
  double* __restrict out_x = buf->x.data();
  double* __restrict out_y = buf->y.data();
  double* __restrict out_z = buf->z.data();
  double* __restrict out_tau = buf->tau.data();
  double* __restrict out_inv_tau2 = buf->inv_tau2.data();
  // (pointers stepped along the scan line, by a constant along rows: no index arithmetic in the loops)
  const std::uint8_t* __restrict v = valid + cell0;
  const double* __restrict q = points + 3 * static_cast<std::ptrdiff_t>(cell0);
  const double* __restrict t = cell_tau + 2 * static_cast<std::ptrdiff_t>(cell0);
  int m = 0;
  auto copy = [&](int k) __attribute__((always_inline)) {
    out_pos[m] = k;
    out_x[m] = q[0];
    out_y[m] = q[1];
    out_z[m] = q[2];
    out_tau[m] = t[0];
    out_inv_tau2[m] = t[1];
    ++m;
  };
  if (horizontal) {
    for (int k = 0; k < n; ++k, ++v, q += 3, t += 2)
      if (*v) copy(k);
  } else {
    // A column's cells are `cols` cells apart, a stride the hardware prefetchers do not follow: the points and
    // thresholds kPrefetchCells cells to the right are requested into L2 while this column is read.
    constexpr int kPrefetchCells = 16;
    const std::ptrdiff_t stride = step;
    for (int k = 0; k < n; ++k, v += stride, q += 3 * stride, t += 2 * stride) {
      __builtin_prefetch(q + 3 * kPrefetchCells, 0, 2);
      __builtin_prefetch(t + 2 * kPrefetchCells, 0, 2);
      if (*v) copy(k);
    }
  }
  buf->count = m;
  // Running sums in registers (the same additions, in the same order, as prev + p p^T). Four points at a time: their
  // products as vectors, transposed into one (x, y, z, xx) and one (xy, xz, yy, yz) vector per point.
  ScanBuffer::PrefixSums* __restrict next = buf->prefix.data();
  *next++ = {0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0};
  F4 low = {0.0, 0.0, 0.0, 0.0}, high = {0.0, 0.0, 0.0, 0.0};  // (sx, sy, sz, xx), (xy, xz, yy, yz): PrefixSums order
  double zz = 0.0;
  auto add = [&](const F4& point_low, const F4& point_high, double point_zz) __attribute__((always_inline)) {
    low += point_low;
    high += point_high;
    zz += point_zz;
    std::memcpy(&next->sx, &low, sizeof low);
    std::memcpy(&next->xy, &high, sizeof high);
    next->zz = zz;
    ++next;
  };
  int k = 0;
  for (; k + kLanes <= m; k += kLanes) {
    const F4 x = load4(out_x + k), y = load4(out_y + k), z = load4(out_z + k);
    F4 lows[kLanes], highs[kLanes];
    transpose4(x, y, z, x * x, lows);
    transpose4(x * y, x * z, y * y, y * z, highs);
    const F4 zzs = z * z;
    for (int i = 0; i < kLanes; ++i) add(lows[i], highs[i], zzs[i]);
  }
  for (; k < m; ++k) {
    const double x = out_x[k], y = out_y[k], z = out_z[k];
    add(F4{x, y, z, x * x}, F4{x, x, y, y} * F4{y, z, y, z}, z * z);
  }
}

}  // namespace line_odom::line_fit_detail
