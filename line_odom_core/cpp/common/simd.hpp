// The hot loops are compiled twice, for AVX2 and the baseline, and one copy is picked at load time, so a package
// built on one x86 machine runs on another. No "fma": contracting a*b + c would change the last bits against the
// scalar paths, so both copies compute the same IEEE operations and give the same results on every machine.
// Below the macros: four-lane vector types and helpers for the loops written lane by lane.
#pragma once

#if defined(__x86_64__) && defined(__GNUC__) && !defined(__clang__)
#define LINE_ODOM_X86_DISPATCH 1
#define LINE_ODOM_VECTOR_CLONES __attribute__((target_clones("avx2", "default")))
#define LINE_ODOM_VECTOR_CLONES_FLATTEN __attribute__((target_clones("avx2", "default"), flatten))
// A helper forced into the clones that call it, so that it is compiled once per clone.
#define LINE_ODOM_CLONE_INLINE inline __attribute__((always_inline))
#else
#define LINE_ODOM_VECTOR_CLONES
#define LINE_ODOM_VECTOR_CLONES_FLATTEN __attribute__((flatten))
#define LINE_ODOM_CLONE_INLINE inline
#endif

#include <cstdint>
#include <cstring>

namespace line_odom::simd {

// Four lanes of doubles / 64-bit integers (GCC vector extensions: AVX2 registers in the AVX2 clones, SSE2 pairs
// in the baseline; the same IEEE operations lane by lane as the scalar expressions they replace).
// (Always inlined: these helpers never pass vectors across a call, whose ABI would differ between the clones.)
#pragma GCC diagnostic ignored "-Wpsabi"
typedef double F4 __attribute__((vector_size(32)));
typedef std::int64_t I4 __attribute__((vector_size(32)));
constexpr int kLanes = 4;
// Two lanes of doubles (one SSE2 register in either clone).
typedef double F2 __attribute__((vector_size(16)));
// Four lanes of floats and their compare masks (one SSE register in either clone).
typedef float F4f __attribute__((vector_size(16)));
typedef std::int32_t I4f __attribute__((vector_size(16)));

inline __attribute__((always_inline)) F4 load4(const double* p) {
  F4 v;
  std::memcpy(&v, p, sizeof v);
  return v;
}

inline __attribute__((always_inline)) bool any(const I4& m) { return (m[0] | m[1] | m[2] | m[3]) != 0; }

// rows[i] = (a[i], b[i], c[i], d[i])
inline __attribute__((always_inline)) void transpose4(const F4& a, const F4& b, const F4& c, const F4& d, F4* rows) {
  const F4 ab_even = __builtin_shuffle(a, b, I4{0, 4, 2, 6}), ab_odd = __builtin_shuffle(a, b, I4{1, 5, 3, 7});
  const F4 cd_even = __builtin_shuffle(c, d, I4{0, 4, 2, 6}), cd_odd = __builtin_shuffle(c, d, I4{1, 5, 3, 7});
  rows[0] = __builtin_shuffle(ab_even, cd_even, I4{0, 1, 4, 5});
  rows[1] = __builtin_shuffle(ab_odd, cd_odd, I4{0, 1, 4, 5});
  rows[2] = __builtin_shuffle(ab_even, cd_even, I4{2, 3, 6, 7});
  rows[3] = __builtin_shuffle(ab_odd, cd_odd, I4{2, 3, 6, 7});
}

}  // namespace line_odom::simd
