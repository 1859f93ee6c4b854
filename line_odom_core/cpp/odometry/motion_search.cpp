// The motion searched beyond the candidates' reach from the prediction (paper §6.3 needs a guess within the
// candidate distance): the first motion with no velocity yet, a velocity no scan has measured, a turn the prediction
// missed. Each scores shifted or turned motions by the candidate pairs they support (support_peak) and registers
// from the peak.
#include "odometry/motion_search.hpp"

#include <Eigen/Eigenvalues>

#include <algorithm>
#include <array>
#include <cmath>
#include <utility>
#include <vector>

#include "common/stopwatch.hpp"
#include "features/scan_directions.hpp"
#include "odometry/motion_prediction.hpp"
#include "registration/line_pair_table.hpp"

namespace line_odom {

namespace {

constexpr double kWeakShiftStep = 8.0;  // inlier thresholds between the shifts of a first motion's scan (the
                                        // support peak of KITTI 04's forward motion: ~10 thresholds wide)
constexpr double kSameAxisCosine = 0.999;  // a direction within 2.6 deg of a sensor axis is scanned with it
constexpr double kMaxShiftSteps = 25.0;  // per side and axis, however small the inlier threshold
constexpr double kUnmeasuredTranslation = 0.5;  // an unmeasured direction this much (squared) a translation is scanned
constexpr double kRecoveryMargin = 1.5;  // the support a motion found along unmeasured directions must have, in units
                                         // of the held estimate's (measured: docs/NODE.md "The first motion")
constexpr double kHeldRotationCosine = 0.5;  // held directions within 60 deg of a rotation hold a turn (xi: m, rad;
                                             // KITTI 04's held forward motion: within 2 deg of the x axis)
constexpr double kSupportDrop = 1.0 / 3.0;  // a frame with less of the last one's inlier weight is checked for a turn
                                            // (KITTI, TUM, the simulated street: > 0.48 of it; a 20 deg wrong heading
                                            // on the simulated street: 0.14-0.29)
constexpr double kOwnReach = 0.25;  // a peak moving the lines within this share of the candidate distance of the
                                    // estimate is the registration's own: its candidates reach it (and a scan's flat
                                    // support peaks anywhere there)
constexpr std::size_t kScanLines = 600;  // lines of the scan scored per shift (every k-th): the same peaks on KITTI
                                         // as all 3000, at a fifth of the cost (docs/RESULTS.md)

// Every k-th line of each direction, k the smallest keeping at most max_lines in all; the planes as they are.
ScanFeatures every_kth_line(const ScanFeatures& features, std::size_t max_lines) {
  const std::size_t lines = features.h_lines.size() + features.v_lines.size();
  const std::size_t k = std::max<std::size_t>(1, (lines + max_lines - 1) / max_lines);
  ScanFeatures out;
  out.planes = features.planes;
  out.cluster_directions = features.cluster_directions;
  for (std::size_t i = 0; i < features.h_lines.size(); i += k) out.h_lines.push_back(features.h_lines[i]);
  for (std::size_t i = 0; i < features.v_lines.size(); i += k) out.v_lines.push_back(features.v_lines[i]);
  return out;
}

// The scan without the lines that lie within `height` of `ground` (both endpoints): two of them meet under any turn
// about its normal, so they say nothing about the heading.
ScanFeatures lines_off_ground(const ScanFeatures& features, const Plane& ground, double height) {
  ScanFeatures out;
  out.planes = features.planes;
  out.cluster_directions = features.cluster_directions;
  auto on_ground = [&](const Vec3& p) { return std::abs(ground.n.dot(p) + ground.delta) <= height; };
  for (const auto& [lines, kept] : {std::pair{&features.h_lines, &out.h_lines}, {&features.v_lines, &out.v_lines}})
    for (const LineFeature& line : *lines)
      if (!(on_ground(line.segment.a) && on_ground(line.segment.b))) kept->push_back(line);
  return out;
}

// The motions of a support scan (support_peak): shifted along an axis, or turned about it through the current scan's
// origin (the sensor turned in place: T_prev_curr keeps its translation).
RigidTransform shift_motion(const RigidTransform& T, const Vec3& axis, double amount) {
  RigidTransform out = T;
  out.t += amount * axis;
  return out;
}

RigidTransform turn_motion(const RigidTransform& T, const Vec3& axis, double amount) {
  RigidTransform out = T;
  out.R = T.R * Eigen::AngleAxisd(amount, axis).toRotationMatrix();
  return out;
}

}  // namespace

// Without a guess the candidate pairs are the lines' closest partners under no motion, where the pairs of lines
// along the motion (a highway's ground, rails and kerbs) all meet, whatever the speed: a sample with the right
// motion loses on them to the unmoved guess, or is never drawn (KITTI 04 at 13 m/s, docs/RESULTS.md). The coarse
// search's motion, when it gave one, can be as wrong (KITTI 00 every third scan, 2.6 m a scan: 0.2 m back). So
// the passes also run from the first pass's loser and from the best-supported shift (weak_translation_peak), also
// when the first pass failed (a street at 3 m a scan: ill-conditioned from standing still), and the result kept is
// the one the candidates picked near each motion support most.
PassOutcome MotionSearch::first_motion(const ScanFeatures& prev, const ScanFeatures& cur,
                                       const RigidTransform& prediction, const RigidTransform* coarse_motion,
                                       const RegistrationFrame& frame, FrameStats* st) const {
  const bool guessed = coarse_motion != nullptr;
  const RigidTransform& first_start = guessed ? *coarse_motion : prediction;
  PassOutcome outcome = lines_.register_features(prev, cur, prediction, first_start, guessed, frame, st);
  const bool found = outcome.have && !outcome.stats.degenerate && outcome.stats.covariance.allFinite();
  Stopwatch scan;
  CandidateIndex index(prev);
  // Failed there, the first pass's start stands (the caller falls back to the coarse motion) unless out-supported.
  const RigidTransform& reference = found ? outcome.best : first_start;
  double best_support = found || guessed ? lines_.support(index, cur, reference) : -1.0;
  std::vector<RigidTransform> starts;
  if (found && outcome.have_rival) starts.push_back(outcome.rival);
  RigidTransform peak;
  if (weak_translation_peak(index, cur, reference, found ? &outcome.stats.covariance : nullptr, prediction, &peak))
    starts.push_back(peak);
  st->ms.candidates += scan.ms();
  for (const RigidTransform& start : starts) {
    FrameStats other_stats;
    PassOutcome other = lines_.register_features(prev, cur, prediction, start, true, frame, &other_stats);
    st->ms.candidates += other_stats.ms.candidates;
    st->ms.ransac += other_stats.ms.ransac;
    st->iterations += other_stats.iterations;
    if (!other.have || other.stats.degenerate) continue;
    scan = Stopwatch();
    const double other_support = lines_.support(index, cur, other.best);
    st->ms.candidates += scan.ms();
    if (other_support <= best_support) continue;
    best_support = other_support;
    outcome = other;
    st->candidates = other_stats.candidates;
    st->plane_candidates = other_stats.plane_candidates;
    st->passes = other_stats.passes;
  }
  return outcome;
}

// A velocity no frame has measured since the first motion was held (a start mid-drive on a sparse highway or in a
// featureless corridor) stays at standing still along the directions no scan observes. When a scene that observes
// them comes, the candidates picked near that velocity miss a motion beyond their distance: on the simulated street
// after the corridor at 3 m a frame, held at zero for good or for 7 frames, some registered as standing still. So
// each frame until they are measured, the estimate is scanned along their translations (translation_peak, as the first
// motion's) and registered from the peak; that motion is taken when it observes every direction and the candidates
// picked near it support it kRecoveryMargin times as much as the estimate. A velocity held correctly is out-supported
// by no shift, and where the scene does not observe them the scan finds no peak or the registration is degenerate.
bool MotionSearch::search_unmeasured(const ScanFeatures& prev, const ScanFeatures& cur,
                                     const ScanFeatures& prev_scanned, const ScanFeatures& cur_scanned,
                                     const RigidTransform& prediction, const Mat6& unmeasured_projector,
                                     const RegistrationFrame& frame, PassOutcome* outcome, FrameStats* st) const {
  const RigidTransform& estimate = outcome->have ? outcome->best : prediction;
  const Eigen::SelfAdjointEigenSolver<Mat3> translations(unmeasured_projector.topLeftCorner<3, 3>());
  std::vector<std::pair<RigidTransform, Vec3>> scans;
  for (int k = 0; k < 3; ++k)
    if (translations.eigenvalues()(k) >= kUnmeasuredTranslation)
      scans.emplace_back(estimate, translations.eigenvectors().col(k));
  if (scans.empty()) return false;
  Stopwatch scan;
  RigidTransform peak;
  CandidateIndex scanned_index(prev_scanned);
  const bool peaked = translation_peak(scanned_index, cur_scanned, estimate, scans, &peak);
  st->ms.candidates += scan.ms();
  if (!peaked || (peak.t - estimate.t).norm() < kOwnReach * config().candidates.max_distance) return false;
  return adopt_if_better(prev, cur, prediction, estimate, peak, frame, outcome, st);
}

// The turn rate changed since the last frame (a robot reversing its turn, a swung sensor): the prediction's heading
// is off by the whole change, at 10-20 m a 10 degree error moves the lines 1.7-3.5 m, past the candidates' reach, and
// the registration fails or holds the rotation at the wrong prediction (docs/NODE.md "Turns"). Such a frame scans
// the heading of its estimate about the ground's up axis over registration.max_rotation_deg (support_peak), each step
// moving the lines at the scan's median range as far as a step of the shift scan, and registers from the peak. So does
// a frame that kept less than kSupportDrop of the last frame's support (a wrong heading where a few coincidental pairs
// observe every direction). A frame that holds only translations (a highway's forward motion) is not searched.
bool MotionSearch::search_turn(const ScanFeatures& prev, const ScanFeatures& cur, const RigidTransform& prediction,
                               double last_inlier_weight, const RegistrationFrame& frame, PassOutcome* outcome,
                               FrameStats* st) const {
  const bool registered = outcome->have && !outcome->stats.degenerate && outcome->stats.covariance.allFinite();
  if (registered) {
    Mat6 rotations = Mat6::Zero();
    rotations.bottomRightCorner<3, 3>().setIdentity();
    const bool holds_rotation = !common_directions(outcome->held_projector, rotations, kHeldRotationCosine).isZero();
    // A registration that kept a small share of the last frame's support (the walls' pairs out of reach, only the
    // ground's meeting) may have settled on a wrong heading, whatever it holds.
    const bool lost_support = outcome->stats.inlier_weight < kSupportDrop * last_inlier_weight;
    if (!holds_rotation && !lost_support) return false;
  }
  st->turn_searched = true;
  const RigidTransform& estimate = registered ? outcome->best : prediction;
  Stopwatch scan;
  const double threshold = config().ransac.inlier_threshold;
  const double lever = median_line_range(cur);
  const double range = config().registration.max_rotation_deg * kPi / 180.0;
  const double step = std::max(kWeakShiftStep * threshold / lever, range / kMaxShiftSteps);
  const int steps = static_cast<int>(range / step + 1e-9);
  const double tolerance = 0.5 * step * lever / threshold;
  Plane ground;
  const bool level = ground_plane(cur, &ground);
  // (ground lines meet within the tolerance at every heading when each is within half of it of the plane)
  const ScanFeatures scored = level ? lines_off_ground(cur, ground, 0.5 * tolerance * threshold) : ScanFeatures{};
  CandidateIndex index(prev);
  RigidTransform peak;
  const bool peaked = steps > 0 && support_peak(index, level ? scored : cur, estimate,
                                                {{estimate, level ? ground.n : Vec3::UnitZ()}}, turn_motion, step,
                                                steps, tolerance, &peak);
  st->ms.candidates += scan.ms();
  if (!peaked) return false;
  // A registration's candidates reached a peak that moves the lines at the median range less than kOwnReach of their
  // distance: its held turn is not a wrong basin's.
  const double moved = Eigen::AngleAxisd(estimate.R.transpose() * peak.R).angle() * lever;
  if (registered && moved < kOwnReach * config().candidates.max_distance) return false;
  return adopt_if_better(prev, cur, prediction, estimate, peak, frame, outcome, st);
}

// No velocity yet: a registration on the scans downsampled by registration.coarse_downsample finds the first motion
// (paper §6.3 needs a guess within the candidate distance), the configured resolution refines it from there (or from
// standing still) and from other starts (first_motion).
PassOutcome MotionSearch::search_first_motion(const ScanFeatures& prev, const ScanFeatures& prev_coarse,
                                              const ScanFeatures& cur, const ScanFeatures& coarse_cur,
                                              const RigidTransform& prediction, const RegistrationFrame& frame,
                                              FrameStats* st) const {
  bool coarse_used = false;
  PassOutcome coarse;
  if (!prev_coarse.h_lines.empty() && !coarse_cur.h_lines.empty()) {
    FrameStats coarse_stats;
    coarse = lines_.register_features(prev_coarse, coarse_cur, prediction, prediction, false, frame, &coarse_stats);
    st->ms.candidates += coarse_stats.ms.candidates;
    st->ms.ransac += coarse_stats.ms.ransac;
    st->iterations += coarse_stats.iterations;
    coarse_used = coarse.have && !coarse.stats.degenerate;
  }
  PassOutcome outcome = first_motion(prev, cur, prediction, coarse_used ? &coarse.best : nullptr, frame, st);
  // The first motion seen there stands when the configured resolution cannot confirm it (too few crossings
  // along the motion, e.g. a highway at 1/64 with a first motion found at 1/36).
  if (coarse_used && !(outcome.have && !outcome.stats.degenerate)) outcome = coarse;
  return outcome;
}

bool MotionSearch::adopt_if_better(const ScanFeatures& prev, const ScanFeatures& cur,
                                   const RigidTransform& prediction, const RigidTransform& held,
                                   const RigidTransform& start, const RegistrationFrame& frame, PassOutcome* outcome,
                                   FrameStats* st) const {
  FrameStats other_stats;
  PassOutcome other = lines_.register_features(prev, cur, prediction, start, true, frame, &other_stats);
  st->ms.candidates += other_stats.ms.candidates;
  st->ms.ransac += other_stats.ms.ransac;
  st->iterations += other_stats.iterations;
  if (!other.have || other.stats.degenerate || other.held_directions > 0 || !other.stats.covariance.allFinite())
    return false;
  Stopwatch scan;
  CandidateIndex index(prev);
  const double held_support = lines_.support(index, cur, held);
  const double found_support = lines_.support(index, cur, other.best);
  st->ms.candidates += scan.ms();
  if (!(found_support > kRecoveryMargin * held_support)) return false;
  *outcome = other;
  st->candidates = other_stats.candidates;
  st->plane_candidates = other_stats.plane_candidates;
  st->passes = other_stats.passes;
  return true;
}

// The shifts (translation_peak) of the estimate along its least observed translation (largest eigenvalue of its
// covariance, when it has one), and of the prediction along each sensor axis and along the lines (vehicles move along
// a sensor axis or the road; a wrong sample's rotation would hide the right shift, and where two directions are about
// as weak the eigenvector mixes them).
bool MotionSearch::weak_translation_peak(CandidateIndex& index, const ScanFeatures& cur, const RigidTransform& estimate,
                                     const Mat6* covariance, const RigidTransform& prediction,
                                     RigidTransform* peak) const {
  std::vector<std::pair<RigidTransform, Vec3>> scans;
  if (covariance) {
    const Eigen::SelfAdjointEigenSolver<Mat3> eigen(covariance->topLeftCorner<3, 3>());
    if (eigen.info() == Eigen::Success) scans.emplace_back(estimate, eigen.eigenvectors().col(2));
  }
  // Each sensor axis; the other travel directions unless the estimate's weakest one is already along them.
  const std::vector<Vec3> directions = travel_directions(cur);
  for (std::size_t k = 0; k < directions.size(); ++k) {
    bool scanned = false;
    if (k >= 3)
      for (const auto& scan : scans) scanned = scanned || std::abs(scan.second.dot(directions[k])) >= kSameAxisCosine;
    if (!scanned) scans.emplace_back(prediction, directions[k]);
  }
  return translation_peak(index, cur, estimate, scans, peak);
}

// Each origin shifted along its direction every kWeakShiftStep inlier thresholds (at most kMaxShiftSteps per side) out
// to the largest motion the registration accepts (registration.max_translation, at least the candidate distance),
// scored with half a step of tolerance (support_peak).
bool MotionSearch::translation_peak(CandidateIndex& index, const ScanFeatures& cur, const RigidTransform& estimate,
                                const std::vector<std::pair<RigidTransform, Vec3>>& scans, RigidTransform* peak) const {
  const double threshold = config().ransac.inlier_threshold;
  const double range = std::max(config().candidates.max_distance, config().registration.max_translation);
  const double step = std::max(kWeakShiftStep * threshold, range / kMaxShiftSteps);
  const int steps = static_cast<int>(range / step + 1e-9);
  return support_peak(index, cur, estimate, scans, shift_motion, step, steps, 0.5 * step / threshold, peak);
}

// Each origin moved along its axis (`move`) every `step` out to `steps` per side, scored on up to kScanLines of the
// scan's lines and the candidates within a quarter of the candidate distance, with `tolerance` inlier thresholds:
// true when one out-supports the estimate itself; the peak refined to a quarter step.
bool MotionSearch::support_peak(CandidateIndex& index, const ScanFeatures& cur, const RigidTransform& estimate,
                            const std::vector<std::pair<RigidTransform, Vec3>>& scans, MoveMotion move, double step,
                            int steps, double tolerance, RigidTransform* peak) const {
  const ScanFeatures scored = every_kth_line(cur, kScanLines);
  const double reach = 0.25 * config().candidates.max_distance;
  double best = lines_.support(index, scored, estimate, tolerance, reach);
  const double estimate_tolerant = best;
  Vec3 peak_axis = Vec3::Zero();
  for (const auto& [origin, axis] : scans) {
    for (int k = -steps; k <= steps; ++k) {
      if (k == 0) continue;
      const RigidTransform moved = move(origin, axis, k * step);
      const double s = lines_.support(index, scored, moved, tolerance, reach);
      if (s > best) {
        best = s;
        *peak = moved;
        peak_axis = axis;
      }
    }
  }
  if (!(best > estimate_tolerant)) return false;
  // The peak to a quarter step: half and a quarter of a step either side, with as much tolerance.
  double fine_step = step, fine_tolerance = tolerance;
  for (int round = 0; round < 2; ++round) {
    fine_step *= 0.5;
    fine_tolerance *= 0.5;
    const RigidTransform centre = *peak;
    double centre_support = lines_.support(index, scored, centre, fine_tolerance, reach);
    for (const double side : {-1.0, 1.0}) {
      const RigidTransform moved = move(centre, peak_axis, side * fine_step);
      const double s = lines_.support(index, scored, moved, fine_tolerance, reach);
      if (s > centre_support) {
        centre_support = s;
        *peak = moved;
      }
    }
  }
  return true;
}


}  // namespace line_odom
