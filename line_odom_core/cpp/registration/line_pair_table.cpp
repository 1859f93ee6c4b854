#include "registration/line_pair_table.hpp"

#include <algorithm>

#include "common/simd.hpp"

namespace line_odom {
namespace {

struct FlatMotion {
  double r[9];  // row-major R
  double t[3];
};

FlatMotion flatten(const RigidTransform& T) {
  FlatMotion m;
  for (int i = 0; i < 3; ++i) {
    for (int j = 0; j < 3; ++j) m.r[3 * i + j] = T.R(i, j);
    m.t[i] = T.t[i];
  }
  return m;
}

struct PairTerms {
  double d0, d1, d2;  // d_b'
  double m0, m1, m2;  // m_b'
  double c0, c1, c2;  // d_a x d_b'
  double f, s2;
};

// The 12 coordinate rows of a table.
struct Rows {
  const double* ad[3];
  const double* am[3];
  const double* bd[3];
  const double* bm[3];
};

Rows rows_of(const double* coords, long n) {
  Rows rows;
  for (int k = 0; k < 3; ++k) {
    rows.ad[k] = coords + k * n;
    rows.am[k] = coords + (3 + k) * n;
    rows.bd[k] = coords + (6 + k) * n;
    rows.bm[k] = coords + (9 + k) * n;
  }
  return rows;
}

// PluckerLine::moved, the cross product and reciprocal_product of pair i, in the order Eigen 3.4 evaluates them
// (it sums the third row of a 3x3 product the other way round). Scalars only, so the loops below vectorize.
inline PairTerms pair_terms(const Rows& rows, const FlatMotion& M, long i) {
  const double* r = M.r;
  const double* t = M.t;
  PairTerms o;
  const double dx = rows.bd[0][i], dy = rows.bd[1][i], dz = rows.bd[2][i];
  o.d0 = r[0] * dx + r[1] * dy + r[2] * dz;
  o.d1 = r[3] * dx + r[4] * dy + r[5] * dz;
  o.d2 = r[6] * dx + (r[7] * dy + r[8] * dz);
  const double mx = rows.bm[0][i], my = rows.bm[1][i], mz = rows.bm[2][i];
  o.m0 = (r[0] * mx + r[1] * my + r[2] * mz) + (t[1] * o.d2 - t[2] * o.d1);
  o.m1 = (r[3] * mx + r[4] * my + r[5] * mz) + (t[2] * o.d0 - t[0] * o.d2);
  o.m2 = (r[6] * mx + (r[7] * my + r[8] * mz)) + (t[0] * o.d1 - t[1] * o.d0);
  const double ax = rows.ad[0][i], ay = rows.ad[1][i], az = rows.ad[2][i];
  o.f = (ax * o.m0 + ay * o.m1 + az * o.m2) + (o.d0 * rows.am[0][i] + o.d1 * rows.am[1][i] + o.d2 * rows.am[2][i]);
  o.c0 = ay * o.d2 - az * o.d1;
  o.c1 = az * o.d0 - ax * o.d2;
  o.c2 = ax * o.d1 - ay * o.d0;
  o.s2 = o.c0 * o.c0 + o.c1 * o.c1 + o.c2 * o.c2;
  return o;
}

// ivdep: the outputs never overlap the table (GCC otherwise gives up on the run-time alias checks). The tests go
// to 64-bit flags first: a byte store in the same loop would make it run 32 pairs per vector iteration, with long
// scalar tails on the short blocks of the RANSAC pre-test.
LINE_ODOM_VECTOR_CLONES
void mask_kernel(const Rows rows, const FlatMotion motion, double th2, double min_s2, long begin, long end,
                 std::uint8_t* mask) {
  std::int64_t meets[kPairBlockSize];
  for (long chunk = begin; chunk < end; chunk += kPairBlockSize) {
    const long chunk_end = std::min(end, chunk + kPairBlockSize);
#if defined(__GNUC__) && !defined(__clang__)
#pragma GCC ivdep
#endif
    for (long i = chunk; i < chunk_end; ++i) {
      const PairTerms o = pair_terms(rows, motion, i);
      meets[i - chunk] = (o.s2 >= min_s2) & (o.f * o.f < th2 * o.s2);
    }
    for (long i = chunk; i < chunk_end; ++i) mask[i - begin] = static_cast<std::uint8_t>(meets[i - chunk]);
  }
}

LINE_ODOM_VECTOR_CLONES
void residual_kernel(const Rows rows, const double* weights, const FlatMotion motion, double th2, double min_s2,
                     long begin, long end, LineResidualBlock* out) {
  std::int64_t used[LineResidualBlock::kSize];  // 64-bit, as in mask_kernel
#if defined(__GNUC__) && !defined(__clang__)
#pragma GCC ivdep
#endif
  for (long i = begin; i < end; ++i) {
    const PairTerms o = pair_terms(rows, motion, i);
    const long k = i - begin;
    const double ax = rows.ad[0][i], ay = rows.ad[1][i], az = rows.ad[2][i];
    const double amx = rows.am[0][i], amy = rows.am[1][i], amz = rows.am[2][i];
    out->c[0][k] = o.c0;
    out->c[1][k] = o.c1;
    out->c[2][k] = o.c2;
    out->e[0][k] = (o.m1 * az - o.m2 * ay) + (o.d1 * amz - o.d2 * amy);
    out->e[1][k] = (o.m2 * ax - o.m0 * az) + (o.d2 * amx - o.d0 * amz);
    out->e[2][k] = (o.m0 * ay - o.m1 * ax) + (o.d0 * amy - o.d1 * amx);
    out->f[k] = o.f;
    out->s2[k] = o.s2;
    used[k] = (weights[i] > 0.0) & !(o.s2 < min_s2) & !(o.f * o.f >= th2 * o.s2);
  }
  int count = 0;
  for (long k = 0; k < end - begin; ++k) {
    out->used[count] = static_cast<int>(k);
    count += static_cast<int>(used[k]);
  }
  out->used_count = count;
}

}  // namespace

LinePairTable::LinePairTable(const Correspondences& data)
    : n_(static_cast<int>(std::min(data.lines_a.size(), data.lines_b.size()))) {
  const size_t n = static_cast<size_t>(n_);
  rows_.reset(new double[13 * n]);
  double* rows = rows_.get();
  const bool weighted = data.weights.size() == n;
  for (size_t i = 0; i < n; ++i) {
    const PluckerLine& a = data.lines_a[i];
    const PluckerLine& b = data.lines_b[i];
    for (size_t k = 0; k < 3; ++k) {
      rows[k * n + i] = a.d[k];
      rows[(3 + k) * n + i] = a.m[k];
      rows[(6 + k) * n + i] = b.d[k];
      rows[(9 + k) * n + i] = b.m[k];
    }
    rows[12 * n + i] = weighted ? data.weights[i] : 1.0;
  }
}

void LinePairTable::inlier_mask(const RigidTransform& T, double threshold, double min_sine, int begin, int end,
                                std::uint8_t* mask) const {
  mask_kernel(rows_of(rows_.get(), n_), flatten(T), threshold * threshold, min_sine * min_sine, std::max(0, begin),
              std::min(end, n_), mask);
}

int LinePairTable::residual_block(const RigidTransform& T, double threshold, double min_sine, int begin, int end,
                                  LineResidualBlock* out) const {
  const int last = std::min({end, n_, begin + LineResidualBlock::kSize});
  out->used_count = 0;
  if (last <= begin) return 0;
  residual_kernel(rows_of(rows_.get(), n_), weights(), flatten(T), threshold * threshold,
                  min_sine * min_sine, begin, last, out);
  return last - begin;
}

double score_motion(const LinePairTable& pairs, const RigidTransform& T_ab, double threshold, double min_sine,
                    int* inliers) {
  std::uint8_t mask[kPairBlockSize];
  double score = 0.0;
  int count = 0;
  for (int begin = 0; begin < pairs.size(); begin += kPairBlockSize) {
    const int end = std::min(pairs.size(), begin + kPairBlockSize);
    pairs.inlier_mask(T_ab, threshold, min_sine, begin, end, mask);
    for (int i = begin; i < end; ++i)
      if (mask[i - begin]) score += pairs.weight(i), ++count;
  }
  if (inliers) *inliers = count;
  return score;
}

}  // namespace line_odom
