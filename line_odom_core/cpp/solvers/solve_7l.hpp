// 7L solver (paper §4): seven line intersections, solved from a pose guess by alternating projection
// (intersection projection, then per-frame rigidity projection), or by Gauss-Newton on SE(3) over the
// seven signed line distances.
#pragma once

#include <array>
#include <limits>

#include "common/types.hpp"

namespace line_odom {

enum class Solve7LMethod { kAlternatingProjection, kGaussNewton };

struct Solve7LOptions {
  Solve7LMethod method = Solve7LMethod::kGaussNewton;
  int max_iterations = 30000;  // the paper's alternating projection needs up to 30K
  double tolerance = 1e-12;    // stop when the update falls under this
  // Reject a converged pose whose largest |signed line distance| exceeds this (m). Noisy samples never meet
  // all seven exactly, so the default accepts any converged pose and leaves the judgement to the caller.
  double max_residual = std::numeric_limits<double>::infinity();
};

struct Solve7LStats {
  int iterations = 0;
  double residual = 0.0;  // max |signed line distance| at the solution
  bool converged = false;
};

// Returns 1 and writes T_ab to `solution` when the iteration converged, the residual is within max_residual
// and the seven lines fix all six degrees of freedom there; else 0 (degenerate, diverged or not finite).
int solve_7l(const std::array<Segment, 7>& segments_a, const std::array<Segment, 7>& segments_b,
             const RigidTransform& init, RigidTransform* solution, const Solve7LOptions& options = {},
             Solve7LStats* stats = nullptr);

}  // namespace line_odom
