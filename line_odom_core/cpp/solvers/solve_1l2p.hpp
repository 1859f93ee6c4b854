// 1L2P minimal solver (paper §5.1): one line intersection + two plane correspondences.
// Constraint: line_a meets T·line_b; planes_a[k] = T·planes_b[k]. At most one solution.
#pragma once

#include <array>

#include "common/types.hpp"

namespace line_odom {

constexpr int kMaxSolutions1L2P = 1;

// Dihedral angles between the two planes of each frame must agree within this (rad): a rigid motion keeps
// it; with noisy planes it absorbs the noise, a wrong plane pair usually exceeds it.
constexpr double kMaxDihedralDifference1L2P = 0.1;

// Returns the number of solutions written to `solutions` (capacity kMaxSolutions1L2P); 0 when degenerate
// (near-parallel planes, dihedral angles that differ, a line that gives no constraint on t1).
int solve_1l2p(const PluckerLine& line_a, const PluckerLine& line_b, const std::array<Plane, 2>& planes_a,
               const std::array<Plane, 2>& planes_b, RigidTransform* solutions,
               double max_dihedral_difference = kMaxDihedralDifference1L2P);

}  // namespace line_odom
