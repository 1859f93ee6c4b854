// Geometry types shared by the whole engine (docs/DESIGN.md §3).
// Poses T_ab map frame-b coordinates into frame a: x_a = R x_b + t.
#pragma once

#include <algorithm>
#include <cmath>

#include <Eigen/Core>
#include <Eigen/Geometry>

namespace line_odom {

using Vec3 = Eigen::Vector3d;
using Vec6 = Eigen::Matrix<double, 6, 1>;
using Mat3 = Eigen::Matrix3d;
using Mat4 = Eigen::Matrix4d;
using Mat6 = Eigen::Matrix<double, 6, 6>;

constexpr double kPi = 3.14159265358979323846;

struct RigidTransform {
  Mat3 R = Mat3::Identity();
  Vec3 t = Vec3::Zero();

  static RigidTransform identity() { return {}; }
  static RigidTransform from_matrix(const Mat4& T) { return {T.topLeftCorner<3, 3>(), T.topRightCorner<3, 1>()}; }
  Mat4 matrix() const {
    Mat4 T = Mat4::Identity();
    T.topLeftCorner<3, 3>() = R;
    T.topRightCorner<3, 1>() = t;
    return T;
  }
  Vec3 apply(const Vec3& x) const { return R * x + t; }
  RigidTransform inverse() const { return {R.transpose(), -(R.transpose() * t)}; }
  RigidTransform operator*(const RigidTransform& o) const { return {R * o.R, R * o.t + t}; }
  bool is_finite() const { return R.allFinite() && t.allFinite(); }
};

// The angle of a rotation (rad).
inline double rotation_angle(const Mat3& R) { return std::acos(std::clamp((R.trace() - 1.0) / 2.0, -1.0, 1.0)); }

// Plücker line (d, m): |d| = 1, m = p x d for any point p on the line.
struct PluckerLine {
  Vec3 d = Vec3::UnitX();
  Vec3 m = Vec3::Zero();

  static PluckerLine through(const Vec3& p, const Vec3& q) {
    const Vec3 d = (q - p).normalized();
    return {d, p.cross(d)};
  }
  Vec6 vector() const { return (Vec6() << d, m).finished(); }
  // d' = R d, m' = R m + t x (R d)
  PluckerLine moved(const RigidTransform& T) const {
    const Vec3 Rd = T.R * d;
    return {Rd, T.R * m + T.t.cross(Rd)};
  }
  Vec3 closest_point_to_origin() const { return d.cross(m); }
};

// Reciprocal product d1·m2 + d2·m1: zero iff the lines meet or are parallel.
inline double reciprocal_product(const PluckerLine& l1, const PluckerLine& l2) {
  return l1.d.dot(l2.m) + l2.d.dot(l1.m);
}

// Signed distance between two lines; falls back to the parallel-line distance when |d1 x d2| is tiny.
inline double signed_line_distance(const PluckerLine& l1, const PluckerLine& l2) {
  const Vec3 c = l1.d.cross(l2.d);
  const double s = c.norm();
  if (s > 1e-9) return reciprocal_product(l1, l2) / s;
  return l1.d.cross(l2.m - l1.m).norm();
}

struct Segment {
  Vec3 a = Vec3::Zero();
  Vec3 b = Vec3::UnitX();

  PluckerLine line() const { return PluckerLine::through(a, b); }
  Segment moved(const RigidTransform& T) const { return {T.apply(a), T.apply(b)}; }
  double length() const { return (b - a).norm(); }
};

// Plane (n, delta): n·x + delta = 0, |n| = 1.
struct Plane {
  Vec3 n = Vec3::UnitZ();
  double delta = 0.0;

  Plane normalized() const {
    const double s = n.norm();
    return {n / s, delta / s};
  }
  // n' = R n, delta' = delta - n'·t
  Plane moved(const RigidTransform& T) const {
    const Vec3 Rn = T.R * n;
    return {Rn, delta - Rn.dot(T.t)};
  }
  double signed_distance(const Vec3& x) const { return n.dot(x) + delta; }
};

}  // namespace line_odom
