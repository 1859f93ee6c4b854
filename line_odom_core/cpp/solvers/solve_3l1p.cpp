// 3L1P (paper §5.2). Canonical frame of each scan: the plane -> z = 0 with normal +z. The frames then differ by
// R = Rz(theta), t = (t1, t2, 0) and intersection i reads A_i + t1 B_i + t2 C_i = 0, A, B, C affine in
// (cos theta, sin theta). det[A B C](theta) has no third harmonic (the e^{i theta} parts of the B and C columns
// are proportional), so it is a trigonometric polynomial of degree 2: five samples give it exactly, and with
// u = tan(phi/2) it is the quartic of the paper. phi is measured from theta0 chosen so that u = infinity falls
// on the sample where |det| is largest, which keeps the quartic's leading coefficient away from zero
// (theta near pi needs no special case).
#include "solvers/solve_3l1p.hpp"

#include <algorithm>
#include <cmath>

#include "solvers/polynomial_roots.hpp"
#include "solvers/solver_input.hpp"

namespace line_odom {
namespace {

constexpr double kDegenerateDeterminant = 1e-10;  // max |det| samples relative to its natural scale
constexpr double kMinPairDeterminant = 1e-12;     // |B_i C_j - B_j C_i| (dimensionless)

// Entry (c, s) = k0 + kc c + ks s.
struct Affine {
  double k0, kc, ks;
  double at(double c, double s) const { return k0 + kc * c + ks * s; }
};

struct Row {
  Affine A, B, C;
};

struct PlaneFrame {
  Mat3 Q;      // rows: canonical axes in scan coordinates (third row = plane normal)
  Vec3 origin; // foot of the perpendicular from the scan origin to the plane
};

PlaneFrame plane_frame(const Plane& plane) {
  PlaneFrame f;
  const Vec3 ex = solver_input::any_orthogonal(plane.n);
  f.Q.row(0) = ex.transpose();
  f.Q.row(1) = plane.n.cross(ex).transpose();
  f.Q.row(2) = plane.n.transpose();
  f.origin = -plane.delta * plane.n;
  return f;
}

// Line in canonical coordinates x_c = Q (x - origin): d_c = Q d, m_c = Q (m - origin x d).
PluckerLine to_canonical(const PlaneFrame& f, const PluckerLine& l) {
  return {f.Q * l.d, f.Q * (l.m - f.origin.cross(l.d))};
}

// Intersection constraint a·(R mb) + ma·(R b) + t·(R b x a) = 0 with R = Rz(theta), t = (t1, t2, 0).
Row constraint_row(const PluckerLine& la, const PluckerLine& lb) {
  const Vec3 &a = la.d, &ma = la.m, &b = lb.d, &mb = lb.m;
  Row r;
  r.A.k0 = a.z() * mb.z() + ma.z() * b.z();
  r.A.kc = a.x() * mb.x() + a.y() * mb.y() + ma.x() * b.x() + ma.y() * b.y();
  r.A.ks = a.y() * mb.x() - a.x() * mb.y() + ma.y() * b.x() - ma.x() * b.y();
  r.B = {-b.z() * a.y(), b.y() * a.z(), b.x() * a.z()};
  r.C = {b.z() * a.x(), -b.x() * a.z(), b.y() * a.z()};
  return r;
}

double determinant_at(const Row* rows, double c, double s) {
  double m[3][3];
  for (int i = 0; i < 3; ++i) {
    m[i][0] = rows[i].A.at(c, s);
    m[i][1] = rows[i].B.at(c, s);
    m[i][2] = rows[i].C.at(c, s);
  }
  return m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1]) - m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0]) +
         m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0]);
}

}  // namespace

int solve_3l1p(const std::array<PluckerLine, 3>& lines_a, const std::array<PluckerLine, 3>& lines_b,
               const Plane& plane_a, const Plane& plane_b, RigidTransform* solutions) {
  Plane pa, pb;
  if (!solver_input::normalize_plane(plane_a, &pa) || !solver_input::normalize_plane(plane_b, &pb)) return 0;
  const PlaneFrame fa = plane_frame(pa), fb = plane_frame(pb);
  Row rows[3];
  double scale = 0.0;  // bound on |det| up to a constant: linear in the A column (moments), B and C <= 1
  for (int i = 0; i < 3; ++i) {
    PluckerLine la, lb;
    if (!solver_input::normalize_line(lines_a[i], &la) || !solver_input::normalize_line(lines_b[i], &lb)) return 0;
    const PluckerLine ca = to_canonical(fa, la), cb = to_canonical(fb, lb);
    rows[i] = constraint_row(ca, cb);
    scale = std::max(scale, 1.0 + ca.m.norm() + cb.m.norm());
  }
  if (!(scale > 0.0) || !std::isfinite(scale)) return 0;

  // Samples f_k = det at theta_k = 2 pi k / 5 -> f = a0 + a1 cos + b1 sin + a2 cos 2theta + b2 sin 2theta
  static const double kCos[5] = {1.0, std::cos(2 * kPi / 5), std::cos(4 * kPi / 5), std::cos(6 * kPi / 5),
                                 std::cos(8 * kPi / 5)};
  static const double kSin[5] = {0.0, std::sin(2 * kPi / 5), std::sin(4 * kPi / 5), std::sin(6 * kPi / 5),
                                 std::sin(8 * kPi / 5)};
  double f[5];
  int k_max = 0;
  for (int k = 0; k < 5; ++k) {
    f[k] = determinant_at(rows, kCos[k], kSin[k]);
    if (std::abs(f[k]) > std::abs(f[k_max])) k_max = k;
  }
  if (!(std::abs(f[k_max]) > kDegenerateDeterminant * scale)) return 0;  // det vanishes identically
  double a0 = 0, a1 = 0, b1 = 0, a2 = 0, b2 = 0;
  for (int k = 0; k < 5; ++k) {
    const int k2 = (2 * k) % 5;
    a0 += f[k];
    a1 += f[k] * kCos[k];
    b1 += f[k] * kSin[k];
    a2 += f[k] * kCos[k2];
    b2 += f[k] * kSin[k2];
  }
  a0 *= 0.2;
  a1 *= 0.4;
  b1 *= 0.4;
  a2 *= 0.4;
  b2 *= 0.4;
  // theta = theta0 + phi with theta0 = theta_kmax - pi, so phi = pi (u = infinity) is the largest sample.
  const double c0 = -kCos[k_max], s0 = -kSin[k_max];
  const double c20 = c0 * c0 - s0 * s0, s20 = 2.0 * c0 * s0;
  const double a1p = a1 * c0 + b1 * s0, b1p = b1 * c0 - a1 * s0;
  const double a2p = a2 * c20 + b2 * s20, b2p = b2 * c20 - a2 * s20;
  // (1 + u^2)^2 g(phi) with cos phi = (1-u^2)/(1+u^2), sin phi = 2u/(1+u^2)
  const double quartic[5] = {a0 - a1p + a2p, 2.0 * b1p - 4.0 * b2p, 2.0 * a0 - 6.0 * a2p, 2.0 * b1p + 4.0 * b2p,
                             a0 + a1p + a2p};
  double roots[4];
  const int root_count = polynomial_roots::quartic_roots(quartic, roots);

  int count = 0;
  double accepted[4];
  for (int r = 0; r < root_count; ++r) {
    const double u = roots[r];
    if (!std::isfinite(u)) continue;
    bool duplicate = false;
    for (int q = 0; q < count; ++q) duplicate |= std::abs(accepted[q] - u) <= 1e-12 * (1.0 + std::abs(u));
    if (duplicate) continue;
    const double w = 1.0 / (1.0 + u * u);
    const double cp = (1.0 - u * u) * w, sp = 2.0 * u * w;
    const double c = c0 * cp - s0 * sp, s = s0 * cp + c0 * sp;
    double A[3], B[3], C[3];
    for (int i = 0; i < 3; ++i) {
      A[i] = rows[i].A.at(c, s);
      B[i] = rows[i].B.at(c, s);
      C[i] = rows[i].C.at(c, s);
    }
    // null vector (1, t1, t2): the best-conditioned pair of rows
    int bi = 0, bj = 1;
    double det2 = 0.0;
    for (int i = 0; i < 3; ++i) {
      const int j = (i + 1) % 3;
      const double d = B[i] * C[j] - B[j] * C[i];
      if (std::abs(d) > std::abs(det2)) {
        det2 = d;
        bi = i;
        bj = j;
      }
    }
    if (!(std::abs(det2) > kMinPairDeterminant)) continue;
    const double t1 = (A[bj] * C[bi] - A[bi] * C[bj]) / det2;
    const double t2 = (A[bi] * B[bj] - A[bj] * B[bi]) / det2;

    Mat3 Rz;
    Rz << c, -s, 0.0, s, c, 0.0, 0.0, 0.0, 1.0;
    RigidTransform T;
    T.R = fa.Q.transpose() * Rz * fb.Q;
    T.t = fa.origin + fa.Q.transpose() * Vec3(t1, t2, 0.0) - T.R * fb.origin;
    if (!T.is_finite()) continue;
    accepted[count] = u;
    solutions[count++] = T;
  }
  return count;
}

}  // namespace line_odom
