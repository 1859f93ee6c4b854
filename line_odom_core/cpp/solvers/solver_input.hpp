// Input conditioning shared by the minimal solvers: unit directions and normals at the boundary, finite values,
// and orthonormal frames. Solver-internal (not part of the engine contract).
#pragma once

#include <cmath>

#include "common/types.hpp"

namespace line_odom {
namespace solver_input {

inline bool is_finite(const Vec3& v) { return std::isfinite(v.x()) && std::isfinite(v.y()) && std::isfinite(v.z()); }

// Scales (d, m) so |d| = 1 and removes the part of m along d (a valid Plücker line). False if d ~ 0 or not finite.
inline bool normalize_line(const PluckerLine& in, PluckerLine* out) {
  if (!is_finite(in.d) || !is_finite(in.m)) return false;
  const double s = in.d.norm();
  if (!(s > 1e-12)) return false;
  out->d = in.d / s;
  out->m = in.m / s;
  out->m -= out->d.dot(out->m) * out->d;
  return true;
}

// Scales (n, delta) so |n| = 1. False if n ~ 0 or not finite.
inline bool normalize_plane(const Plane& in, Plane* out) {
  if (!is_finite(in.n) || !std::isfinite(in.delta)) return false;
  const double s = in.n.norm();
  if (!(s > 1e-12)) return false;
  out->n = in.n / s;
  out->delta = in.delta / s;
  return true;
}

// A unit vector orthogonal to the unit vector n (crossed with the axis n is least aligned with).
inline Vec3 any_orthogonal(const Vec3& n) {
  const double ax = std::abs(n.x()), ay = std::abs(n.y()), az = std::abs(n.z());
  Vec3 v;
  if (ax <= ay && ax <= az) {
    v = Vec3(0.0, n.z(), -n.y());  // e_x x n
  } else if (ay <= az) {
    v = Vec3(-n.z(), 0.0, n.x());  // e_y x n
  } else {
    v = Vec3(n.y(), -n.x(), 0.0);  // e_z x n
  }
  return v.normalized();
}

}  // namespace solver_input
}  // namespace line_odom
