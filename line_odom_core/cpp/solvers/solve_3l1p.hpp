// 3L1P minimal solver (paper §5.2): three line intersections + one plane correspondence.
// Canonical frame: plane -> z = 0, so R = Rz(theta), t = (t1, t2, 0); det[A B C] = 0 is a quartic in
// u = tan(theta/2) once the factor (1 + u^2) is divided out (docs/DESIGN.md §3). At most four solutions.
#pragma once

#include <array>

#include "common/types.hpp"

namespace line_odom {

constexpr int kMaxSolutions3L1P = 4;

// Returns the number of solutions written to `solutions` (capacity kMaxSolutions3L1P).
int solve_3l1p(const std::array<PluckerLine, 3>& lines_a, const std::array<PluckerLine, 3>& lines_b,
               const Plane& plane_a, const Plane& plane_b, RigidTransform* solutions);

}  // namespace line_odom
