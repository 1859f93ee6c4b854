#include "registration/refine.hpp"

#include <Eigen/Eigenvalues>
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <vector>

#include "common/simd.hpp"
#include "registration/motion_estimation.hpp"

namespace line_odom {
namespace {

Mat3 skew(const Vec3& w) {
  Mat3 S;
  S << 0.0, -w.z(), w.y(), w.z(), 0.0, -w.x(), -w.y(), w.x(), 0.0;
  return S;
}

constexpr double kConvergedTranslation = 1e-4;  // m: a step this small ends the iteration
constexpr double kConvergedRotation = 1e-5;     // rad

// Normal equations of the gated residuals at T.
struct NormalEquations {
  Mat6 H = Mat6::Zero();
  Vec6 g = Vec6::Zero();
  double weighted_sq = 0.0;  // sum of weight * residual^2 (metres^2)
  double weight_sum = 0.0;   // over residual components
  int residuals = 0;         // residual components
  int line_inliers = 0;
  double line_inlier_weight = 0.0;
  double line_sq = 0.0;
  int plane_inliers = 0;
};

// Four running sums side by side (element-wise IEEE operations, so each lane is the scalar sum bit for bit; the lanes
// only let one instruction update several of the normal equations' sums).
using Lanes4 = simd::F4;

// The line pairs' sums of NormalEquations in lanes: column c < 4 of H, rows 0..3, in h_col[c] (the rows above the
// diagonal unused); rows 4, 5 of columns (0, 1), (2, 3), (4, 5) in h_rows45[0..2] as (4,c) (5,c) (4,c+1) (5,c+1);
// g 0..3 in g0123; g 4, g 5 and weighted_sq in g45_sq; weight_sum, line_inlier_weight, line_sq in weights_sq.
struct LineSums {
  Lanes4 h_col[4] = {};
  Lanes4 h_rows45[3] = {};
  Lanes4 g0123 = {};
  Lanes4 g45_sq = {};
  Lanes4 weights_sq = {};
};

// H += w J J^T, g += w r J and the sums over the used pairs of a block, in pair order: each sum adds the same
// products in the same order as a scalar loop would (H(row, col) += (w J_col) J_row, g += (w r) J).
LINE_ODOM_VECTOR_CLONES
void accumulate_lines(const LineResidualBlock& block, const double* pair_weights, double weight_scale, double huber,
                      LineSums* sums) {
  Lanes4 h_col0 = sums->h_col[0], h_col1 = sums->h_col[1], h_col2 = sums->h_col[2], h_col3 = sums->h_col[3];
  Lanes4 h_rows45_01 = sums->h_rows45[0], h_rows45_23 = sums->h_rows45[1], h_rows45_45 = sums->h_rows45[2];
  Lanes4 g0123 = sums->g0123, g45_sq = sums->g45_sq, weights_sq = sums->weights_sq;
  for (int u = 0; u < block.used_count; ++u) {
    const int k = block.used[u];
    const double w_pair = pair_weights[k];
    const double inv_s = 1.0 / std::sqrt(block.s2[k]);  // one division per pair, not seven
    const double r = block.f[k] * inv_s;
    // d f / d(v, w) for d'' = d' + w x d', m'' = m' + w x m' + v x d' (left perturbation), |d_a x d''| held:
    // J = (-c / s, e / s); J0123 = J 0..3, J45r = (J 4, J 5, r, 0).
    const Lanes4 J0123 = Lanes4{-inv_s, -inv_s, -inv_s, inv_s} *
                         Lanes4{block.c[0][k], block.c[1][k], block.c[2][k], block.e[0][k]};
    const Lanes4 J45r = Lanes4{inv_s, inv_s, inv_s, 0.0} * Lanes4{block.e[1][k], block.e[2][k], block.f[k], 0.0};
    const double w_scaled = w_pair * weight_scale;
    const double w = w_scaled * huber_weight(std::abs(r), huber);
    const Lanes4 wJ0123 = w * J0123;
    const Lanes4 wJ45r = w * J45r;  // (w J 4, w J 5, w r, 0)
    h_col0 += Lanes4{wJ0123[0], wJ0123[0], wJ0123[0], wJ0123[0]} * J0123;
    h_col1 += Lanes4{wJ0123[1], wJ0123[1], wJ0123[1], wJ0123[1]} * J0123;
    h_col2 += Lanes4{wJ0123[2], wJ0123[2], wJ0123[2], wJ0123[2]} * J0123;
    h_col3 += Lanes4{wJ0123[3], wJ0123[3], wJ0123[3], wJ0123[3]} * J0123;
    const Lanes4 J4545 = Lanes4{J45r[0], J45r[1], J45r[0], J45r[1]};
    h_rows45_01 += Lanes4{wJ0123[0], wJ0123[0], wJ0123[1], wJ0123[1]} * J4545;
    h_rows45_23 += Lanes4{wJ0123[2], wJ0123[2], wJ0123[3], wJ0123[3]} * J4545;
    h_rows45_45 += Lanes4{wJ45r[0], wJ45r[0], wJ45r[1], wJ45r[1]} * J4545;
    const Lanes4 wr = Lanes4{wJ45r[2], wJ45r[2], wJ45r[2], wJ45r[2]};
    g0123 += wr * J0123;
    g45_sq += wr * J45r;  // (w r J 4, w r J 5, w r r, 0)
    weights_sq += Lanes4{w_scaled, w_pair, r * r, 0.0};
  }
  sums->h_col[0] = h_col0, sums->h_col[1] = h_col1, sums->h_col[2] = h_col2, sums->h_col[3] = h_col3;
  sums->h_rows45[0] = h_rows45_01, sums->h_rows45[1] = h_rows45_23, sums->h_rows45[2] = h_rows45_45;
  sums->g0123 = g0123, sums->g45_sq = g45_sq, sums->weights_sq = weights_sq;
}

NormalEquations accumulate(const Correspondences& data, const LinePairTable& pairs, const RigidTransform& T,
                           const RefineOptions& o, double weight_scale) {
  NormalEquations ne;
  const double huber = o.huber_delta > 0.0 ? o.huber_delta : o.line_threshold;
  LineResidualBlock block;
  LineSums sums;
  for (int begin = 0; begin < pairs.size(); begin += LineResidualBlock::kSize) {
    pairs.residual_block(T, o.line_threshold, o.min_line_sine, begin, pairs.size(), &block);
    accumulate_lines(block, pairs.weights() + begin, weight_scale, huber, &sums);
    ne.line_inliers += block.used_count;
  }
  for (int col = 0; col < 4; ++col)
    for (int row = col; row < 4; ++row) ne.H(row, col) = sums.h_col[col][row];
  for (int cols = 0; cols < 3; ++cols) {
    ne.H(4, 2 * cols) = sums.h_rows45[cols][0];
    ne.H(5, 2 * cols) = sums.h_rows45[cols][1];
    if (cols < 2) ne.H(4, 2 * cols + 1) = sums.h_rows45[cols][2];
    ne.H(5, 2 * cols + 1) = sums.h_rows45[cols][3];
  }
  ne.g << sums.g0123[0], sums.g0123[1], sums.g0123[2], sums.g0123[3], sums.g45_sq[0], sums.g45_sq[1];
  ne.weighted_sq = sums.g45_sq[2];
  ne.weight_sum = sums.weights_sq[0];
  ne.line_inlier_weight = sums.weights_sq[1];
  ne.line_sq = sums.weights_sq[2];
  ne.residuals = ne.line_inliers;
  const double k_angle = o.line_threshold / o.plane_angle_threshold;
  const double k_dist = o.line_threshold / o.plane_distance_threshold;
  const double cos_th = std::cos(o.plane_angle_threshold);
  const size_t m = std::min(data.planes_a.size(), data.planes_b.size());
  ne.H.triangularView<Eigen::StrictlyUpper>() = ne.H.transpose();
  for (size_t j = 0; j < m; ++j) {
    const Plane& a = data.planes_a[j];
    const Plane b = data.planes_b[j].moved(T);
    const double cosang = a.n.dot(b.n);
    const double dd = b.delta - a.delta;
    if (!(cosang > cos_th) || !(std::abs(dd) < o.plane_distance_threshold)) continue;
    // n'' = n' + w x n'  ->  d n''/dw = -[n']x ;  delta'' = delta' - n'.v  ->  d delta''/dv = -n'
    const Vec3 rn = (b.n - a.n) * k_angle;
    const Mat3 Jn = -skew(b.n) * k_angle;
    const double rd = dd * k_dist;
    const Vec3 Jd = -b.n * k_dist;
    const double wn = huber_weight(rn.norm(), huber);
    const double wd = huber_weight(std::abs(rd), huber);
    ne.H.bottomRightCorner<3, 3>().noalias() += wn * Jn.transpose() * Jn;
    ne.g.tail<3>().noalias() += wn * Jn.transpose() * rn;
    ne.H.topLeftCorner<3, 3>().noalias() += wd * Jd * Jd.transpose();
    ne.g.head<3>().noalias() += wd * rd * Jd;
    ne.weighted_sq += wn * rn.squaredNorm() + wd * rd * rd;
    ne.weight_sum += 3.0;
    ne.residuals += 3;  // the normal residual has rank 2
    ne.plane_inliers += 1;
  }
  return ne;
}

// S = diag(1, 1, 1, len, len, len) with len = sqrt(trace H_tt / trace H_rr), so that both blocks of S H S weigh
// alike; false when either block has no information.
bool block_scale(const Mat6& H, Vec6* s) {
  const double tt = H.topLeftCorner<3, 3>().trace();
  const double tr = H.bottomRightCorner<3, 3>().trace();
  if (!(tt > 0.0) || !(tr > 0.0)) return false;
  const double len = std::sqrt(tt / tr);
  *s << 1.0, 1.0, 1.0, len, len, len;
  return true;
}

// Smallest / largest eigenvalue of H with the rotation block scaled by a length so both blocks weigh alike.
double scaled_condition(const Mat6& H) {
  Vec6 s;
  if (!block_scale(H, &s)) return 0.0;
  const Mat6 Hs = s.asDiagonal() * H * s.asDiagonal();
  Eigen::SelfAdjointEigenSolver<Mat6> es(Hs, Eigen::EigenvaluesOnly);
  const double lmax = es.eigenvalues()(5);
  if (!(lmax > 0.0)) return 0.0;
  return std::max(0.0, es.eigenvalues()(0) / lmax);
}

}  // namespace

RigidTransform se3_exp(const Vec6& xi) {
  const Vec3 v = xi.head<3>();
  const Vec3 w = xi.tail<3>();
  const double th2 = w.squaredNorm();
  const Mat3 W = skew(w);
  const Mat3 W2 = W * W;
  double a, b, c;  // sin(th)/th, (1-cos th)/th^2, (th - sin th)/th^3
  if (th2 < 1e-10) {
    a = 1.0 - th2 / 6.0;
    b = 0.5 - th2 / 24.0;
    c = 1.0 / 6.0 - th2 / 120.0;
  } else {
    const double th = std::sqrt(th2);
    a = std::sin(th) / th;
    b = (1.0 - std::cos(th)) / th2;
    c = (th - std::sin(th)) / (th2 * th);
  }
  RigidTransform T;
  T.R = Mat3::Identity() + a * W + b * W2;
  T.t = (Mat3::Identity() + b * W + c * W2) * v;
  return T;
}

bool plane_pair_is_inlier(const Plane& a, const Plane& b_moved, double angle_threshold, double distance_threshold) {
  return a.n.dot(b_moved.n) > std::cos(angle_threshold) && std::abs(b_moved.delta - a.delta) < distance_threshold;
}

void copy_refinement_stats(const RefineResult& refined, MotionStats* stats) {
  stats->inliers = refined.line_inliers;
  stats->inlier_weight = refined.line_inlier_weight;
  stats->plane_inliers = refined.plane_inliers;
  stats->residual_rms = refined.residual_rms;
  stats->condition = refined.condition;
  stats->degenerate = refined.degenerate;
}

double axis_support(const LinePairTable& pairs, const RigidTransform& T, double threshold, double min_sine,
                    double* pair_share, AxisShares* per_axis) {
  if (pair_share) *pair_share = 0.0;
  if (per_axis) *per_axis = AxisShares{};
  const int n = pairs.size();
  std::vector<std::uint8_t> meets(n);
  pairs.inlier_mask(T, threshold, min_sine, 0, n, meets.data());
  std::vector<int> inliers;
  double total = 0.0, r2 = 0.0;
  for (int j = 0; j < n; ++j) {
    const double w = pairs.weight(j);
    if (w > 0.0 && meets[j]) {
      inliers.push_back(j);
      total += w;
      r2 += pairs.a_d(j).cross(pairs.a_m(j)).squaredNorm();  // PluckerLine::closest_point_to_origin
    }
  }
  if (inliers.empty() || total <= 0.0) return 0.0;
  const double count = static_cast<double>(inliers.size());
  const double push = 20.0 * threshold;
  const double turn = push / std::max(1.0, std::sqrt(r2 / count));
  double worst = 0.0, worst_pairs = 0.0;
  for (int axis = 0; axis < 6; ++axis) {
    for (const double sign : {-1.0, 1.0}) {
      Vec6 xi = Vec6::Zero();
      xi[axis] = sign * (axis < 3 ? push : turn);
      const RigidTransform P = se3_exp(xi) * T;
      pairs.inlier_mask(P, threshold, min_sine, 0, n, meets.data());
      double kept = 0.0, kept_pairs = 0.0;
      for (const int j : inliers) {
        if (meets[j]) {
          kept += pairs.weight(j);
          kept_pairs += 1.0;
        }
      }
      worst = std::max(worst, kept / total);
      worst_pairs = std::max(worst_pairs, kept_pairs / count);
      if (per_axis) {
        per_axis->weight[axis] = std::max(per_axis->weight[axis], kept / total);
        per_axis->pairs[axis] = std::max(per_axis->pairs[axis], kept_pairs / count);
      }
    }
  }
  if (pair_share) *pair_share = worst_pairs;
  return worst;
}

namespace {

// Directions of xi held where the start has them (refine_motion_partial): an orthonormal basis `locked` of them in
// the scaled coordinates xi_s = S^-1 xi, S = block_scale(H).
struct LockedSubspace {
  Vec6 scale = Vec6::Ones();
  Mat6 locked = Mat6::Zero();
  int count = 0;

  Mat6 free_projector() const {
    return Mat6::Identity() - locked.leftCols(count) * locked.leftCols(count).transpose();
  }
  Mat6 scaled(const Mat6& H) const { return scale.asDiagonal() * H * scale.asDiagonal(); }  // S H S
  // The Gauss-Newton step with no component along the locked directions: (Q Hs Q + c L L^T) dx_s = -Q gs.
  Vec6 step(const Mat6& H, const Vec6& g) const {
    const Mat6 Q = free_projector();
    const Mat6 Hs = scaled(H);
    const double stiffness = std::max(Hs.trace(), 1e-30);
    const Mat6 M = Q * Hs * Q + stiffness * (Mat6::Identity() - Q);
    const Vec6 dx_s = M.ldlt().solve(-(Q * (scale.asDiagonal() * g)));
    return scale.asDiagonal() * dx_s;
  }
  // (Q Hs Q)^+: Hs^-1 on the free directions, zero along the locked ones, in scaled coordinates.
  Mat6 free_inverse(const Mat6& Hs) const {
    const Mat6 Q = free_projector();
    const Mat6 locked_projector = Mat6::Identity() - Q;
    return (Q * Hs * Q + locked_projector).inverse() - locked_projector;
  }
  // ... in xi coordinates, from free_inverse(Hs).
  Mat6 free_covariance(const Mat6& free_inv) const { return scale.asDiagonal() * free_inv * scale.asDiagonal(); }
  // d xi / d xi_prior of the constrained minimum: S (I - (Q Hs Q)^+ Hs) (I - Q) S^-1 (the locked components
  // are the prior's, the free ones move by their least-squares coupling to them).
  Mat6 held_sensitivity(const Mat6& Hs, const Mat6& free_inv) const {
    const Mat6 locked_projector = Mat6::Identity() - free_projector();
    return scale.asDiagonal() * (Mat6::Identity() - free_inv * Hs) * locked_projector *
           scale.cwiseInverse().asDiagonal();
  }
};

// sigma^2 H^-1, the eigenvalues of H floored at 1e-12 of the largest.
Mat6 covariance_from(const Mat6& H, double sigma2) {
  Eigen::SelfAdjointEigenSolver<Mat6> es(H);
  const double lmax = std::max(es.eigenvalues()(5), 1e-300);
  Vec6 inv;
  for (int k = 0; k < 6; ++k) inv(k) = 1.0 / std::max(es.eigenvalues()(k), 1e-12 * lmax);
  Mat6 cov = sigma2 * es.eigenvectors() * inv.asDiagonal() * es.eigenvectors().transpose();
  return cov;
}

// Pair weights are relative: scale them to mean 1 over all line pairs so sigma^2 stays in metres^2.
double pair_weight_scale(const Correspondences& data) {
  if (data.weights.empty()) return 1.0;
  double sum = 0.0;
  int count = 0;
  for (double w : data.weights)
    if (w > 0.0) sum += w, ++count;
  return sum > 0.0 ? count / sum : 1.0;
}

bool gauss_newton(const Correspondences& data, const LinePairTable& pairs, const RigidTransform& T0,
                  const RefineOptions& options, const LockedSubspace* locked, RefineResult* result) {
  RefineResult res;
  res.T = T0;
  const double weight_scale = pair_weight_scale(data);

  RigidTransform T = T0;
  bool ok = true;
  NormalEquations ne;
  bool ne_at_T = false;
  for (int it = 0; it < options.iterations; ++it) {
    ne = accumulate(data, pairs, T, options, weight_scale);
    ne_at_T = true;
    if (ne.residuals < 6) {
      ok = false;
      break;
    }
    Vec6 dx;
    if (locked) {
      dx = locked->step(ne.H, ne.g);
    } else {
      const double damping = 1e-12 * std::max(ne.H.trace(), 1e-30);
      dx = (ne.H + damping * Mat6::Identity()).ldlt().solve(-ne.g);
    }
    if (!dx.allFinite()) {
      ok = false;
      break;
    }
    res.iterations = it + 1;
    // Converged: a step this small is not taken, so the equations just built are those of the result.
    if (dx.head<3>().norm() < kConvergedTranslation && dx.tail<3>().norm() < kConvergedRotation) break;
    T = se3_exp(dx) * T;
    ne_at_T = false;
  }
  if (!ok || !ne_at_T) ne = accumulate(data, pairs, ok ? T : T0, options, weight_scale);
  if (!ok || ne.residuals < 6 || !T.is_finite()) {
    res.T = T0;
    res.line_inliers = ne.line_inliers;
    res.line_inlier_weight = ne.line_inlier_weight;
    res.plane_inliers = ne.plane_inliers;
    res.degenerate = true;
    if (result) *result = res;
    return false;
  }
  res.T = T;
  res.line_inliers = ne.line_inliers;
  res.line_inlier_weight = ne.line_inlier_weight;
  res.plane_inliers = ne.plane_inliers;
  res.residual_rms = ne.line_inliers > 0 ? std::sqrt(ne.line_sq / ne.line_inliers) : 0.0;
  Mat6 free_inv = Mat6::Zero();  // locked: (Q Hs Q)^+ at the result
  if (locked) {
    // Condition of the free directions alone: the locked ones are the `count` zero eigenvalues of Q Hs Q.
    const Mat6 Hs = locked->scaled(ne.H);
    const Mat6 Q = locked->free_projector();
    Eigen::SelfAdjointEigenSolver<Mat6> es(Q * Hs * Q, Eigen::EigenvaluesOnly);
    const double lmax = es.eigenvalues()(5);
    res.condition = lmax > 0.0 ? std::max(0.0, es.eigenvalues()(locked->count) / lmax) : 0.0;
    res.locked_directions = locked->count;
    for (int k = 0; k < locked->count; ++k)
      res.locked_basis.col(k) = (locked->scale.asDiagonal() * locked->locked.col(k)).normalized();
    free_inv = locked->free_inverse(Hs);
    res.held_sensitivity = locked->held_sensitivity(Hs, free_inv);
  } else {
    res.condition = scaled_condition(ne.H);
  }
  res.degenerate = !(res.condition >= options.degeneracy_threshold);
  if (options.compute_covariance) {
    // sigma^2 from the residuals, floored so an exact fit still gives a positive definite covariance.
    const int dof = std::max(1, ne.residuals - 6 + (locked ? locked->count : 0));
    const double sigma_floor = 1e-3 * options.line_threshold;
    const double sigma2 = std::max(ne.weighted_sq / dof, sigma_floor * sigma_floor);
    Mat6 cov = locked ? Mat6(sigma2 * locked->free_covariance(free_inv)) : covariance_from(ne.H, sigma2);
    cov = 0.5 * (cov + cov.transpose());
    if (cov.allFinite()) res.covariance = cov;
  }
  if (result) *result = res;
  return true;
}

}  // namespace

bool refine_motion(const Correspondences& data, const LinePairTable& pairs, const RigidTransform& T0,
                   const RefineOptions& options, RefineResult* result) {
  return gauss_newton(data, pairs, T0, options, nullptr, result);
}

Vec6 motion_difference(const RigidTransform& T, const RigidTransform& reference) {
  const RigidTransform D = T * reference.inverse();
  const Eigen::AngleAxisd aa(D.R);
  Vec6 xi;
  xi << D.t, aa.angle() * aa.axis();
  return xi;
}

RigidTransform apply_motion_difference(const Vec6& xi, const RigidTransform& reference) {
  RigidTransform step;
  const double angle = xi.tail<3>().norm();
  if (angle > 1e-15) step.R = Eigen::AngleAxisd(angle, xi.tail<3>() / angle).toRotationMatrix();
  step.t = xi.head<3>();
  return step * reference;
}

bool refine_motion_partial(const Correspondences& data, const LinePairTable& pairs, const RigidTransform& T_from,
                           const RigidTransform& prior, int locked_axes, bool lock_weak, const RefineOptions& options,
                           RefineResult* result, const Mat6* locked_projector) {
  if (result) *result = RefineResult{};
  if (result) result->T = T_from;
  const NormalEquations ne = accumulate(data, pairs, T_from, options, pair_weight_scale(data));
  LockedSubspace locked;
  if (ne.residuals < 6 || !block_scale(ne.H, &locked.scale)) return false;
  auto lock = [&](Vec6 u) {  // Gram-Schmidt against the directions locked so far
    for (int k = 0; k < locked.count; ++k) u -= locked.locked.col(k).dot(u) * locked.locked.col(k);
    if (u.norm() > 1e-6 && locked.count < 6) locked.locked.col(locked.count++) = u.normalized();
  };
  for (int axis = 0; axis < 6; ++axis)
    if (locked_axes & (1 << axis)) lock(Vec6::Unit(axis));
  if (locked_projector != nullptr) {  // its directions in xi, u, are S^-1 u in the scaled coordinates
    const Eigen::SelfAdjointEigenSolver<Mat6> es(*locked_projector);
    for (int k = 0; k < 6; ++k)
      if (es.eigenvalues()(k) > 0.5) lock(locked.scale.cwiseInverse().asDiagonal() * es.eigenvectors().col(k));
  }
  if (lock_weak) {
    Eigen::SelfAdjointEigenSolver<Mat6> es(locked.scaled(ne.H));
    const double lmax = es.eigenvalues()(5);
    for (int k = 0; k < 5; ++k)
      if (!(es.eigenvalues()(k) >= options.degeneracy_threshold * lmax)) lock(es.eigenvectors().col(k));
  }
  if (locked.count == 0 || locked.count >= 6) return false;
  // Start from T_from with its locked components replaced by the prior's.
  const Vec6 xi_s = locked.scale.cwiseInverse().asDiagonal() * motion_difference(T_from, prior);
  const Vec6 start = locked.scale.asDiagonal() * (locked.free_projector() * xi_s);
  return gauss_newton(data, pairs, apply_motion_difference(start, prior), options, &locked, result);
}

}  // namespace line_odom
