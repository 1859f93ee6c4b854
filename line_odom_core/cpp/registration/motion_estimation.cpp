#include "registration/motion_estimation.hpp"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <utility>

#include "registration/line_pair_table.hpp"
#include "registration/ransac.hpp"
#include "registration/refine.hpp"
#include "solvers/solve_1l2p.hpp"
#include "solvers/solve_3l1p.hpp"
#include "solvers/solve_7l.hpp"
#include "solvers/solver_input.hpp"

namespace line_odom {
namespace {

constexpr int kSolver7L = 0;
constexpr int kSolver3L1P = 1;
constexpr int kSolver1L2P = 2;
constexpr double kMinLineSine = 0.05;        // ~2.9 deg: closer to parallel, a pair gives no constraint
constexpr double kSegmentHalfLength = 1.0;   // 7L segments built from lines (m)
constexpr int kLocalOptimisationIterations = 4;
constexpr int kPretestMinPairs = 400;        // pre-test only above this many line pairs
constexpr int kBoundCheckStride = 32;
constexpr std::uint64_t kShuffleSeedSalt = 0x5bd1e9955bd1e995ULL;

using solver_input::normalize_line;
using solver_input::normalize_plane;
using solver_input::is_finite;

// Eight mask bytes (0 or 1) as one word whose lowest set bit is in the first pair's byte (little-endian GCC and
// clang); elsewhere the scoring loop reads the bytes one by one.
#if defined(__GNUC__) && defined(__BYTE_ORDER__) && __BYTE_ORDER__ == __ORDER_LITTLE_ENDIAN__
constexpr bool kWordMasks = true;
inline int first_meeting_pair(std::uint64_t eight_meets) { return __builtin_ctzll(eight_meets) >> 3; }
#else
constexpr bool kWordMasks = false;
inline int first_meeting_pair(std::uint64_t) { return 0; }
#endif

// Points where two lines come closest (the closest points to the origin for near-parallel lines).
void closest_points(const PluckerLine& l1, const PluckerLine& l2, Vec3* p1, Vec3* p2) {
  const Vec3 o1 = l1.closest_point_to_origin();
  const Vec3 o2 = l2.closest_point_to_origin();
  const double b = l1.d.dot(l2.d);
  const double den = 1.0 - b * b;
  if (den < 1e-10) {
    *p1 = o1;
    *p2 = o2;
    return;
  }
  const Vec3 w0 = o1 - o2;
  const double d = l1.d.dot(w0), e = l2.d.dot(w0);
  *p1 = o1 + ((b * e - d) / den) * l1.d;
  *p2 = o2 + ((e - b * d) / den) * l2.d;
}

// Valid pairs in a random order (so any prefix is a random subset for the pre-test), with everything the
// estimator needs filled in: weights, clusters, segments.
struct PreparedData {
  Correspondences work;
  LinePairTable pairs;  // the line pairs of `work`
  std::vector<int> line_origin, plane_origin;  // input index of each work pair
  std::array<std::vector<int>, 3> cluster_members;
  std::vector<double> suffix_weight;  // sum of weights from i to the end (size n + 1)
  double total_line_weight = 0.0;
  bool stratified = false;
};

void prepare(const Correspondences& in, const RigidTransform& init, std::uint64_t seed, PreparedData* out,
             MotionStats* stats) {
  const size_t n = std::min(in.lines_a.size(), in.lines_b.size());
  const bool has_segments = in.segments_a.size() == n && in.segments_b.size() == n;
  const bool has_weights = in.weights.size() == n;
  const bool has_clusters = in.clusters.size() == n;
  std::vector<int> order;
  order.reserve(n);
  std::vector<PluckerLine> la(n), lb(n);
  bool b_ok = false;
  for (size_t i = 0; i < n; ++i) {
    // Candidates list the partners of a line of b one after the other: a line of b equal bit for bit to the
    // previous pair's is normalized once.
    if (i == 0 || std::memcmp(&in.lines_b[i], &in.lines_b[i - 1], sizeof(PluckerLine)) != 0)
      b_ok = normalize_line(in.lines_b[i], &lb[i]);
    else
      lb[i] = lb[i - 1];
    bool ok = normalize_line(in.lines_a[i], &la[i]) && b_ok;
    if (has_weights) ok = ok && std::isfinite(in.weights[i]) && in.weights[i] >= 0.0;
    if (has_segments) {
      const Segment &sa = in.segments_a[i], &sb = in.segments_b[i];
      ok = ok && is_finite(sa.a) && is_finite(sa.b) && is_finite(sb.a) && is_finite(sb.b) && sa.length() > 1e-9 &&
           sb.length() > 1e-9;
    }
    if (ok)
      order.push_back(static_cast<int>(i));
    else
      ++stats->dropped_line_pairs;
  }
  RansacRng rng(seed ^ kShuffleSeedSalt);
  for (size_t i = order.size(); i > 1; --i) std::swap(order[i - 1], order[rng.uniform_int(static_cast<int>(i))]);

  Correspondences& w = out->work;
  const size_t k = order.size();
  w.lines_a.resize(k);
  w.lines_b.resize(k);
  w.segments_a.resize(k);
  w.segments_b.resize(k);
  w.weights.resize(k);
  w.clusters.assign(k, -1);
  out->line_origin = order;
  const RigidTransform init_inv = init.inverse();
  for (size_t j = 0; j < k; ++j) {
    const int i = order[j];
    w.lines_a[j] = la[i];
    w.lines_b[j] = lb[i];
    w.weights[j] = has_weights ? in.weights[i] : 1.0;
    const int c = has_clusters ? in.clusters[i] : -1;
    if (c >= 0 && c < 3) {
      w.clusters[j] = c;
      out->cluster_members[c].push_back(static_cast<int>(j));
    }
    if (has_segments) {
      w.segments_a[j] = in.segments_a[i];
      w.segments_b[j] = in.segments_b[i];
    } else {
      Vec3 pa, pb_in_a;
      closest_points(la[i], lb[i].moved(init), &pa, &pb_in_a);
      const Vec3 pb = init_inv.apply(pb_in_a);
      w.segments_a[j] = {pa - kSegmentHalfLength * la[i].d, pa + kSegmentHalfLength * la[i].d};
      w.segments_b[j] = {pb - kSegmentHalfLength * lb[i].d, pb + kSegmentHalfLength * lb[i].d};
    }
  }
  out->pairs = LinePairTable(w);
  out->suffix_weight.assign(k + 1, 0.0);
  for (size_t j = k; j > 0; --j) out->suffix_weight[j - 1] = out->suffix_weight[j] + w.weights[j - 1];
  out->total_line_weight = out->suffix_weight[0];
  out->stratified = has_clusters;

  const size_t m = std::min(in.planes_a.size(), in.planes_b.size());
  for (size_t i = 0; i < m; ++i) {
    Plane pa, pb;
    if (normalize_plane(in.planes_a[i], &pa) && normalize_plane(in.planes_b[i], &pb)) {
      w.planes_a.push_back(pa);
      w.planes_b.push_back(pb);
      out->plane_origin.push_back(static_cast<int>(i));
    } else {
      ++stats->dropped_plane_pairs;
    }
  }
}

// The hybrid estimator of paper §6.3 over {line pairs, plane pairs} and {7L, 3L1P, 1L2P} (ransac.hpp concept).
class MotionHybridEstimator {
 public:
  using Model = RigidTransform;
  static constexpr int kNumDataTypes = 2;
  static constexpr int kNumSolvers = 3;
  static constexpr int kMaxSampleSize = 7;
  static constexpr int kMaxModels = 4;
  using Sample = HybridSample<MotionHybridEstimator>;

  MotionHybridEstimator(const PreparedData& data, const RigidTransform& init, const MotionOptions& options,
                        const RefineOptions& refine_options)
      : d_(data), w_(data.work), init_(init), options_(options), lo_options_(refine_options) {
    n_lines_ = static_cast<int>(w_.lines_a.size());
    n_planes_ = static_cast<int>(w_.planes_a.size());
    lo_options_.iterations = kLocalOptimisationIterations;
    lo_options_.compute_covariance = false;
    plane_cos_ = std::cos(refine_options.plane_angle_threshold);
    pretest_size_ = (options.pretest && n_lines_ >= kPretestMinPairs) ? std::max(kPretestMinPairs / 2, n_lines_ / 8)
                                                                      : 0;
    solve_7l_.method = options.solve_7l_method;
    solve_7l_.max_iterations = options.solve_7l_max_iterations > 0 ? options.solve_7l_max_iterations
                               : options.solve_7l_method == Solve7LMethod::kGaussNewton ? 12
                                                                                        : 30000;
    solve_7l_.max_residual = 3.0 * options.inlier_threshold;
  }

  int num_data(int type) const { return type == 0 ? n_lines_ : n_planes_; }
  int sample_size(int solver, int type) const {
    static constexpr int kSizes[3][2] = {{7, 0}, {3, 1}, {1, 2}};
    return kSizes[solver][type];
  }
  double solver_prior(int solver) const {
    switch (options_.solver) {
      case SolverMode::k7L: return solver == kSolver7L ? 1.0 : 0.0;
      case SolverMode::k3L1P: return solver == kSolver3L1P ? 1.0 : 0.0;
      case SolverMode::k1L2P: return solver == kSolver1L2P ? 1.0 : 0.0;
      case SolverMode::kAuto: break;
    }
    return 1.0;
  }

  // Paper §6.3 candidate selection: 7L = 2 per normal cluster + 1, 3L1P = 1 per cluster, planes uniform.
  bool draw_sample(int solver, RansacRng& rng, Sample* sample) {
    int* lines = (*sample)[0].data();
    int* planes = (*sample)[1].data();
    const int k_lines = sample_size(solver, 0);
    const int per_cluster = solver == kSolver7L ? 2 : solver == kSolver3L1P ? 1 : 0;
    int filled = 0;
    if (d_.stratified && per_cluster > 0) {
      for (int c = 0; c < 3; ++c) {
        const std::vector<int>& pool = d_.cluster_members[c];
        for (int r = 0; r < per_cluster; ++r) {
          if (!pick_unique(rng, pool.empty() ? nullptr : &pool, lines, filled)) return false;
          ++filled;
        }
      }
    }
    for (; filled < k_lines; ++filled)
      if (!pick_unique(rng, nullptr, lines, filled)) return false;
    return draw_distinct(rng, n_planes_, sample_size(solver, 1), planes);
  }

  int generate(int solver, const Sample& sample, Model* models) {
    const auto& L = sample[0];
    const auto& P = sample[1];
    int n = 0;
    if (solver == kSolver7L) {
      std::array<Segment, 7> sa, sb;
      for (int i = 0; i < 7; ++i) {
        sa[i] = w_.segments_a[L[i]];
        sb[i] = w_.segments_b[L[i]];
      }
      n = solve_7l(sa, sb, init_, models, solve_7l_);
    } else if (solver == kSolver3L1P) {
      const std::array<PluckerLine, 3> la{w_.lines_a[L[0]], w_.lines_a[L[1]], w_.lines_a[L[2]]};
      const std::array<PluckerLine, 3> lb{w_.lines_b[L[0]], w_.lines_b[L[1]], w_.lines_b[L[2]]};
      n = solve_3l1p(la, lb, w_.planes_a[P[0]], w_.planes_b[P[0]], models);
    } else {
      const std::array<Plane, 2> pa{w_.planes_a[P[0]], w_.planes_a[P[1]]};
      const std::array<Plane, 2> pb{w_.planes_b[P[0]], w_.planes_b[P[1]]};
      n = solve_1l2p(w_.lines_a[L[0]], w_.lines_b[L[0]], pa, pb, models);
    }
    int kept = 0;
    for (int i = 0; i < n; ++i)
      if (models[i].is_finite()) models[kept++] = models[i];
    return kept;
  }

  // Weighted count of line pairs within the inlier threshold (paper §6.3); plane inliers for the solver choice.
  RansacScore score(const Model& T, double to_beat) {
    RansacScore sc;
    if (!T.is_finite()) return sc;
    const double best_fraction = to_beat > 0.0 && d_.total_line_weight > 0.0 ? to_beat / d_.total_line_weight : 0.0;
    const bool pretest = best_fraction > 0.0;
    double weight = 0.0;
    int count = 0;
    std::uint8_t meets[kPairBlockSize];
    int block_begin = 0, block_end = 0;
    for (int i = 0; i < n_lines_;) {
      if (i == pretest_size_ && pretest) {
        const double prefix = d_.total_line_weight - d_.suffix_weight[i];
        if (prefix > 0.0 && weight < 0.5 * best_fraction * prefix) return partial(sc, weight, count);
      }
      if ((i % kBoundCheckStride) == 0 && weight + d_.suffix_weight[i] <= to_beat) return partial(sc, weight, count);
      if (i == block_end) {
        // Blocks end at the pre-test, so a hypothesis it drops costs no more pairs than it read.
        block_begin = i;
        block_end = std::min(n_lines_, i + kPairBlockSize);
        if (i < pretest_size_ && pretest) block_end = std::min(block_end, pretest_size_);
        d_.pairs.inlier_mask(T, options_.inlier_threshold, kMinLineSine, block_begin, block_end, meets);
      }
      // Up to the next pair a test above looks at.
      int next_test = std::min(block_end, (i / kBoundCheckStride + 1) * kBoundCheckStride);
      if (i < pretest_size_ && pretest) next_test = std::min(next_test, pretest_size_);
      while (i < next_test) {
        if (kWordMasks && i + 8 <= next_test) {
          // The meeting pairs of eight in order, without a branch per pair (most pairs miss a wrong hypothesis).
          std::uint64_t eight_meets;
          std::memcpy(&eight_meets, meets + (i - block_begin), 8);
          for (; eight_meets != 0; eight_meets &= eight_meets - 1) {
            weight += w_.weights[i + first_meeting_pair(eight_meets)];
            ++count;
          }
          i += 8;
          continue;
        }
        if (meets[i - block_begin]) {
          weight += w_.weights[i];
          ++count;
        }
        ++i;
      }
    }
    int plane_count = 0;
    for (int j = 0; j < n_planes_; ++j) {
      const Plane pb = w_.planes_b[j].moved(T);
      if (w_.planes_a[j].n.dot(pb.n) > plane_cos_ &&
          std::abs(pb.delta - w_.planes_a[j].delta) < options_.plane_distance_threshold)
        ++plane_count;
    }
    sc.value = weight;
    sc.inliers = count;
    sc.inlier_fraction[0] = d_.total_line_weight > 0.0 ? weight / d_.total_line_weight : 0.0;
    sc.inlier_fraction[1] = n_planes_ > 0 ? static_cast<double>(plane_count) / n_planes_ : 0.0;
    return sc;
  }

  void refine(Model* T) {
    RefineResult r;
    if (refine_motion(w_, d_.pairs, *T, lo_options_, &r) && r.T.is_finite()) *T = r.T;
  }

 private:
  static RansacScore partial(RansacScore sc, double weight, int count) {
    sc.value = weight;
    sc.inliers = count;
    return sc;
  }

  // One index from pool (or from all line pairs when pool is null) not among out[0..filled).
  bool pick_unique(RansacRng& rng, const std::vector<int>* pool, int* out, int filled) const {
    const int size = pool ? static_cast<int>(pool->size()) : n_lines_;
    if (size <= 0) return false;
    for (int attempt = 0; attempt < 64; ++attempt) {
      const int r = rng.uniform_int(size);
      const int v = pool ? (*pool)[r] : r;
      bool taken = false;
      for (int j = 0; j < filled; ++j) taken |= (out[j] == v);
      if (!taken) {
        out[filled] = v;
        return true;
      }
    }
    return false;
  }

  const PreparedData& d_;
  const Correspondences& w_;
  RigidTransform init_;
  const MotionOptions& options_;
  RefineOptions lo_options_;
  Solve7LOptions solve_7l_;
  int n_lines_ = 0, n_planes_ = 0, pretest_size_ = 0;
  double plane_cos_ = 1.0;
};

// Mean line inlier weight of T pushed by 20 inlier thresholds along the 8 diagonals (+-1, +-1, +-1)/sqrt(3) and
// turned about a second diagonal by the angle that moves the inlier lines' mean distance from the origin as
// far: the support a wrong pose gets by chance. Diagonals, not axes: pairs on a plane keep intersecting under
// any shift within that plane, and scenes tend to have planes through the axes.
double perturbed_inlier_weight(const Correspondences& w, const LinePairTable& pairs, const RigidTransform& T,
                               const std::vector<std::uint8_t>& inlier, double threshold) {
  double r2 = 0.0;
  int n = 0;
  for (size_t j = 0; j < w.lines_a.size(); ++j)
    if (inlier[j]) r2 += w.lines_a[j].closest_point_to_origin().squaredNorm(), ++n;
  const double push = 20.0 * threshold;
  const double turn = push / std::max(1.0, n > 0 ? std::sqrt(r2 / n) : 1.0);
  std::vector<std::uint8_t> meets(pairs.size());
  double total = 0.0;
  for (int k = 0; k < 8; ++k) {
    const Vec3 s((k & 1) ? 1.0 : -1.0, (k & 2) ? 1.0 : -1.0, (k & 4) ? 1.0 : -1.0);
    Vec6 xi;
    xi << push * s / std::sqrt(3.0), turn * Vec3(s.y(), -s.z(), s.x()) / std::sqrt(3.0);
    pairs.inlier_mask(se3_exp(xi) * T, threshold, kMinLineSine, 0, pairs.size(), meets.data());
    for (int j = 0; j < pairs.size(); ++j)
      if (meets[j]) total += pairs.weight(j);
  }
  return total / 8.0;
}

RefineOptions refine_options_from(const MotionOptions& o) {
  RefineOptions r;
  r.iterations = o.refine_iterations;
  r.line_threshold = o.inlier_threshold;
  r.plane_angle_threshold = o.plane_angle_threshold_deg * kPi / 180.0;
  r.plane_distance_threshold = o.plane_distance_threshold;
  r.huber_delta = o.huber_delta > 0.0 ? o.huber_delta : o.inlier_threshold;
  r.min_line_sine = kMinLineSine;
  r.degeneracy_threshold = o.degeneracy_threshold;
  return r;
}

}  // namespace

bool estimate_motion(const Correspondences& data, const RigidTransform& init, const MotionOptions& options,
                     RigidTransform* T_ab, MotionStats* stats_out, const RigidTransform* incumbent) {
  MotionStats stats;
  const RigidTransform start = init.is_finite() ? init : RigidTransform::identity();
  if (T_ab) *T_ab = start;

  PreparedData prepared;
  prepare(data, start, options.seed, &prepared, &stats);
  const RefineOptions refine_options = refine_options_from(options);
  MotionHybridEstimator estimator(prepared, start, options, refine_options);

  RansacOptions ransac_options;
  ransac_options.max_iterations = options.max_iterations;
  ransac_options.min_iterations = options.min_iterations;
  ransac_options.confidence = options.confidence;
  ransac_options.seed = options.seed;
  ransac_options.local_optimisation = options.local_optimisation;

  RigidTransform best = start;
  RansacStats rs;
  const bool use_incumbent = incumbent && incumbent->is_finite();
  const bool found = hybrid_ransac(estimator, ransac_options, &best, &rs, use_incumbent ? incumbent : nullptr);
  stats.iterations = rs.iterations;
  stats.models = rs.models;
  stats.best_solver = found && rs.best_solver < 0 ? -2 : rs.best_solver;
  for (int s = 0; s < 3; ++s) {
    stats.solver_counts[s] = rs.solver_wins[s];
    stats.solver_iterations[s] = rs.solver_iterations[s];
  }
  // No sample beat the incumbent: the caller holds it (and its refinement) already.
  if (!found || !best.is_finite() || stats.best_solver == -2) {
    if (stats_out) *stats_out = std::move(stats);
    return false;
  }

  RefineResult refined;
  const bool refined_ok = refine_motion(prepared.work, prepared.pairs, best, refine_options, &refined);
  const RigidTransform final_T = refined_ok ? refined.T : best;
  copy_refinement_stats(refined, &stats);
  if (refined_ok) stats.covariance = refined.covariance;

  const Correspondences& w = prepared.work;
  std::vector<std::uint8_t> work_inlier(w.lines_a.size(), 0);
  prepared.pairs.inlier_mask(final_T, options.inlier_threshold, kMinLineSine, 0, prepared.pairs.size(),
                             work_inlier.data());
  for (size_t j = 0; j < w.lines_a.size(); ++j) work_inlier[j] = work_inlier[j] && w.weights[j] > 0.0;
  stats.perturbed_inlier_weight =
      perturbed_inlier_weight(w, prepared.pairs, final_T, work_inlier, options.inlier_threshold);
  stats.line_inlier_mask.assign(std::min(data.lines_a.size(), data.lines_b.size()), 0);
  for (size_t j = 0; j < w.lines_a.size(); ++j) stats.line_inlier_mask[prepared.line_origin[j]] = work_inlier[j];
  stats.plane_inlier_mask.assign(std::min(data.planes_a.size(), data.planes_b.size()), 0);
  for (size_t j = 0; j < w.planes_a.size(); ++j)
    stats.plane_inlier_mask[prepared.plane_origin[j]] =
        plane_pair_is_inlier(w.planes_a[j], w.planes_b[j].moved(final_T), refine_options.plane_angle_threshold,
                             refine_options.plane_distance_threshold);

  stats.success = refined_ok && !refined.degenerate && refined.line_inliers >= options.min_inliers &&
                  refined.line_inlier_weight >= options.min_inlier_contrast * stats.perturbed_inlier_weight +
                                                    3.0 * std::sqrt(stats.perturbed_inlier_weight) &&
                  final_T.is_finite();
  if (stats.success && T_ab) *T_ab = final_T;
  const bool success = stats.success;
  if (stats_out) *stats_out = std::move(stats);
  return success;
}

}  // namespace line_odom
