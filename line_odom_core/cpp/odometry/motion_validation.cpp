#include "odometry/motion_validation.hpp"

#include <Eigen/Eigenvalues>

#include <bitset>
#include <cstdio>
#include <string>

#include "common/stopwatch.hpp"

namespace line_odom {

namespace {

constexpr const char* kAxisNames[6] = {"x", "y", "z", "rx", "ry", "rz"};

int count_axes(int axes) { return static_cast<int>(std::bitset<6>(static_cast<unsigned>(axes)).count()); }

// The axes of xi mostly inside the span of `projector` (a partial estimate's held directions).
int axes_of(const Mat6& projector) {
  int axes = 0;
  for (int k = 0; k < 6; ++k)
    if (projector(k, k) > 0.5) axes |= 1 << k;
  return axes;
}

std::string unobserved_text(const Observability& obs, double significance) {
  std::string text;
  for (int k = 0; k < 6; ++k) {
    if (!(obs.unobserved >> k & 1)) continue;
    char item[48];
    std::snprintf(item, sizeof item, "%s%s z %.1f", text.empty() ? "" : ", ", kAxisNames[k], obs.z[k]);
    text += item;
  }
  char tail[64];
  std::snprintf(tail, sizeof tail, " < validation.significance %.1f", significance);
  return text + tail;
}

}  // namespace

Observability MotionValidation::observe(const ValidationFrame& frame, const PassOutcome& outcome,
                                        Correspondences* corr) const {
  const OdometryConfig& config = lines_.config();
  CandidateIndex index(*frame.previous);
  build_candidates(index, *frame.current, outcome.best, lines_.last_pass_candidates(), corr, nullptr, lines_.pool());
  const LinePairTable table(*corr);
  return test_observability(*corr, table, outcome.best, config.ransac.inlier_threshold,
                            RefineOptions{}.min_line_sine, observability_push(outcome.best, config.validation),
                            config.validation.significance);
}

RigidTransform MotionValidation::validate(const ValidationFrame& frame, const PointMapTracker& point_map,
                                          PassOutcome* outcome, FrameStats* st) const {
  const ObservabilityOptions& options = lines_.config().validation;
  if (!options.enabled) return frame.prediction;
  Stopwatch watch;
  Correspondences corr;
  Observability obs;
  const bool full = registered_in_full(*outcome);
  if (full) obs = observe(frame, *outcome, &corr);
  RigidTransform reference = frame.prediction;
  const bool weak = !full || obs.unobserved != 0 || frame.first_motion;
  RigidTransform by_points;
  int matched = 0;
  const bool aligned = weak && !frame.guessed &&
                       point_map.align(*frame.points, frame.previous_pose, frame.prediction, &by_points, &matched);
  st->point_map_matches = matched;
  if (aligned) {
    st->points_aligned = true;
    reference = by_points;
    if (!full || frame.first_motion) {
      // The lines again from where the points put the scan: a first motion beyond the candidates' reach from
      // standing still, or a registration that failed from the prediction.
      FrameStats other_stats;
      PassOutcome other = lines_.register_features(*frame.previous, *frame.current, frame.prediction, by_points, true,
                                                   frame.registration, &other_stats);
      st->ms.candidates += other_stats.ms.candidates;
      st->ms.ransac += other_stats.ms.ransac;
      st->iterations += other_stats.iterations;
      if (registered_in_full(other)) {
        Correspondences other_corr;
        const Observability other_obs = observe(frame, other, &other_corr);
        if (!full || count_axes(other_obs.unobserved) < count_axes(obs.unobserved)) {
          *outcome = std::move(other);
          corr = std::move(other_corr);
          obs = other_obs;
          st->candidates = other_stats.candidates;
          st->plane_candidates = other_stats.plane_candidates;
          st->passes = other_stats.passes;
        }
      }
    }
  }
  st->observability = obs.z;
  st->unobserved = obs.unobserved;
  if (registered_in_full(*outcome) && obs.unobserved != 0) {
    // Held where the lines do not decide: at the points' motion, or at a guess; with neither, the lines' own motion
    // stands and only the flag and the covariance say so (fusion holds nothing then).
    const bool held = (aligned || frame.guessed) &&
                      lines_.hold_axes(corr, LinePairTable(corr), reference, obs.unobserved, outcome);
    const std::string why = "the lines do not pin down " + unobserved_text(obs, options.significance);
    outcome->failure = held ? why + (aligned ? ": held at the point map's alignment" : ": held at the guess") : why;
    if (!held) outcome->stats.degenerate = false;
  } else if (aligned && outcome->have && outcome->held_directions > 0) {
    // A partial estimate holds its unobserved directions at the points' motion rather than the prediction's.
    Correspondences held_corr;
    observe(frame, *outcome, &held_corr);
    const std::string failure = outcome->failure;
    if (lines_.hold_axes(held_corr, LinePairTable(held_corr), by_points, axes_of(outcome->held_projector), outcome))
      outcome->failure = failure + ": held at the point map's alignment";
  }
  st->ms.validation += watch.ms();
  return reference;
}

}  // namespace line_odom
