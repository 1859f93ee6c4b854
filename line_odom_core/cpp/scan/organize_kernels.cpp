#include "scan/organize_kernels.hpp"

#include <cstring>
#include <type_traits>

#include "common/simd.hpp"

#ifdef LINE_ODOM_X86_DISPATCH
#include <immintrin.h>
#endif

namespace line_odom::organize_detail {

namespace {

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

// scan_block without AVX2 (and for the last points of a block).
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

}  // namespace

template <typename Points>
void column_and_range(const Points& pts, size_t begin, int n, double cols_per_rad, double* U, double* R) {
#ifdef LINE_ODOM_X86_DISPATCH
  if (have_avx2()) return column_and_range_avx2(pts, begin, n, cols_per_rad, U, R);
#endif
  column_and_range_scalar(pts, begin, n, cols_per_rad, U, R);
}

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

template void column_and_range(const PointArrays&, std::size_t, int, double, double*, double*);
template void column_and_range(const StridedPoints<float>&, std::size_t, int, double, double*, double*);
template void column_and_range(const StridedPoints<double>&, std::size_t, int, double, double*, double*);
template BlockScan scan_block(const float*, int, std::size_t, bool, bool, std::uint8_t*, double*);
template BlockScan scan_block(const double*, int, std::size_t, bool, bool, std::uint8_t*, double*);

}  // namespace line_odom::organize_detail
