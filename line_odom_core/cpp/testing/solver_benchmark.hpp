// Timing and correctness of the minimal solvers on seeded synthetic instances (docs/DESIGN.md §6): random pose,
// exact noise-free minimal sample, C++ timing loop (no Python per call), median over repetitions, and the
// found-ground-truth rate (some returned pose within found_tolerance of the truth, max abs 4x4 entry).
#pragma once

#include <cstdint>
#include <string>

#include "solvers/solve_7l.hpp"

namespace line_odom {

struct SolverBenchmarkOptions {
  std::string solver = "3l1p";  // "1l2p", "3l1p" or "7l"
  int instances = 1000;         // distinct random instances, generated before timing
  int repetitions = 5;          // timed passes over all instances
  int chunk = 0;                // calls per timed chunk (0: 128 for 1L2P/3L1P, 8 for 7L Gauss-Newton, 1 otherwise)
  std::uint64_t seed = 0;
  double found_tolerance = 1e-6;
  double max_translation = 2.0;         // |t_i| of the true pose uniform in [-max, max] (m); rotation uniform
  double scene_radius = 10.0;           // intersection points uniform in [-r, r]^3 (m)
  Solve7LOptions solve_7l;              // 7L method and stopping rule
  double guess_rotation_deg = 5.0;      // 7L starts from the truth moved by up to this rotation ...
  double guess_translation = 0.5;       // ... and up to this translation (m)
};

struct SolverBenchmarkResult {
  int instances = 0;
  int repetitions = 0;
  double median_us = 0.0;           // per call: median over all timed chunks of all passes
  double p90_us = 0.0;              // per call: 90th percentile of the chunks
  double min_us = 0.0;              // per call: fastest chunk
  double mean_us = 0.0;             // per call: all timed calls
  int chunk = 0;
  double solutions_per_call = 0.0;
  double found_rate = 0.0;          // instances with a solution within found_tolerance of the truth
  double no_solution_rate = 0.0;    // instances with no solution at all
  double median_error = 0.0;        // over instances: error of the closest solution (inf when none)
  double p99_error = 0.0;
  double mean_iterations = 0.0;     // 7L only
};

// Throws std::invalid_argument on an unknown solver name or non-positive counts.
SolverBenchmarkResult benchmark_solver(const SolverBenchmarkOptions& options);

}  // namespace line_odom
