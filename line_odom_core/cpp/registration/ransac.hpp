// Generic RANSAC over an estimator concept, and its hybrid form over several data types and solvers
// (paper §6.3; the shape of PoseLib's RansacOptions / hybrid RANSAC and RansacLib's LO-MSAC).
//
// Single data type, single solver — e.g. a robust 3D line fit on one scan line:
//
//   struct LineEstimator {
//     using Model = PluckerLine;
//     static constexpr int kSampleSize = 2;   // data per minimal sample
//     static constexpr int kMaxModels = 1;    // most models one sample can give
//     int num_data() const;
//     int generate(const int* sample, Model* models);           // writes <= kMaxModels, returns count
//     RansacScore score(const Model& model, double to_beat);     // value: higher is better; set
//                                                                // inlier_fraction[0] (weighted, 0..1)
//     void refine(Model* model);                                 // optional: local optimisation
//     bool draw_sample(RansacRng& rng, int* sample);             // optional: own sampling (else uniform)
//   };
//   LineEstimator est{...};  PluckerLine best;  RansacStats stats;
//   bool ok = ransac(est, RansacOptions{}, &best, &stats);
//
// Hybrid: several data types (e.g. line pairs, plane pairs) and several minimal solvers with per-solver
// sample sizes such as {7,0}, {3,1}, {1,2}:
//
//   struct MyHybrid {
//     using Model = ...;
//     static constexpr int kNumDataTypes = 2, kNumSolvers = 3, kMaxSampleSize = 7, kMaxModels = 4;
//     int num_data(int type) const;
//     int sample_size(int solver, int type) const;
//     double solver_prior(int solver) const;                          // relative preference, 0 disables
//     int generate(int solver, const HybridSample<MyHybrid>& sample, Model* models);
//     RansacScore score(const Model& model, double to_beat);          // inlier_fraction[type] per data type
//     void refine(Model* model);                                      // optional
//     bool draw_sample(int solver, RansacRng& rng, HybridSample<MyHybrid>* sample);  // optional
//   };
//   bool ok = hybrid_ransac(est, options, &best, &stats);
//
// Each iteration picks a solver with probability proportional to prior * max(P, min_solver_share * max P),
// where P = prod_t inlier_fraction_t ^ sample_size(solver, t) under the best model so far (the prior alone
// until a model exists). The loop stops after min_iterations once the probability that every sample drawn so far
// contained an outlier, prod_s (1 - P_s)^(samples of s), falls below 1 - confidence. `score` receives the
// best value so far so it may stop early (return anything <= to_beat) once it cannot win. With
// local_optimisation, every new best model is passed to `refine` and kept refined if it scores no worse.
// No heap allocation in the loop; deterministic for a given seed.
#pragma once

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <limits>
#include <type_traits>
#include <utility>

#include "common/splitmix64.hpp"

namespace line_odom {

struct RansacOptions {
  int max_iterations = 1000;  // samples drawn at most
  int min_iterations = 0;     // samples drawn at least (unless no solver can run)
  double confidence = 0.999;  // stop when P(no all-inlier sample yet) < 1 - confidence
  std::uint64_t seed = 0;
  bool local_optimisation = true;
  double min_solver_share = 0.05;  // hybrid: each solver is chosen with weight >= this times the best one's
};

constexpr int kRansacMaxDataTypes = 4;
constexpr int kRansacMaxSolvers = 8;

struct RansacScore {
  double value = -std::numeric_limits<double>::infinity();  // higher is better (e.g. weighted inlier count)
  int inliers = 0;
  std::array<double, kRansacMaxDataTypes> inlier_fraction{};  // per data type, weighted, in [0, 1]
};

struct RansacStats {
  int iterations = 0;     // samples drawn
  int models = 0;         // hypotheses scored
  int refinements = 0;    // local optimisation calls
  int best_solver = -1;   // -1: no model
  int best_iteration = -1;
  RansacScore best_score;
  std::array<int, kRansacMaxSolvers> solver_iterations{};  // samples drawn per solver
  std::array<int, kRansacMaxSolvers> solver_wins{};        // hypotheses that became the best, per solver
};

// xoshiro256** seeded by splitmix64: small, fast and identical on every platform (std distributions are not).
class RansacRng {
 public:
  explicit RansacRng(std::uint64_t seed = 0) {
    for (auto& s : state_) {
      seed += kSplitmix64Gamma;
      s = splitmix64_mix(seed);
    }
  }
  std::uint64_t next() {
    const std::uint64_t result = rotl(state_[1] * 5, 7) * 9;
    const std::uint64_t t = state_[1] << 17;
    state_[2] ^= state_[0];
    state_[3] ^= state_[1];
    state_[1] ^= state_[2];
    state_[0] ^= state_[3];
    state_[2] ^= t;
    state_[3] = rotl(state_[3], 45);
    return result;
  }
  // Uniform integer in [0, n), n > 0.
  int uniform_int(int n) {
#ifdef __SIZEOF_INT128__
    return static_cast<int>((static_cast<unsigned __int128>(next()) * static_cast<std::uint64_t>(n)) >> 64);
#else
    return static_cast<int>(next() % static_cast<std::uint64_t>(n));
#endif
  }
  // Uniform double in [0, 1).
  double uniform() { return static_cast<double>(next() >> 11) * 0x1.0p-53; }

 private:
  static std::uint64_t rotl(std::uint64_t x, int k) { return (x << k) | (x >> (64 - k)); }
  std::array<std::uint64_t, 4> state_{};
};

// k distinct indices from [0, n) into out; false when n < k.
inline bool draw_distinct(RansacRng& rng, int n, int k, int* out) {
  if (k > n) return false;
  for (int i = 0; i < k; ++i) {
    for (;;) {
      const int v = rng.uniform_int(n);
      bool taken = false;
      for (int j = 0; j < i; ++j) taken |= (out[j] == v);
      if (!taken) {
        out[i] = v;
        break;
      }
    }
  }
  return true;
}

template <class E>
using HybridSample = std::array<std::array<int, E::kMaxSampleSize>, E::kNumDataTypes>;

namespace ransac_detail {

template <class E, class = void>
struct HasRefine : std::false_type {};
template <class E>
struct HasRefine<E, std::void_t<decltype(std::declval<E&>().refine(std::declval<typename E::Model*>()))>>
    : std::true_type {};

template <class E, class = void>
struct HasHybridDrawSample : std::false_type {};
template <class E>
struct HasHybridDrawSample<E, std::void_t<decltype(std::declval<E&>().draw_sample(
                                  0, std::declval<RansacRng&>(), std::declval<HybridSample<E>*>()))>>
    : std::true_type {};

template <class E, class = void>
struct HasDrawSample : std::false_type {};
template <class E>
struct HasDrawSample<E, std::void_t<decltype(std::declval<E&>().draw_sample(std::declval<RansacRng&>(),
                                                                            std::declval<int*>()))>>
    : std::true_type {};

// A single-type, single-solver estimator seen as a hybrid one.
template <class E>
struct SingleAsHybrid {
  using Model = typename E::Model;
  static constexpr int kNumDataTypes = 1;
  static constexpr int kNumSolvers = 1;
  static constexpr int kMaxSampleSize = E::kSampleSize;
  static constexpr int kMaxModels = E::kMaxModels;
  E& est;

  int num_data(int) const { return est.num_data(); }
  int sample_size(int, int) const { return E::kSampleSize; }
  double solver_prior(int) const { return 1.0; }
  bool draw_sample(int, RansacRng& rng, HybridSample<SingleAsHybrid>* sample) {
    if constexpr (HasDrawSample<E>::value) {
      return est.draw_sample(rng, (*sample)[0].data());
    } else {
      return draw_distinct(rng, est.num_data(), E::kSampleSize, (*sample)[0].data());
    }
  }
  int generate(int, const HybridSample<SingleAsHybrid>& sample, Model* models) {
    return est.generate(sample[0].data(), models);
  }
  RansacScore score(const Model& model, double to_beat) { return est.score(model, to_beat); }
  void refine(Model* model) {
    if constexpr (HasRefine<E>::value) est.refine(model);
  }
};

// P(all-inlier sample) for one solver under the current inlier fractions.
template <class E>
double all_inlier_probability(const E& est, int solver, const RansacScore& best) {
  double p = 1.0;
  for (int t = 0; t < E::kNumDataTypes; ++t) {
    const int k = est.sample_size(solver, t);
    if (k > 0) p *= std::pow(std::clamp(best.inlier_fraction[t], 0.0, 1.0), k);
  }
  return p;
}

}  // namespace ransac_detail

// Returns true and writes the best model when some hypothesis was scored. With `incumbent` (e.g. the motion
// predicted and refined before sampling), it is scored first and the samples must beat it: its support sets the
// stopping criterion from the start, and the pre-test and bound checks drop weaker hypotheses early. It stays the
// result (best_solver -1) when no sample does better.
template <class E>
bool hybrid_ransac(E& est, const RansacOptions& options, typename E::Model* best_model, RansacStats* stats_out,
                   const typename E::Model* incumbent = nullptr) {
  static_assert(E::kNumDataTypes >= 1 && E::kNumDataTypes <= kRansacMaxDataTypes, "kNumDataTypes out of range");
  static_assert(E::kNumSolvers >= 1 && E::kNumSolvers <= kRansacMaxSolvers, "kNumSolvers out of range");
  using Model = typename E::Model;
  constexpr int S = E::kNumSolvers;

  RansacStats stats;
  RansacRng rng(options.seed);

  std::array<double, S> prior{};
  double prior_sum = 0.0;
  for (int s = 0; s < S; ++s) {
    double p = std::max(0.0, static_cast<double>(est.solver_prior(s)));
    for (int t = 0; t < E::kNumDataTypes; ++t) {
      const int k = est.sample_size(s, t);
      if (k > E::kMaxSampleSize || k > est.num_data(t)) p = 0.0;
    }
    prior[s] = p;
    prior_sum += p;
  }
  if (!(prior_sum > 0.0)) {
    if (stats_out) *stats_out = stats;
    return false;
  }

  const double log_failure_target = std::log(std::max(1e-300, 1.0 - std::clamp(options.confidence, 0.0, 1.0)));
  std::array<double, S> p_all_inlier{};
  std::array<double, S> choice{};
  HybridSample<E> sample{};
  std::array<Model, E::kMaxModels> models;
  bool have_best = false;
  if (incumbent) {
    ++stats.models;
    const RansacScore sc = est.score(*incumbent, stats.best_score.value);
    if (sc.value > stats.best_score.value) {
      *best_model = *incumbent;
      have_best = true;
      stats.best_score = sc;
    }
  }

  auto update_probabilities = [&]() {
    double top = 0.0;
    for (int s = 0; s < S; ++s) {
      p_all_inlier[s] = prior[s] > 0.0 ? ransac_detail::all_inlier_probability(est, s, stats.best_score) : 0.0;
      top = std::max(top, p_all_inlier[s]);
    }
    // A solver whose data the best model so far happens to miss keeps a share, or it could never show better.
    const double floor = std::clamp(options.min_solver_share, 0.0, 1.0) * top;
    double sum = 0.0;
    for (int s = 0; s < S; ++s) {
      choice[s] = prior[s] * std::max(p_all_inlier[s], floor);
      sum += choice[s];
    }
    for (int s = 0; s < S; ++s) choice[s] = sum > 0.0 ? choice[s] / sum : prior[s] / prior_sum;
  };
  update_probabilities();

  for (int iter = 0; iter < options.max_iterations; ++iter) {
    if (have_best && iter >= options.min_iterations) {
      double log_failure = 0.0;
      for (int s = 0; s < S; ++s) {
        if (stats.solver_iterations[s] == 0) continue;
        const double p = p_all_inlier[s];
        log_failure += p >= 1.0 ? -std::numeric_limits<double>::infinity()
                                : stats.solver_iterations[s] * std::log1p(-p);
      }
      if (log_failure <= log_failure_target) break;
    }

    int solver = S - 1;
    if constexpr (S > 1) {
      double u = rng.uniform();
      for (int s = 0; s < S; ++s) {
        if (choice[s] <= 0.0) continue;
        solver = s;
        if (u < choice[s]) break;
        u -= choice[s];
      }
    }
    ++stats.iterations;
    ++stats.solver_iterations[solver];

    bool drawn = true;
    if constexpr (ransac_detail::HasHybridDrawSample<E>::value) {
      drawn = est.draw_sample(solver, rng, &sample);
    } else {
      for (int t = 0; t < E::kNumDataTypes && drawn; ++t)
        drawn = draw_distinct(rng, est.num_data(t), est.sample_size(solver, t), sample[t].data());
    }
    if (!drawn) continue;

    const int n_models = std::min(est.generate(solver, sample, models.data()), E::kMaxModels);
    for (int i = 0; i < n_models; ++i) {
      ++stats.models;
      RansacScore sc = est.score(models[i], stats.best_score.value);
      if (!(sc.value > stats.best_score.value)) continue;
      if constexpr (ransac_detail::HasRefine<E>::value) {
        if (options.local_optimisation) {
          Model refined = models[i];
          est.refine(&refined);
          ++stats.refinements;
          const RansacScore sr = est.score(refined, sc.value);
          if (sr.value >= sc.value) {
            models[i] = refined;
            sc = sr;
          }
        }
      }
      *best_model = models[i];
      have_best = true;
      stats.best_score = sc;
      stats.best_solver = solver;
      stats.best_iteration = iter;
      ++stats.solver_wins[solver];
      update_probabilities();
    }
  }
  if (stats_out) *stats_out = stats;
  return have_best;
}

// Single data type, single solver.
template <class E>
bool ransac(E& est, const RansacOptions& options, typename E::Model* best_model, RansacStats* stats) {
  ransac_detail::SingleAsHybrid<E> hybrid{est};
  return hybrid_ransac(hybrid, options, best_model, stats);
}

}  // namespace line_odom
