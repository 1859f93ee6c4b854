// 1L2P (paper §5.1). Canonical frame of each scan: plane 2 -> z = 0 (normal +z), the line where planes 1 and 2
// meet -> x axis with direction n2 x n1. Both frames then differ by R = I, t = (t1, 0, 0), and the one line
// intersection is linear in t1. Undone canonical frames: R = Q_a^T Q_b, t = p_a - R p_b + t1 e_x(a).
#include "solvers/solve_1l2p.hpp"

#include <cmath>

#include "solvers/solver_input.hpp"

namespace line_odom {
namespace {

constexpr double kMinPlaneSine = 1e-3;      // |n1 x n2| below this: planes (near) parallel
constexpr double kMinLineCoefficient = 1e-10;  // |d(line)/d t1| below this: the line does not fix t1

struct CanonicalFrame {
  Vec3 ex, ey, ez;  // rows of Q (canonical axes in scan coordinates)
  Vec3 origin;      // point of the x axis closest to the scan origin
  double cos_dihedral, sin_dihedral;
};

bool canonical_frame(const Plane& plane1, const Plane& plane2, CanonicalFrame* f) {
  const Vec3 c = plane2.n.cross(plane1.n);
  const double s = c.norm();
  if (!(s > kMinPlaneSine)) return false;
  f->ex = c / s;
  f->ez = plane2.n;
  f->ey = f->ez.cross(f->ex);
  // n1·x = -delta1, n2·x = -delta2, c·x = 0
  f->origin = (plane1.delta * plane2.n.cross(c) + plane2.delta * c.cross(plane1.n)) / (s * s);
  f->cos_dihedral = plane1.n.dot(plane2.n);
  f->sin_dihedral = s;
  return true;
}

}  // namespace

int solve_1l2p(const PluckerLine& line_a, const PluckerLine& line_b, const std::array<Plane, 2>& planes_a,
               const std::array<Plane, 2>& planes_b, RigidTransform* solutions, double max_dihedral_difference) {
  PluckerLine la, lb;
  Plane pa[2], pb[2];
  if (!solver_input::normalize_line(line_a, &la) || !solver_input::normalize_line(line_b, &lb)) return 0;
  for (int k = 0; k < 2; ++k) {
    if (!solver_input::normalize_plane(planes_a[k], &pa[k]) || !solver_input::normalize_plane(planes_b[k], &pb[k]))
      return 0;
  }
  CanonicalFrame fa, fb;
  if (!canonical_frame(pa[0], pa[1], &fa) || !canonical_frame(pb[0], pb[1], &fb)) return 0;
  // cos(phi_a - phi_b) with both dihedral angles in [0, pi]
  const double cos_difference = fa.cos_dihedral * fb.cos_dihedral + fa.sin_dihedral * fb.sin_dihedral;
  if (!(cos_difference >= std::cos(max_dihedral_difference))) return 0;

  RigidTransform T;
  T.R = fa.ex * fb.ex.transpose() + fa.ey * fb.ey.transpose() + fa.ez * fb.ez.transpose();
  const Vec3 t0 = fa.origin - T.R * fb.origin;
  // d_a·(R m_b + t x R d_b) + (R d_b)·m_a = 0 with t = t0 + t1 e_x(a)
  const Vec3 Rd = T.R * lb.d;
  const Vec3 Rd_x_da = Rd.cross(la.d);
  const double coefficient = fa.ex.dot(Rd_x_da);
  if (!(std::abs(coefficient) > kMinLineCoefficient)) return 0;
  const double constant = la.d.dot(T.R * lb.m) + Rd.dot(la.m) + t0.dot(Rd_x_da);
  T.t = t0 - (constant / coefficient) * fa.ex;
  if (!T.is_finite()) return 0;
  solutions[0] = T;
  return 1;
}

}  // namespace line_odom
