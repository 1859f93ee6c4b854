#include "odometry/motion_validation.hpp"

#include <algorithm>
#include <bitset>
#include <cmath>
#include <cstdio>
#include <memory>
#include <string>
#include <utility>

#include <Eigen/Eigenvalues>

#include "common/stopwatch.hpp"
#include "features/scan_directions.hpp"
#include "odometry/motion_fusion.hpp"

namespace line_odom {

namespace {

constexpr const char* kAxisNames[6] = {"x", "y", "z", "rx", "ry", "rz"};
constexpr int kAllAxes = 0x3f;
constexpr int kTranslationAxes = 0x07;  // x, y, z
constexpr int kRotationAxes = 0x38;     // rx, ry, rz
// A held subspace holds the travel when it holds this much of its direction (within 26 deg).
constexpr double kHeldTravelCosine = 0.9;

int count_axes(int axes) { return static_cast<int>(std::bitset<6>(static_cast<unsigned>(axes)).count()); }

std::string axes_text(int axes) {
  std::string text;
  for (int k = 0; k < 6; ++k)
    if (axes >> k & 1) text += std::string(text.empty() ? "" : ", ") + kAxisNames[k];
  return text;
}

// The resolution at which the point map's alignment resolves an axis: a third of the tolerance.
double points_resolution(double tolerance) { return tolerance / 3.0; }

// The axes of xi (bits) along which a motion of covariance `covariance` is known to points_resolution(`tolerance`)
// (rotations at `lever`).
int resolved_axes(const Mat6& covariance, double tolerance, double lever) {
  int axes = 0;
  for (int k = 0; k < 6; ++k)
    if (std::sqrt(std::max(0.0, covariance(k, k))) * (k < 3 ? 1.0 : lever) < points_resolution(tolerance))
      axes |= 1 << k;
  return axes;
}

// `from` moved to `to` along the axes of xi in `axes` (bits; motion_difference's chart at `from`), the others kept.
RigidTransform along_axes(const RigidTransform& from, const RigidTransform& to, int axes) {
  Vec6 xi = motion_difference(to, from);
  for (int k = 0; k < 6; ++k)
    if (!(axes >> k & 1)) xi[k] = 0.0;
  return apply_motion_difference(xi, from);
}

// The axes of xi (bits) along which `a` and `b` lie farther apart than `tolerance` (rotations at `lever`).
int axes_apart(const RigidTransform& a, const RigidTransform& b, double tolerance, double lever) {
  const Vec6 difference = motion_difference(a, b);
  int axes = 0;
  for (int k = 0; k < 6; ++k)
    if (std::abs(difference[k]) * (k < 3 ? 1.0 : lever) > tolerance) axes |= 1 << k;
  return axes;
}

// The translation axes along which the points' motion lies on the far side of standing still from the lines': a sparse
// scan's alignment falls short of a motion (open_directions), it does not reverse it. `floor` is the lines' inlier
// threshold, their noise: the lines' translation counts beyond three of it; the points' reversal is judged by their own
// noise, beyond three of their standard deviations.
int reversed_translation(const RigidTransform& lines, const RigidTransform& points, const Mat6& points_covariance,
                         double floor) {
  const double moved = lines.t.norm();
  if (!(moved > 3.0 * floor)) return 0;
  const Vec3 direction = lines.t / moved;
  const double along = points.t.dot(direction);
  const double sigma =
      std::sqrt(std::max(0.0, direction.dot(points_covariance.topLeftCorner<3, 3>() * direction)));
  if (!(along < -3.0 * sigma)) return 0;
  int axes = 0;
  for (int k = 0; k < 3; ++k)
    if (std::abs(lines.t[k]) > floor) axes |= 1 << k;
  return axes;
}

// The axes of xi (bits) along which the points' motion lies farther from the lines' than `floor` and three of the
// points' standard deviations (rotations at `lever`).
int beyond_points_noise(const RigidTransform& lines, const RigidTransform& points, const Mat6& points_covariance,
                        double floor, double lever) {
  const Vec6 turned = motion_difference(lines, points);
  int axes = 0;
  for (int k = 0; k < 6; ++k) {
    const double scale = k < 3 ? 1.0 : lever;
    const double difference = k < 3 ? points.t[k] - lines.t[k] : turned[k];
    if (std::abs(difference) * scale > std::max(3.0 * std::sqrt(std::max(0.0, points_covariance(k, k))) * scale, floor))
      axes |= 1 << k;
  }
  return axes;
}

// The translation axes along which the points' motion lies within `basin` of standing still.
int within_basin(const RigidTransform& points, double basin) {
  int axes = 0;
  for (int k = 0; k < 3; ++k)
    if (std::abs(points.t[k]) < basin) axes |= 1 << k;
  return axes;
}

// The translation axes along which the points' motion lies within `basin` of standing still and short of the lines'
// on the same side: where a sparse scan's alignment falls when it leans to the last scan's sampling, whatever the
// motion beyond it.
int leaning_translation(const RigidTransform& lines, const RigidTransform& points, double basin) {
  int axes = 0;
  for (int k = 0; k < 3; ++k)
    if (points.t[k] * lines.t[k] >= 0.0 && std::abs(lines.t[k]) > std::abs(points.t[k])) axes |= 1 << k;
  return axes & within_basin(points, basin);
}

// The median distance of a scan's points from the sensor (of about a thousand of them, spread over the scan).
double median_range(const std::vector<Vec3>& points) {
  constexpr std::size_t kSampled = 1024;
  const std::size_t step = std::max<std::size_t>(1, points.size() / kSampled);
  std::vector<double> ranges;
  ranges.reserve(points.size() / step + 1);
  for (std::size_t i = 0; i < points.size(); i += step) ranges.push_back(points[i].norm());
  if (ranges.empty()) return 0.0;
  std::nth_element(ranges.begin(), ranges.begin() + ranges.size() / 2, ranges.end());
  return ranges[ranges.size() / 2];
}

// The horizontal direction across a travel of `travel` (unit; zero when it is shorter than `tolerance`, too short to
// tell its way, or runs within 30 degrees of `up`): a vehicle hardly moves along it.
Vec3 side_of_travel(const Vec3& travel, const Vec3& up, double tolerance) {
  const Vec3 side = travel.cross(up);
  return travel.norm() > tolerance && side.norm() > 0.5 * travel.norm() ? Vec3(side.normalized()) : Vec3::Zero();
}

// The projector onto the directions of `projector` and `direction` (xi, unit).
Mat6 widened(const Mat6& projector, const Vec6& direction) {
  const Eigen::SelfAdjointEigenSolver<Mat6> spanned(projector + direction * direction.transpose());
  Eigen::Matrix<double, 6, Eigen::Dynamic> basis(6, 0);
  for (int k = 0; k < 6; ++k) {
    if (!(spanned.eigenvalues()(k) > 0.5)) continue;
    basis.conservativeResize(Eigen::NoChange, basis.cols() + 1);
    basis.col(basis.cols() - 1) = spanned.eigenvectors().col(k);
  }
  return subspace_projector(basis);
}

// A shift along `direction` without a turn, as xi.
Vec6 shift_along(const Vec3& direction) {
  Vec6 xi = Vec6::Zero();
  xi.head<3>() = direction;
  return xi;
}

// `lines` turned to `points` along the rotation axes `turns` (bits), its translation along `side` (unit, or zero) moved
// by the regression of that direction on those axes in the lines' covariance: where the lines trade a turn for a
// sideways shift, the shift their own estimate puts with the turn.
RigidTransform turned_along_valley(const RigidTransform& lines, const RigidTransform& points, int turns,
                                   const Mat6& covariance, const Vec3& side) {
  const Vec6 xi = motion_difference(points, lines);
  Vec6 step = Vec6::Zero();
  Mat6 on_turns = Mat6::Zero();  // the covariance's block of the turned axes (identity elsewhere: invertible)
  const Vec6 side_direction = shift_along(side);
  Vec6 with_side = Vec6::Zero();  // covariance of the side with each turned axis
  for (int k = 0; k < 6; ++k) {
    if (!(turns >> k & 1)) {
      on_turns(k, k) = 1.0;
      continue;
    }
    step[k] = xi[k];
    with_side[k] = side_direction.dot(covariance.col(k));
    for (int j = 0; j < 6; ++j)
      if (turns >> j & 1) on_turns(k, j) = covariance(k, j);
  }
  const double shift = with_side.dot(on_turns.ldlt().solve(step));
  if (std::isfinite(shift)) step.head<3>() = shift * side;
  return apply_motion_difference(step, lines);
}

// The projector onto the direction along which the lines' motion of covariance `covariance` is least known (rotations
// at `lever`): the valley along which they trade a turn for a shift.
Mat6 valley_projector(const Mat6& covariance, double lever) {
  Vec6 scale;
  scale << 1.0, 1.0, 1.0, lever, lever, lever;
  const Eigen::SelfAdjointEigenSolver<Mat6> eigen(scale.asDiagonal() * covariance * scale.asDiagonal());
  if (eigen.info() != Eigen::Success) return Mat6::Zero();
  const Vec6 direction = (eigen.eigenvectors().col(5).array() / scale.array()).matrix().normalized();
  return direction * direction.transpose();
}

// The map judges a frame from its points' alignment when the previous scan entered the map (its place relative to
// this scan is then known) and the frame is not a first motion.
bool judges(const ValidationFrame& frame, const PointMapTracker& point_map, const RigidTransform* by_points) {
  return by_points != nullptr && !frame.first_motion && point_map.holds_last_scan();
}

}  // namespace

struct MotionValidation::Judgement {
  Correspondences corr;  // the last pass's candidates under the motion
  Observability obs;     // McNemar's test on them
  int open = kAllAxes;   // the directions not confirmed (open_directions)
  int reversed = 0, leaning = 0;
  int unpinned = 0;  // open directions the lines' own test leaves open and the points put elsewhere
  int contradicted = 0;  // directions the lines' own test confirms and the points clearly fit elsewhere
  int two_way = 0;   // open translations the points put the other way while fitting the lines' motion as well
  int unconfirmed_place = 0;  // open directions the lines' own test leaves open, along which the last scan sits on the
                              // map where its own unconfirmed lines put it
};

Observability MotionValidation::observe(const ValidationFrame& frame, const PassOutcome& outcome,
                                        Correspondences* corr) const {
  const OdometryConfig& config = lines_.config();
  if (outcome.candidates) {
    *corr = *outcome.candidates;
  } else {
    CandidateIndex index(*frame.previous);
    build_candidates(index, *frame.current, outcome.best, lines_.last_pass_candidates(), corr, nullptr, lines_.pool());
  }
  const LinePairTable table(*corr);
  return test_observability(*corr, table, outcome.best, config.ransac.inlier_threshold,
                            RefineOptions{}.min_line_sine, observability_push(outcome.best, config.validation),
                            config.validation.significance);
}

void MotionValidation::open_directions(const ValidationFrame& frame, const PassOutcome& outcome,
                                       const PointMapTracker& point_map, const RigidTransform* by_points,
                                       const Mat6& points_covariance, Judgement* judgement) const {
  const Observability& obs = judgement->obs;
  int& reversed = judgement->reversed;
  int& unpinned = judgement->unpinned;
  int& two_way = judgement->two_way;
  int& contradicted = judgement->contradicted;
  reversed = unpinned = two_way = contradicted = judgement->leaning = judgement->unconfirmed_place = 0;
  // The lines alone judge a first motion: the map then holds one scan, whose sampling a sparse scan follows (its rings
  // sit where that scan's rings sat when standing still), so its alignment leans to standing still. Leaning, it falls
  // short of a motion but does not reverse it: only a first motion the points put on the other side of standing still
  // is not taken. The lines alone judge after a frame that stayed out of the map: its place on the map is not known.
  if (by_points == nullptr || !point_map.holds_last_scan()) {
    judgement->open = obs.unobserved;
    return;
  }
  const bool judged = judges(frame, point_map, by_points);  // else a first motion: only the reversal below
  // Evidence the intersection inliers did not produce: where the points' motion lies farther from the lines' than the
  // tolerance, or on the other side of standing still (reversed_translation), the lines' motion is not taken; only
  // where the points resolve the direction to a third of the tolerance (along a corridor, or the street a car drives
  // down, they may not: their motion there is no evidence).
  const double tolerance = observability_push(outcome.best, lines_.config().validation);
  const int resolved = resolved_axes(points_covariance, tolerance, obs.lever);
  reversed =
      reversed_translation(outcome.best, *by_points, points_covariance, lines_.config().ransac.inlier_threshold) &
      resolved;
  int open = reversed;
  int lean = 0;
  if (judged) {
    // A rotation apart by the tolerance at the scene's range, not only at the meeting lines' (on a sparse scan those
    // near the sensor dominate, and a heading degrees off moves them less than the tolerance); where a gyro measured
    // the turn the lines started from, at the lines' range.
    const double lever = frame.rotation_guessed ? obs.lever : std::max(obs.lever, median_range(*frame.points));
    const int apart = axes_apart(outcome.best, *by_points, tolerance, lever) & resolved;
    // Where the kernel is wider than the tolerance, points inside it may sit in standing still's basin whatever the
    // motion: agreeing with the lines there to the tolerance confirms nothing (the lines' own test decides).
    const double basin = point_map.alignment_kernel_scale();
    lean = (leaning_translation(outcome.best, *by_points, basin) & apart) |
           (basin > tolerance ? within_basin(*by_points, basin) & ~apart & ~reversed : 0);
    open |= apart & ~lean;
    // Along a direction the lines' own test leaves open, agreeing with the points to the tolerance only says that the
    // lines' valley reaches the points' motion: where the points resolve it, do not lean and put it farther than their
    // resolution (a third of the tolerance) from the lines', the lines' motion there is not confirmed either.
    unpinned = obs.unobserved & resolved & ~lean & ~within_basin(*by_points, basin) &
               beyond_points_noise(outcome.best, *by_points, points_covariance, points_resolution(tolerance), lever) &
               ~open;
    open |= unpinned;
    // Where the lines' own test confirms a direction, the tolerance bounds what the frame claims. But a turn the points
    // put farther off than their resolution (at the scene's range), where they fit their own alignment better by
    // validation.significance standard errors, is contradicted by evidence the intersection inliers did not produce:
    // on a sparse scan that sees little but the road ahead, the lines trade a turn for a sideways shift and keep it as
    // their velocity. Not the translations: there a sparse scan's alignment leans to standing still and follows the
    // traffic (a car ahead that the drive follows to a stop).
    contradicted = axes_apart(outcome.best, *by_points, points_resolution(tolerance), lever) & resolved &
                   kRotationAxes & ~open;
    if (contradicted != 0 &&
        point_map.fit_advantage(*frame.points, frame.previous_pose, *by_points, outcome.best) >
            lines_.config().validation.significance)
      open |= contradicted;
    else
      contradicted = 0;
  }
  // The alignment is a local optimum from the prediction: where the points fit the lines' motion at least as well, it
  // stopped short of it (a first step too wide, a flat direction, a lean), and the points confirm the lines.
  // Unless the alignment lies on the other side of standing still and the points fit the lines' motion no better by
  // validation.significance standard errors: they then fit two motions mirrored about standing still alike and cannot
  // tell which way the scan travelled; nothing confirms the lines' direction there.
  if (open != 0 && point_map.fits_as_well(*frame.points, frame.previous_pose, outcome.best, *by_points)) {
    if (judged && reversed != 0 &&
        point_map.fit_advantage(*frame.points, frame.previous_pose, outcome.best, *by_points) <
            lines_.config().validation.significance)
      two_way = reversed;
    open = two_way;
    reversed = 0;
    unpinned = 0;
    contradicted = 0;
  }
  // Where the points lean, they cannot tell the lines' motion from standing still: the lines' own test decides there.
  judgement->leaning = obs.unobserved & lean;
  // Along the directions the last scan entered the map at its lines' unconfirmed motion, the points' alignment agreeing
  // with the lines may only repeat that motion (a first motion short of the car's, then confirmed by the next scan's
  // alignment to the scan it placed): no confirmation there, the lines' own test decides. (Where the alignment
  // disagrees, the map's other scans put the scan elsewhere: that is evidence, judged above.)
  if (judged)
    judgement->unconfirmed_place = obs.unobserved & point_map.last_scan_unconfirmed() & ~open & ~judgement->leaning;
  judgement->open = judged ? open | judgement->leaning | judgement->unconfirmed_place : obs.unobserved | open;
}

Validated MotionValidation::validate(const ValidationFrame& frame, const PointMapTracker& point_map,
                                     PassOutcome* outcome, FrameStats* st) const {
  Validated out;
  out.reference = frame.prediction;
  if (!lines_.config().validation.enabled) return out;
  Stopwatch watch;
  bool travelled = false;  // a first motion's alignment the points showed the scan travelled to
  const MapAlignment points = align_to_map(frame, point_map, &travelled);
  st->points_aligned = points.aligned;
  st->point_map_matches = points.matched;
  const RigidTransform* by_points = points.aligned ? &points.motion : nullptr;
  const bool judged = judges(frame, point_map, by_points);

  Judgement judgement;
  int off_guess = 0;
  if (registered_in_full(*outcome)) {
    judge(frame, *outcome, point_map, by_points, points.covariance, &judgement);
    // A guess (wheel odometry) measured the distance travelled apart from the lines: a registration translated
    // farther from it than the tolerance is the lines' other valley point, not the guess's error (a slow car among
    // faster traffic: pairs on the passing cars support the motion mirrored about standing still, McNemar z above the
    // significance). Not the rotations: a source's heading may miss a turn change the lines and the turn search find.
    if (frame.guessed) {
      const double tolerance = observability_push(outcome->best, lines_.config().validation);
      off_guess = axes_apart(outcome->best, frame.prediction, tolerance, judgement.obs.lever) & kTranslationAxes;
      judgement.open |= off_guess;
    }
  }
  const bool partly_registered = outcome->have && outcome->held_directions > 0;
  if (points.aligned && judgement.open != 0 &&
      (frame.first_motion || (!registered_in_full(*outcome) && !partly_registered)))
    register_from_points(frame, point_map, points.motion, points.covariance, outcome, &judgement, st);
  if (judged && outcome->have && outcome->held_directions > 0)
    hold_at_the_map(frame, points.motion, points.covariance, outcome, &out);
  st->observability = judgement.obs.z;
  st->unobserved = registered_in_full(*outcome) ? judgement.open : 0;
  settle_open_directions(frame, point_map, judgement, points, judged, travelled, off_guess, outcome, &out);
  if (judged) {
    out.judged = true;
    out.by_points = points.motion;
    out.resolved = resolved_axes(points.covariance,
                                 observability_push(outcome->have ? outcome->best : frame.prediction,
                                                    lines_.config().validation),
                                 judgement.obs.lever);
  }
  st->ms.validation += watch.ms();
  return out;
}

// A first motion is aligned from standing still and from the starts along the directions a vehicle travels that the
// points fit best: from standing still alone, a sparse scan of a car at highway speed falls into standing still's
// basin (its rings' points match the one-scan map's where they sat), even where they fit the right motion clearly
// better (align_from_starts). A guessed frame is not aligned; a frame aligned before its lines takes that alignment.
MapAlignment MotionValidation::align_to_map(const ValidationFrame& frame, const PointMapTracker& point_map,
                                            bool* travelled) const {
  MapAlignment points;
  if (frame.guessed) return points;
  if (frame.first_motion) {
    points.aligned = point_map.align_from_starts(
        *frame.points, frame.previous_pose, frame.prediction, travel_directions(*frame.current),
        lines_.config().registration.max_translation, lines_.config().validation.significance, &points.motion,
        &points.matched, &points.covariance, travelled);
  } else if (frame.aligned_before) {
    points = *frame.aligned_before;
  } else {
    points.aligned = point_map.align(*frame.points, frame.previous_pose, frame.prediction, &points.motion,
                                     &points.matched, &points.covariance);
  }
  return points;
}

// The directions a registration in full leaves open: held at the points' alignment (or a guess), the points'
// alignment taken, or flagged at the lines' motion, `outcome->failure` saying why.
void MotionValidation::settle_open_directions(const ValidationFrame& frame, const PointMapTracker& point_map,
                                              const Judgement& judgement, const MapAlignment& points, bool judged,
                                              bool travelled, int off_guess, PassOutcome* outcome,
                                              Validated* out) const {
  const bool aligned = points.aligned;
  const RigidTransform& by_points = points.motion;
  const RigidTransform reference = aligned ? by_points : frame.prediction;  // what open directions are held at
  // Where the points' motion is taken, the scan enters the map there; a first motion only beyond the alignment
  // kernel's width of standing still: the one-scan map's alignment may have fallen into standing still's basin (a
  // sparse scan moving 1.5 m aligned at 0.07 m), and the map built on it would confirm that motion after.
  const bool placed_by_points =
      aligned && (!frame.first_motion || by_points.t.norm() > point_map.alignment_kernel_scale());
  const Correspondences& corr = judgement.corr;
  const Observability& obs = judgement.obs;
  const int open = judgement.open;
  const int reversed = judgement.reversed, leaning = judgement.leaning, unpinned = judgement.unpinned,
            two_way = judgement.two_way, contradicted = judgement.contradicted,
            unconfirmed_place = judgement.unconfirmed_place;
  // The directions the points cannot judge: the lines' motion stands there (flagged where open).
  const int lines_decide = leaning | unconfirmed_place;

  // Where the lines leave a direction open that the points put elsewhere, their valley (a turn traded for a shift) is
  // held there too: held on that axis alone, the lines slide along the rest of it.
  const Mat6 valley = unpinned != 0 ? valley_projector(outcome->stats.covariance, obs.lever) : Mat6::Zero();
  // The axes the points' alignment resolves at the lines' motion's tolerance.
  const double tolerance = observability_push(outcome->best, lines_.config().validation);
  const int points_resolve = aligned ? resolved_axes(points.covariance, tolerance, obs.lever) : 0;
  // A translation so held shows the lines at another point of that valley than the scene's motion, beyond the
  // covariance's local reach: refitted with the shift held, their turn moves along it, away from the points'. So the
  // rotations the points resolve are held at their alignment too.
  const int turns_held = judged && (unpinned & kTranslationAxes) != 0 ? kRotationAxes & points_resolve : 0;
  if (registered_in_full(*outcome) && open != 0) {
    // Held where nothing confirms the lines: at the points' motion, or at a guess; with neither, the lines' motion
    // stands, flagged. Where no direction is confirmed, the points' motion is the frame's.
    char why[200];
    std::snprintf(why, sizeof why, "the lines' motion is not confirmed along %s (%s)", axes_text(open).c_str(),
                  (open & reversed) != 0    ? "the point map's alignment moves the other way"
                  : (open & ~two_way) == 0  ? "the point map fits the lines' motion and its own the other way alike"
                  : (open & ~unconfirmed_place) == 0
                      ? "McNemar z under validation.significance, the last scan on the point map where its own "
                        "unconfirmed lines put it"
                  : (open & ~leaning) == 0  ? "McNemar z under validation.significance, the point map's alignment "
                                              "leaning to standing still"
                  : (open & ~unpinned) == 0 ? "McNemar z under validation.significance, the point map's alignment "
                                              "resolving it elsewhere"
                  : (open & ~contradicted) == 0 ? "the point map fits its own alignment better by more than "
                                                  "validation.significance standard errors"
                  : judged                  ? "the point map's alignment differs by more than validation.tolerance"
                  : (open & off_guess) != 0 ? "the guess differs by more than validation.tolerance"
                                            : "McNemar z under validation.significance");
    // A first motion the lines confirm along no axis is the points' where they showed the way the scan travelled.
    const bool points_travelled = aligned && travelled && open == kAllAxes;
    if ((!judged && !frame.guessed && (open & reversed) == 0 && !points_travelled) ||
        (judged && (open & ~lines_decide & ~two_way) == 0)) {
      // Flagged: nothing better to hold the translations at (the prediction; a one-scan map's lean, not reversal; a
      // judging map's alignment leaning to standing still, or agreeing with lines that placed its last scan, where the
      // lines do not pin the motion down). A frame the map did not judge enters it at the lines' motion so flagged.
      // A first motion's rotations the lines leave open are the points', where they resolve them: the lines' rotation
      // there is one end of a valley they cannot tell apart (a turn traded for a sideways shift along a street's
      // walls); the points measured it. Not the translations, which lean to standing still; but the side of the travel
      // moves with the turn along that valley, as far as the lines' own covariance puts it with the turn.
      outcome->failure = why;
      const int turns = frame.first_motion ? open & kRotationAxes & points_resolve : 0;
      if (!judged) out->unconfirmed_place = open & ~turns;
      if (turns != 0) {
        const Vec3 side = side_of_travel(outcome->best.t, ground_up(*frame.current), tolerance);
        outcome->best = turned_along_valley(outcome->best, by_points, turns, outcome->stats.covariance, side);
        outcome->failure += ": " + axes_text(turns) + " taken from the point map's alignment";
      }
    } else if (aligned && open == kAllAxes) {
      outcome->have = false;
      outcome->failure = std::string(why) + ": the point map's alignment taken";
      out->reference = by_points;
      out->held_at_points = placed_by_points;
    } else if ((aligned || frame.guessed) &&
               lines_.hold_directions(corr, LinePairTable(corr), reference, (open & ~lines_decide) | turns_held,
                                      unpinned != 0 ? &valley : nullptr, outcome)) {
      outcome->failure = std::string(why) + (aligned ? ": held at the point map's alignment" : ": held at the guess") +
                         (turns_held != 0 ? ", with " + axes_text(turns_held) : "");
      out->reference = reference;
      out->held_at_points = aligned;
    } else if (judged) {
      // The lines cannot be held there (their inliers are other pairs at the points' motion): the points' alignment,
      // not the lines' unconfirmed motion, is what the next frames predict from.
      outcome->have = false;
      outcome->failure = std::string(why) + ": the point map's alignment taken";
      out->reference = by_points;
      out->held_at_points = placed_by_points;
    } else {
      outcome->failure = why;
    }
  } else if (aligned && !outcome->have) {
    outcome->failure += std::string(outcome->failure.empty() ? "" : ": ") + "the point map's alignment taken";
    out->reference = by_points;
    out->held_at_points = placed_by_points;
  }
}

void MotionValidation::judge(const ValidationFrame& frame, const PassOutcome& outcome, const PointMapTracker& point_map,
                             const RigidTransform* points, const Mat6& points_covariance, Judgement* judgement) const {
  judgement->obs = observe(frame, outcome, &judgement->corr);
  open_directions(frame, outcome, point_map, points, points_covariance, judgement);
}

void MotionValidation::register_from_points(const ValidationFrame& frame, const PointMapTracker& point_map,
                                            const RigidTransform& by_points, const Mat6& points_covariance,
                                            PassOutcome* outcome, Judgement* judgement, FrameStats* st) const {
  // The lines again from where the points put the scan: a first motion beyond the candidates' reach from standing
  // still, or a registration that failed from the prediction (not one whose refinement held a direction the lines
  // do not pin down: from another start they would not pin it down either).
  FrameStats other_stats;
  PassOutcome other = lines_.register_features(*frame.previous, *frame.current, frame.prediction, by_points, true,
                                               frame.registration, &other_stats);
  st->ms.candidates += other_stats.ms.candidates;
  st->ms.ransac += other_stats.ms.ransac;
  st->iterations += other_stats.iterations;
  if (!registered_in_full(other)) return;
  Judgement other_judgement;
  judge(frame, other, point_map, &by_points, points_covariance, &other_judgement);
  if (count_axes(other_judgement.open) >= count_axes(judgement->open)) return;
  *outcome = std::move(other);
  *judgement = std::move(other_judgement);
  st->candidates = other_stats.candidates;
  st->plane_candidates = other_stats.plane_candidates;
  st->passes = other_stats.passes;
}

void MotionValidation::hold_at_the_map(const ValidationFrame& frame, const RigidTransform& by_points,
                                       const Mat6& points_covariance, PassOutcome* outcome, Validated* out) const {
  // The rotations the lines leave open are held at the point map's alignment, which measured this scan, rather than
  // at the prediction, which only extrapolates the last frames (and kept a wrong turn rate along them), where the
  // points resolve them. The translations only along the velocity's directions no frame measured (a first motion
  // taken from the one-scan map's alignment, which leans to standing still): elsewhere the prediction carries a
  // motion the lines measured, and a sparse scan's alignment leans to the map's sampling (open_directions); and the
  // side of the travel where held_side says.
  Correspondences held_corr;
  const Observability held_obs = observe(frame, *outcome, &held_corr);
  const double tolerance = observability_push(outcome->best, lines_.config().validation);
  const int resolved = resolved_axes(points_covariance, tolerance, held_obs.lever);
  Vec6 step = motion_difference(by_points, frame.prediction);
  for (int k = 0; k < 6; ++k)
    if (!(resolved >> k & 1)) step[k] = 0.0;
  const Mat3 unmeasured = frame.unmeasured.topLeftCorner<3, 3>();
  const Vec3 side = held_side(frame, *outcome, points_covariance, tolerance);
  const Vec3 moved = step.head<3>();
  step.head<3>() = unmeasured * moved + (Mat3::Identity() - unmeasured) * side * side.dot(moved);
  const bool measured = (unmeasured * moved).norm() > 0.0;
  const bool sided = !side.isZero();
  const bool travelled = held_travel(frame, *outcome, by_points, points_covariance, tolerance, &step, out);
  if ((resolved & kRotationAxes) != 0 || measured || sided || travelled) {
    const RigidTransform turned = apply_motion_difference(step, frame.prediction);
    const Mat6 projector = sided ? widened(outcome->held_projector, shift_along(side)) : outcome->held_projector;
    if (lines_.hold_directions(held_corr, LinePairTable(held_corr), turned, 0, &projector, outcome)) {
      std::string held = measured ? "held at the point map's alignment along the velocity no frame measured"
                         : (resolved & kRotationAxes) != 0 ? "turn held at the point map's alignment"
                                                            : "";
      if (sided) held += held.empty() ? "the side of the travel held at the point map's alignment"
                                      : ", and the side of the travel";
      if (travelled)
        held += std::string(held.empty() ? "" : ", and ") +
                "the travel the frames before held taken from the point map's alignments since";
      outcome->failure += std::string(outcome->failure.empty() ? "" : ": ") + held;
      out->reference = turned;
      out->measured_velocity = measured;
    }
  }
}

bool MotionValidation::held_travel(const ValidationFrame& frame, const PassOutcome& outcome,
                                   const RigidTransform& by_points, const Mat6& points_covariance, double tolerance,
                                   Vec6* step, Validated* out) const {
  const double resolution = points_resolution(tolerance);
  const Vec3& travel = frame.prediction.t;
  if (frame.held_travel == nullptr || !(travel.norm() > resolution)) return false;
  const Vec3 along = travel.normalized();
  if ((outcome.held_projector.topLeftCorner<3, 3>() * along).norm() < kHeldTravelCosine) return false;
  const double points_sd = std::sqrt(std::max(0.0, along.dot(points_covariance.topLeftCorner<3, 3>() * along)));
  if (!(points_sd < resolution)) return false;
  out->travel_held = true;
  out->points_travel = along.dot(by_points.t);
  double mean = 0.0;
  if (!frame.held_travel->contradicted(out->points_travel, travel.norm(), resolution,
                                       lines_.config().validation.significance, &mean))
    return false;
  step->head<3>() += along * (mean - along.dot(apply_motion_difference(*step, frame.prediction).t));
  return true;
}

Vec3 MotionValidation::held_side(const ValidationFrame& frame, const PassOutcome& outcome,
                                 const Mat6& points_covariance, double tolerance) const {
  // The lines' held direction can run off the road, so that the side they report follows the prediction's: held at
  // the points' where that passes on more of the prediction's error than the points' own. The map's alignment leans
  // to standing still, which along the side of a vehicle's travel is where the motion is.
  const Vec3 side = side_of_travel(frame.prediction.t, ground_up(*frame.current), tolerance);
  const Mat6 reference_error = reference_covariance(lines_.config().registration, frame.registration.have_velocity);
  const Vec6 passed_on = outcome.held_sensitivity.transpose() * shift_along(side);
  return passed_on.dot(reference_error * passed_on) > side.dot(points_covariance.topLeftCorner<3, 3>() * side)
             ? side
             : Vec3::Zero();
}

RigidTransform place_on_map(const Validated& validated, const RigidTransform& previous_place,
                            const RigidTransform& delta) {
  return previous_place * along_axes(delta, validated.by_points, validated.resolved);
}

}  // namespace line_odom
