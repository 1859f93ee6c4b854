#include "odometry/line_registration.hpp"

#include <Eigen/QR>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <memory>
#include <string>

#include "common/splitmix64.hpp"
#include "common/stopwatch.hpp"

namespace line_odom {

namespace {

constexpr double kHeldAxisCosine = 0.9;  // an axis this close to the held directions counts as held
constexpr double kRivalRotation = 0.5 * kPi / 180.0;  // first motions closer than this (and the inlier threshold)
                                                      // are one
constexpr int kRoundsAgain = 2;  // candidates re-associated and refined after a sweep is deskewed again

std::uint64_t mix_seed(std::uint64_t seed, std::uint64_t frame, std::uint64_t pass) {
  return splitmix64_mix(seed + kSplitmix64Gamma * (frame * 16 + pass + 1));
}

}  // namespace

bool registered_in_full(const PassOutcome& outcome) {
  return outcome.have && !outcome.stats.degenerate && outcome.held_directions == 0 &&
         outcome.stats.covariance.allFinite();
}

Mat6 subspace_projector(const Eigen::Matrix<double, 6, Eigen::Dynamic>& basis) {
  if (basis.cols() == 0) return Mat6::Zero();
  const Eigen::HouseholderQR<Eigen::Matrix<double, 6, Eigen::Dynamic>> qr(basis);
  const Eigen::Matrix<double, 6, Eigen::Dynamic> q =
      qr.householderQ() * Eigen::Matrix<double, 6, Eigen::Dynamic>::Identity(6, basis.cols());
  return q * q.transpose();
}

CandidateOptions LineRegistration::last_pass_candidates() const {
  const RegistrationOptions& reg = config_->registration;
  CandidateOptions copt = config_->candidates;
  const double last_pass_scale = std::pow(reg.pass_distance_scale, reg.passes - 1);
  copt.max_distance *= last_pass_scale;
  copt.plane_max_distance *= last_pass_scale;
  return copt;
}

RefineOptions LineRegistration::refine_options() const {
  RefineOptions ropt;
  ropt.iterations = config_->ransac.refine_iterations;
  ropt.line_threshold = config_->ransac.inlier_threshold;
  ropt.plane_angle_threshold = config_->ransac.plane_angle_threshold_deg * kPi / 180.0;
  ropt.plane_distance_threshold = config_->ransac.plane_distance_threshold;
  ropt.huber_delta = config_->ransac.huber_delta > 0.0 ? config_->ransac.huber_delta : config_->ransac.inlier_threshold;
  ropt.degeneracy_threshold = config_->ransac.degeneracy_threshold;
  return ropt;
}

// Precise lines meet their partners under the right motion; noisy ones leave only the sample and a few chance pairs
// within the threshold, whatever motion they are fitted to. The share must be shown, not just reached: two binomial
// standard deviations above registration.min_inlier_ratio (a few dozen candidates prove little).
bool LineRegistration::too_few_pairs_meet(const Correspondences& corr, const LinePairTable& table, const RigidTransform& T,
                                  int* inliers) const {
  score_motion(table, T, config_->ransac.inlier_threshold, RefineOptions{}.min_line_sine, inliers);
  const double pairs = static_cast<double>(corr.lines_a.size());
  const double r = config_->registration.min_inlier_ratio;
  return pairs > 0.0 && r > 0.0 && *inliers < r * pairs + 2.0 * std::sqrt(pairs * r * (1.0 - r));
}

// The axes a push along which keeps the inliers (refine.hpp: axis_support): motions the intersections do not observe,
// however well-conditioned the coincidental pairs make J^T W J look.
int LineRegistration::unobserved_axes_at(const LinePairTable& table, const RigidTransform& T) const {
  const RegistrationOptions& reg = config_->registration;
  if (!(reg.max_axis_support < 1.0 || reg.max_axis_pair_support < 1.0)) return 0;
  AxisShares shares;
  axis_support(table, T, config_->ransac.inlier_threshold, RefineOptions{}.min_line_sine, nullptr, &shares);
  int axes = 0;
  for (int axis = 0; axis < 6; ++axis)
    if ((reg.max_axis_support < 1.0 && shares.weight[axis] >= reg.max_axis_support) ||
        (reg.max_axis_pair_support < 1.0 && shares.pairs[axis] >= reg.max_axis_pair_support))
      axes |= 1 << axis;
  return axes;
}

// Whether the pairs of `prev` and `cur` alone (picked under T at the last pass's candidate distance) observe every
// direction of T: a well-conditioned refinement, enough of them meeting, no axis a push along which keeps them.
bool LineRegistration::observes_every_direction(CandidateIndex& index, const CandidateSubset& subset,
                                                const ScanFeatures& cur, const RigidTransform& T, FrameStats* st) const {
  const LastPassFit fit = refit_last_pass(index, cur, T, st, subset);
  Stopwatch checks;
  int inliers = 0;
  const bool observed = fit.converged && !fit.refined.degenerate &&
                        !too_few_pairs_meet(fit.corr, fit.table, T, &inliers) && unobserved_axes_at(fit.table, T) == 0;
  st->ms.ransac += checks.ms();
  return observed;
}

LineRegistration::LastPassFit LineRegistration::refit_last_pass(CandidateIndex& index, const ScanFeatures& cur,
                                                const RigidTransform& T, FrameStats* st,
                                                const CandidateSubset& subset) const {
  LastPassFit fit;
  Stopwatch stage;
  build_candidates(index, cur, T, last_pass_candidates(), &fit.corr, &fit.stats, pool_, subset);
  st->ms.candidates += stage.ms();
  stage = Stopwatch();
  fit.table = LinePairTable(fit.corr);
  fit.converged = refine_motion(fit.corr, fit.table, T, refine_options(), &fit.refined);
  st->ms.ransac += stage.ms();
  return fit;
}

bool LineRegistration::within_reach(const RigidTransform& prediction, const RigidTransform& T) const {
  if (!T.is_finite()) return false;
  const RigidTransform deviation = prediction.inverse() * T;
  return deviation.t.norm() <= config_->registration.max_translation &&
         rotation_angle(deviation.R) <= config_->registration.max_rotation_deg * kPi / 180.0;
}

// The state the passes of one registration carry from pass to pass: the last pass's candidates, the estimate kept so
// far and the refined guess of the last pass.
struct LineRegistration::Passes {
  RefineOptions ropt;
  CandidateOptions copt;
  Correspondences corr;
  LinePairTable table;  // corr's line pairs, for the pass and the checks after the last one
  CandidateStats cstats;
  RigidTransform best;
  MotionStats best_stats;
  bool have = false;
  std::string failure;
  RefineResult last_refined;  // the refined guess of the last pass, when it converged
  bool last_refine_converged = false;
  bool have_rival = false;
  RigidTransform rival;
};

PassOutcome LineRegistration::register_features(const ScanFeatures& prev, const ScanFeatures& cur,
                                                const RigidTransform& prediction, const RigidTransform& start,
                                                bool limit_pairs, const RegistrationFrame& frame,
                                                FrameStats* st) const {
  CandidateIndex prev_index(prev);  // frame a never moves: indexed once for all passes
  return register_features(prev_index, cur, prediction, start, limit_pairs, frame, st);
}

PassOutcome LineRegistration::register_features(CandidateIndex& prev_index, const ScanFeatures& cur,
                                                const RigidTransform& prediction, const RigidTransform& start,
                                                bool limit_pairs, const RegistrationFrame& frame,
                                                FrameStats* st) const {
  Passes passes;
  passes.ropt = refine_options();
  passes.best = start;
  passes.copt = config_->candidates;
  if (!limit_pairs) passes.copt.max_pairs_per_line = config_->registration.first_motion_pairs_per_line;
  for (int pass = 0; pass < config_->registration.passes; ++pass)
    run_pass(pass, prev_index, cur, prediction, limit_pairs, frame, &passes, st);
  const int axes = unobserved_after_passes(&passes);
  PassOutcome out;
  hold_unobserved(prediction, frame, axes, &passes, &out);
  out.best = passes.best;
  out.stats = passes.best_stats;
  out.have = passes.have;
  out.failure = passes.failure;
  out.have_rival = passes.have_rival;
  out.rival = passes.rival;
  out.candidates = std::make_shared<const Correspondences>(std::move(passes.corr));
  return out;
}

// One pass (paper §6.3): the candidates under the estimate so far, RANSAC on them, and the estimate kept when it is
// better supported than the last one; the candidate distance narrowed for the next.
void LineRegistration::run_pass(int pass, CandidateIndex& prev_index, const ScanFeatures& cur,
                                const RigidTransform& prediction, bool limit_pairs, const RegistrationFrame& frame,
                                Passes* s, FrameStats* st) const {
  const RegistrationOptions& reg = config_->registration;
  const RefineOptions& ropt = s->ropt;
  Stopwatch stage;
  build_candidates(prev_index, cur, s->best, s->copt, &s->corr, &s->cstats, pool_);
  st->ms.candidates += stage.ms();
  st->candidates = s->cstats.line_pairs;
  st->plane_candidates = s->cstats.plane_pairs;

  stage = Stopwatch();
  s->table = LinePairTable(s->corr);
  MotionOptions mopt = config_->ransac;
  mopt.seed = mix_seed(config_->seed, frame.index, static_cast<std::uint64_t>(pass));
  // The guess itself, refined on this pass's candidates, competes with the RANSAC samples: it is scored first
  // and whichever has the larger weighted inlier count on the same candidates is kept (paper §6.3).
  // An ill-conditioned refined guess still competes: a sample must out-support it to win, or the pass fails.
  RefineResult refined;
  const bool refine_converged =
      refine_motion(s->corr, s->table, s->best, ropt, &refined) && within_reach(prediction, refined.T);
  const bool refined_ok = refine_converged && !refined.degenerate && refined.line_inliers >= reg.min_inliers;
  s->last_refined = refined;
  s->last_refine_converged = refine_converged;
  RigidTransform estimate;
  MotionStats ms;
  // Without a motion guess (the first motion, searched from standing still) the refined guess may sit on a
  // wrong shift that most pairs support: it must not cut the sampling short, so it only competes afterwards.
  const bool guessed = limit_pairs || s->have;
  const RigidTransform* competing = refine_converged && guessed ? &refined.T : nullptr;
  bool ok = estimate_motion(s->corr, s->best, mopt, &estimate, &ms, competing) && within_reach(prediction, estimate) &&
            ms.inliers >= reg.min_inliers;
  st->iterations += ms.iterations;
  const double thr = config_->ransac.inlier_threshold;
  int sample_pairs = 0, guess_pairs = 0;
  double score_ransac = ok ? score_motion(s->table, estimate, thr, ropt.min_line_sine, &sample_pairs) : -1.0;
  const double score_guess =
      refine_converged ? score_motion(s->table, refined.T, thr, ropt.min_line_sine, &guess_pairs) : -1.0;
  if (ok && refine_converged && guessed && ms.best_solver >= 0 &&
      sample_pairs < reg.min_sample_pair_share * guess_pairs) {
    // A sample that out-weighs the refined guess on a few heavily weighted (small) normal clusters while losing
    // the pairs of the others is a wrong motion, not a correction: a right one keeps those pairs too.
    ok = false;
    score_ransac = -1.0;
  }
  const double score_prior = s->have ? score_motion(s->table, s->best, thr, ropt.min_line_sine) : -1.0;
  const double score_refined = refined_ok ? score_guess : -1.0;
  if (!guessed && ok && refined_ok) {
    const bool sample_won = score_ransac > score_refined;
    s->rival = sample_won ? refined.T : estimate;
    const RigidTransform difference = s->rival.inverse() * (sample_won ? estimate : refined.T);
    s->have_rival = difference.t.norm() > thr || rotation_angle(difference.R) > kRivalRotation;
  }
  st->ms.ransac += stage.ms();

  s->copt.max_distance *= reg.pass_distance_scale;
  s->copt.plane_max_distance *= reg.pass_distance_scale;
  s->copt.max_pairs_per_line = config_->candidates.max_pairs_per_line;
  if (!ok && !refined_ok) {
    if (refine_converged && refined.degenerate && refined.line_inliers >= reg.min_inliers) {
      char condition[64];
      std::snprintf(condition, sizeof condition, "%.1e < ransac.degeneracy_threshold %.1e", refined.condition,
                    ropt.degeneracy_threshold);
      s->failure = "ill-conditioned constraints (" + std::to_string(refined.line_inliers) + " inliers, condition " +
                   condition + ")";
    } else {
      s->failure =
          ms.inliers < reg.min_inliers && ms.inliers > 0
              ? "too few inliers (" + std::to_string(ms.inliers) + " < " + std::to_string(reg.min_inliers) + ")"
              : "no model with enough support (" + std::to_string(s->cstats.line_pairs) + " candidates)";
    }
    return;
  }
  // Ties go to the guess (the constant-velocity prediction carries the weakly observed directions).
  const double margin = 1.0 + reg.guess_preference;
  if (score_ransac > margin * score_refined && score_ransac > margin * score_prior) {
    s->best = estimate;
    s->best_stats = ms;
  } else if (score_refined > score_prior) {
    s->best = refined.T;
    copy_refinement_stats(refined, &s->best_stats);
    s->best_stats.covariance = refined.covariance;
    if (!s->have) s->best_stats.best_solver = -2;
  } else {
    return;
  }
  s->have = true;
  ++st->passes;
  s->failure.clear();
}

// The estimate the passes kept, flagged degenerate when too few of the last pass's pairs meet under it or a push along
// an axis keeps its inliers: those axes (bits of xi).
int LineRegistration::unobserved_after_passes(Passes* s) const {
  if (!s->have || s->best_stats.degenerate) return 0;
  int inliers = 0;
  if (too_few_pairs_meet(s->corr, s->table, s->best, &inliers)) {
    s->best_stats.degenerate = true;
    s->failure = "too few candidate pairs meet (" + std::to_string(inliers) + " of " +
                 std::to_string(s->corr.lines_a.size()) + " < registration.min_inlier_ratio)";
    return 0;
  }
  const int axes = unobserved_axes_at(s->table, s->best);
  if (axes != 0) {
    s->best_stats.degenerate = true;
    s->failure = "unobservable motion (a push along one axis keeps the inliers)";
  }
  return axes;
}

// What the pairs do observe of a degenerate motion is kept, the rest follows the motion model (refine.hpp:
// refine_motion_partial): the unobserved axes of an estimate, or the weak directions of an ill-conditioned
// refined guess. The result must pass the same checks along the directions it does not hold.
void LineRegistration::hold_unobserved(const RigidTransform& prediction, const RegistrationFrame& frame, int axes,
                                       Passes* s, PassOutcome* out) const {
  const RegistrationOptions& reg = config_->registration;
  const RigidTransform* partial_from = nullptr;
  bool lock_weak = false;
  const bool partial = reg.partial_updates && frame.have_velocity;  // no velocity yet: the prediction holds nothing
  if (partial && s->have && s->best_stats.degenerate && axes != 0) {
    partial_from = &s->best;
  } else if (partial && !s->have && s->last_refine_converged && s->last_refined.line_inliers >= reg.min_inliers) {
    partial_from = &s->last_refined.T;
    lock_weak = true;
  }
  int inliers = 0;
  for (int round = 0; partial_from && round < 2; ++round) {
    RefineResult partial;
    if (!refine_motion_partial(s->corr, s->table, *partial_from, prediction, axes, lock_weak, s->ropt, &partial) ||
        !within_reach(prediction, partial.T) || partial.degenerate || partial.line_inliers < reg.min_inliers ||
        too_few_pairs_meet(s->corr, s->table, partial.T, &inliers))
      break;
    // An unobserved axis the held directions already (nearly) contain is held; another one is held too, once.
    int uncovered = 0;
    const int unobserved = unobserved_axes_at(s->table, partial.T);
    for (int axis = 0; axis < 6; ++axis)
      if ((unobserved >> axis & 1) &&
          partial.locked_basis.leftCols(partial.locked_directions).row(axis).norm() < kHeldAxisCosine)
        uncovered |= 1 << axis;
    if (uncovered != 0) {
      axes |= uncovered;
      continue;
    }
    s->best = partial.T;
    copy_refinement_stats(partial, &s->best_stats);
    s->best_stats.covariance = partial.covariance;
    s->best_stats.degenerate = false;
    if (!s->have) s->best_stats.best_solver = -2;
    s->have = true;
    out->held_directions = partial.locked_directions;
    out->held_sensitivity = partial.held_sensitivity;
    out->held_projector = subspace_projector(partial.locked_basis.leftCols(partial.locked_directions));
    s->failure = "partly unobserved motion: " + std::to_string(partial.locked_directions) +
                 " of 6 directions held by the motion model";
    break;
  }
}

PassOutcome LineRegistration::register_again(const ScanFeatures& prev, const ScanFeatures& cur,
                                             const RigidTransform& prediction, const RigidTransform& start,
                                             const PassOutcome& first, FrameStats* st) const {
  const RegistrationOptions& reg = config_->registration;
  CandidateIndex index(prev);
  PassOutcome out = first;
  out.have = false;
  RigidTransform T = start;
  for (int round = 0; round < kRoundsAgain; ++round) {
    const LastPassFit fit = refit_last_pass(index, cur, T, st);
    const RefineResult& refined = fit.refined;
    Stopwatch checks;
    int inliers = 0;
    const bool ok = fit.converged && within_reach(prediction, refined.T) && !refined.degenerate &&
                    refined.line_inliers >= reg.min_inliers &&
                    !too_few_pairs_meet(fit.corr, fit.table, refined.T, &inliers) &&
                    unobserved_axes_at(fit.table, refined.T) == 0;
    st->ms.ransac += checks.ms();
    if (!ok) return out;
    T = refined.T;
    copy_refinement_stats(refined, &out.stats);
    out.stats.covariance = refined.covariance;
    out.stats.best_solver = first.stats.best_solver;
    st->candidates = fit.stats.line_pairs;
    st->plane_candidates = fit.stats.plane_pairs;
  }
  out.best = T;
  out.have = true;
  return out;
}

double LineRegistration::support(CandidateIndex& index, const ScanFeatures& cur, const RigidTransform& T,
                         double threshold_scale, double max_distance) const {
  Correspondences corr;
  CandidateOptions options = config_->candidates;
  if (max_distance > 0.0) options.max_distance = options.plane_max_distance = max_distance;
  build_candidates(index, cur, T, options, &corr, nullptr, pool_);
  return score_motion(LinePairTable(corr), T, threshold_scale * config_->ransac.inlier_threshold,
                      RefineOptions{}.min_line_sine);
}

bool LineRegistration::hold_directions(const Correspondences& corr, const LinePairTable& table,
                                       const RigidTransform& held, int axes, const Mat6* projector,
                                       PassOutcome* outcome) const {
  RefineResult partial;
  if (!refine_motion_partial(corr, table, outcome->best, held, axes, false, refine_options(), &partial, projector) ||
      !partial.T.is_finite() || partial.degenerate)
    return false;
  outcome->best = partial.T;
  copy_refinement_stats(partial, &outcome->stats);
  outcome->stats.covariance = partial.covariance;
  outcome->stats.degenerate = false;
  outcome->have = true;
  outcome->held_directions = partial.locked_directions;
  outcome->held_sensitivity = partial.held_sensitivity;
  outcome->held_projector = subspace_projector(partial.locked_basis.leftCols(partial.locked_directions));
  return true;
}

}  // namespace line_odom
