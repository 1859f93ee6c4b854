#include "testing/solver_benchmark.hpp"

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <limits>
#include <random>
#include <stdexcept>
#include <vector>

#include "solvers/solve_1l2p.hpp"
#include "solvers/solve_3l1p.hpp"

namespace line_odom {
namespace {


class InstanceGenerator {
 public:
  explicit InstanceGenerator(const SolverBenchmarkOptions& o) : o_(o), rng_(o.seed) {}

  Vec3 unit() {
    Vec3 v;
    do v = Vec3(normal_(rng_), normal_(rng_), normal_(rng_));
    while (v.norm() < 1e-6);
    return v.normalized();
  }
  double uniform(double lo, double hi) { return std::uniform_real_distribution<double>(lo, hi)(rng_); }

  RigidTransform pose() {
    Eigen::Quaterniond q(normal_(rng_), normal_(rng_), normal_(rng_), normal_(rng_));
    q.normalize();
    const double m = o_.max_translation;
    return {q.toRotationMatrix(), Vec3(uniform(-m, m), uniform(-m, m), uniform(-m, m))};
  }

  // The truth moved by a rotation of up to max_deg about a random axis and a translation of up to max_m.
  RigidTransform perturbed(const RigidTransform& T, double max_deg, double max_m) {
    const Mat3 dR = Eigen::AngleAxisd(uniform(0.0, max_deg) * kPi / 180.0, unit()).toRotationMatrix();
    return {dR * T.R, dR * T.t + uniform(0.0, max_m) * unit()};
  }

  Vec3 scene_point() {
    const double r = o_.scene_radius;
    return Vec3(uniform(-r, r), uniform(-r, r), uniform(-r, r));
  }

  // Segments through a common scene point: segment_a in frame a, segment_b = T^-1 of the other (frame b).
  void segment_pair(const RigidTransform& T, Segment* a, Segment* b) {
    const Vec3 X = scene_point();
    const Vec3 da = unit(), db = unit();
    *a = {X + uniform(-3.0, -0.5) * da, X + uniform(0.5, 3.0) * da};
    const Segment b_in_a{X + uniform(-3.0, -0.5) * db, X + uniform(0.5, 3.0) * db};
    *b = b_in_a.moved(T.inverse());
  }

  void line_pair(const RigidTransform& T, PluckerLine* a, PluckerLine* b) {
    Segment sa, sb;
    segment_pair(T, &sa, &sb);
    *a = sa.line();
    *b = sb.line();
  }

  void plane_pair(const RigidTransform& T, Plane* a, Plane* b) {
    const double r = o_.scene_radius;
    *a = {unit(), uniform(-r, r)};
    *b = a->moved(T.inverse());
  }

 private:
  const SolverBenchmarkOptions& o_;
  std::mt19937_64 rng_;
  std::normal_distribution<double> normal_{0.0, 1.0};
};

struct Instance {
  RigidTransform truth, init;
  std::array<PluckerLine, 3> lines_a, lines_b;
  std::array<Plane, 2> planes_a, planes_b;
  std::array<Segment, 7> segments_a, segments_b;
};

enum class Solver { k1L2P, k3L1P, k7L };

Solver parse_solver(const std::string& name) {
  if (name == "1l2p") return Solver::k1L2P;
  if (name == "3l1p") return Solver::k3L1P;
  if (name == "7l") return Solver::k7L;
  throw std::invalid_argument("benchmark_solver: solver must be '1l2p', '3l1p' or '7l', got '" + name + "'");
}

Instance make_instance(Solver solver, InstanceGenerator* gen, const SolverBenchmarkOptions& o) {
  Instance in;
  in.truth = gen->pose();
  switch (solver) {
    case Solver::k1L2P:
      gen->line_pair(in.truth, &in.lines_a[0], &in.lines_b[0]);
      for (int k = 0; k < 2; ++k) gen->plane_pair(in.truth, &in.planes_a[k], &in.planes_b[k]);
      break;
    case Solver::k3L1P:
      for (int k = 0; k < 3; ++k) gen->line_pair(in.truth, &in.lines_a[k], &in.lines_b[k]);
      gen->plane_pair(in.truth, &in.planes_a[0], &in.planes_b[0]);
      break;
    case Solver::k7L:
      for (int k = 0; k < 7; ++k) gen->segment_pair(in.truth, &in.segments_a[k], &in.segments_b[k]);
      in.init = gen->perturbed(in.truth, o.guess_rotation_deg, o.guess_translation);
      break;
  }
  return in;
}

int solve(Solver solver, const Instance& in, const Solve7LOptions& options_7l, RigidTransform* out,
          int* iterations) {
  switch (solver) {
    case Solver::k1L2P:
      return solve_1l2p(in.lines_a[0], in.lines_b[0], in.planes_a, in.planes_b, out);
    case Solver::k3L1P:
      return solve_3l1p(in.lines_a, in.lines_b, in.planes_a[0], in.planes_b[0], out);
    case Solver::k7L: {
      Solve7LStats stats;
      const int n = solve_7l(in.segments_a, in.segments_b, in.init, out, options_7l, &stats);
      *iterations += stats.iterations;
      return n;
    }
  }
  return 0;
}

double pose_error(const RigidTransform& a, const RigidTransform& b) {
  return std::max((a.R - b.R).cwiseAbs().maxCoeff(), (a.t - b.t).cwiseAbs().maxCoeff());
}

double percentile(std::vector<double> v, double q) {
  if (v.empty()) return 0.0;
  const size_t k = std::min(v.size() - 1, static_cast<size_t>(q * static_cast<double>(v.size() - 1) + 0.5));
  std::nth_element(v.begin(), v.begin() + static_cast<std::ptrdiff_t>(k), v.end());
  return v[k];
}

}  // namespace

SolverBenchmarkResult benchmark_solver(const SolverBenchmarkOptions& o) {
  const Solver solver = parse_solver(o.solver);
  if (o.instances < 1 || o.repetitions < 1)
    throw std::invalid_argument("benchmark_solver: instances and repetitions must be >= 1");
  InstanceGenerator gen(o);
  std::vector<Instance> instances;
  instances.reserve(static_cast<size_t>(o.instances));
  for (int i = 0; i < o.instances; ++i) instances.push_back(make_instance(solver, &gen, o));

  SolverBenchmarkResult result;
  result.instances = o.instances;
  result.repetitions = o.repetitions;
  RigidTransform out[4];

  // correctness pass (untimed)
  std::vector<double> errors;
  errors.reserve(instances.size());
  long solutions = 0;
  int found = 0, none = 0, iterations = 0;
  for (const Instance& in : instances) {
    const int n = solve(solver, in, o.solve_7l, out, &iterations);
    solutions += n;
    double best = std::numeric_limits<double>::infinity();
    for (int k = 0; k < n; ++k) best = std::min(best, pose_error(out[k], in.truth));
    errors.push_back(best);
    found += best <= o.found_tolerance;
    none += n == 0;
  }
  const double count = static_cast<double>(o.instances);
  result.solutions_per_call = static_cast<double>(solutions) / count;
  result.found_rate = found / count;
  result.no_solution_rate = none / count;
  result.median_error = percentile(errors, 0.5);
  result.p99_error = percentile(errors, 0.99);
  result.mean_iterations = iterations / count;

  // timed passes, each cut into chunks of consecutive calls short enough (tens of µs) that most run without
  // being preempted on a loaded machine; the per-call time of every chunk is one sample
  const int chunk = o.chunk > 0 ? o.chunk : solver == Solver::k7L ? (o.solve_7l.method == Solve7LMethod::kGaussNewton ? 8 : 1) : 128;
  std::vector<double> per_call_us;
  double total_us = 0.0;
  volatile long sink = 0;
  for (int rep = 0; rep < o.repetitions; ++rep) {
    for (size_t first = 0; first < instances.size(); first += static_cast<size_t>(chunk)) {
      const size_t last = std::min(instances.size(), first + static_cast<size_t>(chunk));
      long total = 0;
      int it = 0;
      const auto start = std::chrono::steady_clock::now();
      for (size_t i = first; i < last; ++i) total += solve(solver, instances[i], o.solve_7l, out, &it);
      const auto stop = std::chrono::steady_clock::now();
      sink = sink + total + static_cast<long>(out[0].t.x() != 0.0);
      total_us += std::chrono::duration<double, std::micro>(stop - start).count();
      per_call_us.push_back(std::chrono::duration<double, std::micro>(stop - start).count() /
                            static_cast<double>(last - first));
    }
  }
  result.median_us = percentile(per_call_us, 0.5);
  result.p90_us = percentile(per_call_us, 0.9);
  result.mean_us = total_us / (count * o.repetitions);
  result.min_us = *std::min_element(per_call_us.begin(), per_call_us.end());
  result.chunk = chunk;
  return result;
}

}  // namespace line_odom
