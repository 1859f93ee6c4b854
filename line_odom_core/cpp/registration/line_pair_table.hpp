// Candidate line pairs as a structure of arrays, so the intersection test (docs/DESIGN.md §3: l_a and T l_b meet
// iff the reciprocal product d_a.m_b' + d_b'.m_a vanishes) runs under one motion over a block of pairs in a
// vectorizable loop. RANSAC (paper §6.3) tests every hypothesis on every pair and the refinement re-tests all
// pairs at each iterate: these loops are most of a sparse frame's time. The arithmetic is the same, in the same
// order, as PluckerLine::moved + reciprocal_product, so results do not depend on which path computed them.
#pragma once

#include <cstdint>
#include <memory>
#include <vector>

#include "common/types.hpp"
#include "registration/correspondences.hpp"

namespace line_odom {

// The refinement's view of a block of pairs under T (index k = pair - begin): the terms of the signed distance
// r = f / s and its derivative J = (-c / s, e / s) for the left perturbation of refine.hpp, s = |d_a x d_b'|, and the
// pairs it uses (weight > 0, s >= min_sine, |r| < threshold) in pair order.
constexpr int kPairBlockSize = 256;  // pairs per call of the block-wise loops

struct LineResidualBlock {
  static constexpr int kSize = kPairBlockSize;
  double c[3][kSize];  // d_a x d_b'
  double e[3][kSize];  // m_b' x d_a + d_b' x m_a
  double f[kSize];     // reciprocal product d_a.m_b' + d_b'.m_a
  double s2[kSize];    // |d_a x d_b'|^2
  int used[kSize];     // k of the pairs the refinement uses, ascending
  int used_count = 0;
};

class LinePairTable {
 public:
  LinePairTable() = default;
  // Rows of lines_a / lines_b (up to the shorter) with data.weights (1 each when absent or of another size).
  explicit LinePairTable(const Correspondences& data);

  int size() const { return n_; }
  double weight(int i) const { return row(12)[i]; }
  const double* weights() const { return row(12); }
  Vec3 a_d(int i) const { return {row(0)[i], row(1)[i], row(2)[i]}; }
  Vec3 a_m(int i) const { return {row(3)[i], row(4)[i], row(5)[i]}; }

  // mask[i - begin] = 1 iff pair i meets within `threshold` under T and |d_a x d_b'| >= min_sine,
  // for i in [begin, end).
  void inlier_mask(const RigidTransform& T, double threshold, double min_sine, int begin, int end,
                   std::uint8_t* mask) const;
  // Pairs [begin, min(end, begin + LineResidualBlock::kSize)) under T; returns the number filled.
  int residual_block(const RigidTransform& T, double threshold, double min_sine, int begin, int end,
                     LineResidualBlock* out) const;

 private:
  const double* row(int r) const { return rows_.get() + static_cast<size_t>(r) * n_; }
  int n_ = 0;
  std::unique_ptr<double[]> rows_;  // 13 rows of n: d_a, m_a, d_b, m_b (x y z each), weight; written once, so
                                    // not zeroed first
};

// Weighted count of pairs that meet within `threshold` under T_ab (paper §6.3 inlier counting); pairs closer to
// parallel than min_sine (sine of their angle) do not count.
double score_motion(const LinePairTable& pairs, const RigidTransform& T_ab, double threshold, double min_sine = 0.05,
                    int* inliers = nullptr);

}  // namespace line_odom
