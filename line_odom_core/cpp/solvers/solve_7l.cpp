// 7L (paper §4). Two methods from the same pose guess:
// - alternating projection: (1) intersection projection, each pair's four endpoints move by half the gap between
//   the closest points of the two lines; (2) rigidity projection, per frame the rigid transform (Kabsch) that best
//   maps the original endpoints onto the moved ones. Repeat until no endpoint moves more than the tolerance.
// - Gauss-Newton (Levenberg-Marquardt damped) on SE(3) over the seven signed line distances, T <- exp(xi) T.
// Both end with the same acceptance test: residual and rank of the 7x6 Jacobian at the solution.
#include "solvers/solve_7l.hpp"

#include <Eigen/SVD>
#include <algorithm>
#include <cmath>
#include <cstring>
#include <limits>
#include <utility>

#include "common/simd.hpp"
#include "solvers/solver_input.hpp"

namespace line_odom {
namespace {

using Mat76 = Eigen::Matrix<double, 7, 6>;
using Vec7 = Eigen::Matrix<double, 7, 1>;

constexpr double kMinSegmentLength = 1e-9;
constexpr double kMinLineSine = 1e-6;         // |d_a x d_b'| floor of the signed distance's denominator
constexpr double kMinSingularRatio = 1e-7;    // sigma_min / sigma_max of the Jacobian: below it, degenerate
constexpr double kMaxDamping = 1e10;
constexpr double kMinRelativeDecrease = 1e-8;  // an accepted step gaining less than this: converged

struct LinePairs {
  std::array<PluckerLine, 7> a, b;
};

// Line b_i moved by T (d', m') and the terms of its signed distance to line a_i: c = d_a x d', n = max(|c|, floor),
// e = d_a·m' + d'·m_a, r_i = e / n. Scalar code with the operations (and their order) Eigen uses for the same
// expressions: rows 0, 1 of R x as (r0 x0 + r1 x1) + r2 x2, row 2 as r0 x0 + (r1 x1 + r2 x2); dot products and
// norms as (p0 + p1) + p2.
struct MovedPair {
  double d[3], m[3], c[3], n, e;
};
using MovedPairs = std::array<MovedPair, 7>;

inline void mat_vec(const Mat3& R, const double* x, double* y) {
  y[0] = (R(0, 0) * x[0] + R(0, 1) * x[1]) + R(0, 2) * x[2];
  y[1] = (R(1, 0) * x[0] + R(1, 1) * x[1]) + R(1, 2) * x[2];
  y[2] = R(2, 0) * x[0] + (R(2, 1) * x[1] + R(2, 2) * x[2]);
}

inline void cross(const double* a, const double* b, double* c) {
  c[0] = a[1] * b[2] - a[2] * b[1];
  c[1] = a[2] * b[0] - a[0] * b[2];
  c[2] = a[0] * b[1] - a[1] * b[0];
}

inline double dot(const double* a, const double* b) { return (a[0] * b[0] + a[1] * b[1]) + a[2] * b[2]; }

// Signed distances r_i between line a_i and T b_i (and the terms the Jacobian needs).
LINE_ODOM_CLONE_INLINE void residuals(const LinePairs& lines, const RigidTransform& T, Vec7* r, MovedPairs* P) {
  const double t[3] = {T.t(0), T.t(1), T.t(2)};
  for (int i = 0; i < 7; ++i) {
    const double* da = lines.a[i].d.data();
    const double* ma = lines.a[i].m.data();
    MovedPair& p = (*P)[i];
    double Rm[3], txd[3];
    mat_vec(T.R, lines.b[i].d.data(), p.d);  // d' = R d
    mat_vec(T.R, lines.b[i].m.data(), Rm);
    cross(t, p.d, txd);
    for (int k = 0; k < 3; ++k) p.m[k] = Rm[k] + txd[k];  // m' = R m + t x d'
    cross(da, p.d, p.c);
    p.n = std::max(std::sqrt(dot(p.c, p.c)), kMinLineSine);
    p.e = dot(da, p.m) + dot(p.d, ma);
    (*r)(i) = p.e / p.n;
  }
}

// Jacobian of the r_i for T <- exp(xi) T, xi = (omega, v):
// de = omega·(m' x d_a + d' x m_a) + v·(d' x d_a);  dn = (d_a·d') c·omega / n
LINE_ODOM_CLONE_INLINE void jacobian(const LinePairs& lines, const MovedPairs& P, Mat76* J) {
  for (int i = 0; i < 7; ++i) {
    const double* da = lines.a[i].d.data();
    const double* ma = lines.a[i].m.data();
    const MovedPair& p = P[i];
    double mxd[3], dxm[3], dxd[3];
    cross(p.m, da, mxd);
    cross(p.d, ma, dxm);
    cross(p.d, da, dxd);
    const double s = dot(da, p.d) / p.n;
    const double q = p.e / (p.n * p.n);
    for (int k = 0; k < 3; ++k) {
      (*J)(i, k) = (mxd[k] + dxm[k]) / p.n - q * (s * p.c[k]);
      (*J)(i, 3 + k) = dxd[k] / p.n;
    }
  }
}

inline double sum_tree(const double* x, int n) {  // Eigen's unrolled scalar redux: halves, recursively
  switch (n) {
    case 1: return x[0];
    case 2: return x[0] + x[1];
    case 3: return x[0] + (x[1] + x[2]);
    case 4: return (x[0] + x[1]) + (x[2] + x[3]);
    default: return (x[0] + x[1]) + (x[2] + (x[3] + x[4]));
  }
}
inline double sum_packets(const double* x, int n) {  // Eigen's unrolled SSE2 redux (2 lanes)
  switch (n) {
    case 1: return x[0];
    case 2: return x[0] + x[1];
    case 3: return (x[0] + x[1]) + x[2];
    case 4: return (x[0] + x[2]) + (x[1] + x[3]);
    default: return ((x[0] + x[2]) + (x[1] + x[3])) + x[4];
  }
}
// x = A.ldlt().solve(b) for symmetric A (lower part read): Eigen's LDLT with diagonal pivoting, its cutoffs and its
// operation order (sequential sums in the factorization, the unrolled sums above in the two triangular solves), as
// plain scalar code on a local array (Eigen's version goes through dynamic-size blocks and GEMV kernels).
LINE_ODOM_CLONE_INLINE void ldlt_solve(const Mat6& A_in, const Vec6& b, Vec6* x_out) {
  double a[6][6];  // a[row][col], lower part used
  for (int i = 0; i < 6; ++i)
    for (int j = 0; j < 6; ++j) a[i][j] = A_in(i, j);
  int tr[6];
  double temp[6];
#pragma GCC unroll 6
  for (int k = 0; k < 6; ++k) {
    int p = k;
    double best = std::abs(a[k][k]);
    for (int i = k + 1; i < 6; ++i)
      if (std::abs(a[i][i]) > best) {
        best = std::abs(a[i][i]);
        p = i;
      }
    tr[k] = p;
    if (p != k) {
      for (int j = 0; j < k; ++j) std::swap(a[k][j], a[p][j]);
      for (int i = p + 1; i < 6; ++i) std::swap(a[i][k], a[i][p]);
      std::swap(a[k][k], a[p][p]);
      for (int i = k + 1; i < p; ++i) {
        const double t = a[i][k];
        a[i][k] = a[p][i];
        a[p][i] = t;
      }
    }
    if (k > 0) {
      for (int j = 0; j < k; ++j) temp[j] = a[j][j] * a[k][j];
      double s = a[k][0] * temp[0];
      for (int j = 1; j < k; ++j) s = s + a[k][j] * temp[j];
      a[k][k] -= s;
      for (int i = k + 1; i < 6; ++i) {
        double c = 0.0;
        for (int j = 0; j < k; ++j) c = c + a[i][j] * temp[j];
        a[i][k] = a[i][k] + (-c);
      }
    }
    const double akk = a[k][k];
    if (k == 0 && !(std::abs(akk) > 0.0)) {  // Eigen: zero diagonal, identity transpositions, no scaling
      for (int j = 0; j < 6; ++j) tr[j] = j;
      break;
    }
    if (std::abs(akk) > 0.0)
      for (int i = k + 1; i < 6; ++i) a[i][k] /= akk;
  }
  double x[6];
  for (int i = 0; i < 6; ++i) x[i] = b(i);
  for (int k = 0; k < 6; ++k) std::swap(x[k], x[tr[k]]);
#pragma GCC unroll 6
  for (int i = 1; i < 6; ++i) {  // L y = P b
    double t[5];
    for (int j = 0; j < i; ++j) t[j] = a[i][j] * x[j];
    x[i] -= sum_tree(t, i);
  }
  for (int i = 0; i < 6; ++i) {
    if (std::abs(a[i][i]) > std::numeric_limits<double>::min())
      x[i] /= a[i][i];
    else
      x[i] = 0.0;
  }
#pragma GCC unroll 6
  for (int i = 4; i >= 0; --i) {  // L^T z = D^-1 y
    double t[5];
    const int n = 5 - i;
    for (int j = 0; j < n; ++j) t[j] = a[i + 1 + j][i] * x[i + 1 + j];
    x[i] -= sum_packets(t, n);
  }
  for (int k = 5; k >= 0; --k) std::swap(x[k], x[tr[k]]);
  for (int i = 0; i < 6; ++i) (*x_out)(i) = x[i];
}

RigidTransform exp_left(const Vec6& xi, const RigidTransform& T) {
  const Vec3 omega = xi.head<3>();
  const double angle = omega.norm();
  const Mat3 dR = angle > 0.0 ? Eigen::AngleAxisd(angle, omega / angle).toRotationMatrix() : Mat3::Identity();
  return {dR * T.R, dR * T.t + xi.tail<3>()};
}

// Leaves r and J at the returned pose in *r_out and *J_out (the final acceptance test reuses them).
LINE_ODOM_VECTOR_CLONES bool gauss_newton(const LinePairs& lines, const RigidTransform& init,
                                          const Solve7LOptions& options, RigidTransform* T_out, int* iterations,
                                          Vec7* r_out, Mat76* J_out) {
  RigidTransform T = init;
  Vec7& r = *r_out;
  Mat76& J = *J_out;
  MovedPairs P, P_new;
  residuals(lines, T, &r, &P);
  jacobian(lines, P, &J);
  double cost = r.squaredNorm();
  double damping = 1e-9;
  bool converged = false;
  int it = 0;
  while (it < options.max_iterations) {
    ++it;
    const Mat6 H = J.transpose() * J;
    const Vec6 g = J.transpose() * r;
    Mat6 A = H;
    A.diagonal() += damping * (H.diagonal().array() + 1e-12).matrix();
    Vec6 step;
    ldlt_solve(A, g, &step);
    step = -step;
    if (!step.allFinite()) break;
    const RigidTransform T_new = exp_left(step, T);
    Vec7 r_new;
    residuals(lines, T_new, &r_new, &P_new);
    const double cost_new = r_new.squaredNorm();
    const double step_size = step.cwiseAbs().maxCoeff();
    if (cost_new <= cost) {
      const bool stalled = cost - cost_new <= kMinRelativeDecrease * cost;  // at a least-squares minimum
      T = T_new;
      cost = cost_new;
      r = r_new;
      jacobian(lines, P_new, &J);
      damping = std::max(damping * 0.1, 1e-12);
      if (step_size < options.tolerance || stalled) {
        converged = true;
        break;
      }
    } else {
      // no decrease: at the floor of rounding (or of the noise) once the step is tiny or damping is exhausted
      if (step_size < options.tolerance || damping > kMaxDamping) {
        converged = true;
        break;
      }
      damping *= 10.0;
    }
  }
  *T_out = T;
  *iterations = it;
  return converged;
}

// Closest points of the lines through (p0, p1) and (q0, q1); parallel lines use p0 and its foot on the other.
void closest_points(const Vec3& p0, const Vec3& p1, const Vec3& q0, const Vec3& q1, Vec3* on_p, Vec3* on_q) {
  const Vec3 u = p1 - p0, v = q1 - q0, w = p0 - q0;
  const double a = u.dot(u), b = u.dot(v), c = v.dot(v), d = u.dot(w), e = v.dot(w);
  const double den = a * c - b * b;
  if (den > 1e-14 * a * c) {
    *on_p = p0 + ((b * e - c * d) / den) * u;
    *on_q = q0 + ((a * e - b * d) / den) * v;
  } else {
    *on_p = p0;
    *on_q = q0 + (e / c) * v;
  }
}

// Orthogonal polar factor of M (the Kabsch rotation for M = H^T) by scaled Newton iteration X <- (g X + X^-T / g)/2.
// False when M is near singular or det M <= 0 (the caller then uses the SVD with the reflection fix).
bool polar_rotation(const Mat3& M, Mat3* R) {
  Mat3 X = M;
  double det = X.determinant();
  const double size = X.norm();
  if (!(det > 1e-9 * size * size * size)) return false;
  for (int it = 0; it < 30; ++it) {
    const Mat3 inv_t = X.inverse().transpose();
    const double g = std::sqrt(std::sqrt(inv_t.squaredNorm() / X.squaredNorm()));  // Frobenius scaling
    const Mat3 next = 0.5 * (g * X + inv_t / g);
    const double change = (next - X).cwiseAbs().maxCoeff();
    X = next;
    if (change < 1e-15) break;
  }
  *R = X;
  return X.allFinite();
}

// Rigid transform minimizing sum |R src_i + t - dst_i|^2 (Kabsch); src_centered = src - src_mean.
RigidTransform kabsch(const std::array<Vec3, 14>& src_centered, const Vec3& src_mean, const std::array<Vec3, 14>& dst) {
  Vec3 dst_mean = Vec3::Zero();
  for (const Vec3& q : dst) dst_mean += q;
  dst_mean /= 14.0;
  Mat3 H = Mat3::Zero();
  for (int i = 0; i < 14; ++i) H.noalias() += src_centered[i] * (dst[i] - dst_mean).transpose();
  RigidTransform T;
  if (!polar_rotation(H.transpose(), &T.R)) {
    const Eigen::JacobiSVD<Mat3> svd(H, Eigen::ComputeFullU | Eigen::ComputeFullV);
    Mat3 V = svd.matrixV();
    if ((V * svd.matrixU().transpose()).determinant() < 0.0) V.col(2) = -V.col(2);
    T.R = V * svd.matrixU().transpose();
  }
  T.t = dst_mean - T.R * src_mean;
  return T;
}

bool alternating_projection(const std::array<Segment, 7>& segments_a, const std::array<Segment, 7>& segments_b,
                            const RigidTransform& init, const Solve7LOptions& options, RigidTransform* T_out,
                            int* iterations) {
  std::array<Vec3, 14> src_a, src_b, cur_a, cur_b, moved_a, moved_b;
  for (int i = 0; i < 7; ++i) {
    src_a[2 * i] = segments_a[i].a;
    src_a[2 * i + 1] = segments_a[i].b;
    src_b[2 * i] = segments_b[i].a;
    src_b[2 * i + 1] = segments_b[i].b;
  }
  Vec3 mean_a = Vec3::Zero(), mean_b = Vec3::Zero();
  for (int k = 0; k < 14; ++k) {
    mean_a += src_a[k];
    mean_b += src_b[k];
  }
  mean_a /= 14.0;
  mean_b /= 14.0;
  std::array<Vec3, 14> centered_a, centered_b;
  for (int k = 0; k < 14; ++k) {
    centered_a[k] = src_a[k] - mean_a;
    centered_b[k] = src_b[k] - mean_b;
    cur_a[k] = src_a[k];
    cur_b[k] = init.apply(src_b[k]);
  }
  RigidTransform Ta, Tb = init;  // current rigid placement of each frame
  bool converged = false;
  int it = 0;
  while (it < options.max_iterations) {
    ++it;
    for (int i = 0; i < 7; ++i) {  // intersection projection
      Vec3 m, n;
      closest_points(cur_a[2 * i], cur_a[2 * i + 1], cur_b[2 * i], cur_b[2 * i + 1], &m, &n);
      const Vec3 half_gap = 0.5 * (n - m);
      moved_a[2 * i] = cur_a[2 * i] + half_gap;
      moved_a[2 * i + 1] = cur_a[2 * i + 1] + half_gap;
      moved_b[2 * i] = cur_b[2 * i] - half_gap;
      moved_b[2 * i + 1] = cur_b[2 * i + 1] - half_gap;
    }
    Ta = kabsch(centered_a, mean_a, moved_a);  // rigidity projection
    Tb = kabsch(centered_b, mean_b, moved_b);
    double update = 0.0;  // largest endpoint movement (paper §4: iterate until the updates fall under epsilon)
    for (int k = 0; k < 14; ++k) {
      const Vec3 na = Ta.apply(src_a[k]), nb = Tb.apply(src_b[k]);
      update = std::max(update, std::max((na - cur_a[k]).cwiseAbs().maxCoeff(), (nb - cur_b[k]).cwiseAbs().maxCoeff()));
      cur_a[k] = na;
      cur_b[k] = nb;
    }
    if (!(update == update)) break;  // NaN
    if (update < options.tolerance) {
      converged = true;
      break;
    }
  }
  *T_out = Ta.inverse() * Tb;
  *iterations = it;
  return converged;
}


// U V^T of the SVD U S V^T of R (the nearest orthogonal matrix). RANSAC passes the same guess for every sample
// of a frame, so the last result is kept per thread and reused for a bit-identical input.
Mat3 nearest_rotation(const Mat3& R) {
  struct Cache {
    double in[9];
    double out[9];
    bool valid;
  };
  static thread_local Cache cache{};
  if (cache.valid && std::memcmp(cache.in, R.data(), sizeof(cache.in)) == 0) return Eigen::Map<const Mat3>(cache.out);
  const Eigen::JacobiSVD<Mat3> svd(R, Eigen::ComputeFullU | Eigen::ComputeFullV);
  const Mat3 Q = svd.matrixU() * svd.matrixV().transpose();
  std::memcpy(cache.in, R.data(), sizeof(cache.in));
  std::memcpy(cache.out, Q.data(), sizeof(cache.out));
  cache.valid = true;
  return Q;
}

// Cheap sufficient test for the rank check sigma_min(J) > kMinSingularRatio sigma_max(J) done by the SVD below.
// With H = J^T J = L D L^T: sigma_max^2 <= trace(H) and sigma_min^2 >= 1 / trace(H^-1), trace(H^-1) = sum_i
// |row i of L^-1|^2 / d_i. True when trace(H) trace(H^-1) < 1e10, i.e. the ratio is provably above 1e-5: 100x
// the threshold, far beyond the rounding of H, of the factorization (relative ~1e-14 of trace(H)) and of the SVD
// itself, so the SVD would accept too. False (run the SVD) in every other case, incl. non-finite or extreme scales.
bool clearly_full_rank(const Mat76& J) {
  double H[6][6];
  for (int i = 0; i < 6; ++i)
    for (int j = 0; j <= i; ++j) {
      double s = 0.0;
      for (int k = 0; k < 7; ++k) s += J(k, i) * J(k, j);
      H[i][j] = s;
    }
  double trace = 0.0;
  for (int i = 0; i < 6; ++i) trace += H[i][i];
  if (!(trace > 1e-150 && trace < 1e150)) return false;
  // H = L D L^T (unit lower L; stored below the diagonal of H, D on it)
  double d[6];
  for (int j = 0; j < 6; ++j) {
    double dj = H[j][j];
    for (int k = 0; k < j; ++k) dj -= H[j][k] * H[j][k] * d[k];
    if (!(dj > 1e-12 * trace)) return false;  // ratio below 1e-6 (or NaN): leave it to the SVD
    d[j] = dj;
    for (int i = j + 1; i < 6; ++i) {
      double s = H[i][j];
      for (int k = 0; k < j; ++k) s -= H[i][k] * H[j][k] * d[k];
      H[i][j] = s / dj;
    }
  }
  // X = L^-1 (unit lower), row by row; trace(H^-1) = sum_{i,k} X_ik^2 / d_i
  double X[6][6];
  double trace_inv = 0.0;
  for (int i = 0; i < 6; ++i) {
    for (int k = 0; k < i; ++k) {
      double s = -H[i][k];
      for (int m = k + 1; m < i; ++m) s -= H[i][m] * X[m][k];
      X[i][k] = s;
    }
    X[i][i] = 1.0;
    double row = 1.0;
    for (int k = 0; k < i; ++k) row += X[i][k] * X[i][k];
    trace_inv += row / d[i];
  }
  return trace * trace_inv < 1e10;
}
}  // namespace

int solve_7l(const std::array<Segment, 7>& segments_a, const std::array<Segment, 7>& segments_b,
             const RigidTransform& init, RigidTransform* solution, const Solve7LOptions& options,
             Solve7LStats* stats) {
  Solve7LStats local;
  Solve7LStats& st = stats ? *stats : local;
  st = Solve7LStats{};
  if (!init.is_finite()) return 0;
  LinePairs lines;
  for (int i = 0; i < 7; ++i) {
    const Segment& sa = segments_a[i];
    const Segment& sb = segments_b[i];
    if (!solver_input::is_finite(sa.a) || !solver_input::is_finite(sa.b) || !solver_input::is_finite(sb.a) ||
        !solver_input::is_finite(sb.b))
      return 0;
    // Segment::length() and Segment::line() (PluckerLine::through) with the norm computed once: the same values
    const Vec3 va = sa.b - sa.a, vb = sb.b - sb.a;
    const double length_a = va.norm(), length_b = vb.norm();
    if (!(length_a > kMinSegmentLength) || !(length_b > kMinSegmentLength)) return 0;
    lines.a[i].d = va / length_a;
    lines.a[i].m = sa.a.cross(lines.a[i].d);
    lines.b[i].d = vb / length_b;
    lines.b[i].m = sb.a.cross(lines.b[i].d);
  }
  RigidTransform T;
  // start from a proper rotation even if the guess is slightly off SO(3)
  RigidTransform start = init;
  start.R = nearest_rotation(init.R);
  if (start.R.determinant() < 0.0) return 0;
  Vec7 r;
  Mat76 J;
  if (options.method == Solve7LMethod::kGaussNewton) {
    st.converged = gauss_newton(lines, start, options, &T, &st.iterations, &r, &J);
    if (!T.is_finite()) return 0;
  } else {
    st.converged = alternating_projection(segments_a, segments_b, start, options, &T, &st.iterations);
    if (!T.is_finite()) return 0;
    MovedPairs P;
    residuals(lines, T, &r, &P);
    jacobian(lines, P, &J);
  }
  st.residual = r.cwiseAbs().maxCoeff();
  if (!st.converged || !(st.residual <= options.max_residual)) return 0;
  if (clearly_full_rank(J)) {
    *solution = T;
    return 1;
  }
  const Eigen::JacobiSVD<Mat76> jacobian_svd(J);  // singular values only, fixed size: no allocation
  const double hi = jacobian_svd.singularValues()(0), lo = jacobian_svd.singularValues()(5);
  if (!(hi > 0.0) || !(lo > kMinSingularRatio * hi)) return 0;
  *solution = T;
  return 1;
}

}  // namespace line_odom
