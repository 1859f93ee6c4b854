// The hot loops are compiled twice, for AVX2 and the baseline, and one copy is picked at load time, so a package
// built on one x86 machine runs on another. No "fma": contracting a*b + c would change the last bits against the
// scalar paths, so both copies compute the same IEEE operations and give the same results on every machine.
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
