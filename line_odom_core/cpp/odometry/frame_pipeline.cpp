// The per-frame recipe of Odometry (odometry.hpp): each step a method over the components of OdometryState.
#include <Eigen/Geometry>

#include <algorithm>
#include <cmath>
#include <utility>

#include "common/stopwatch.hpp"
#include "features/line_selection.hpp"
#include "features/scan_directions.hpp"
#include "odometry/odometry.hpp"
#include "registration/point_refine.hpp"

namespace line_odom {

namespace {

// Adds the candidate and RANSAC times and hypotheses of a registration made aside into the frame's.
void add_times(const FrameStats& aside, FrameStats* st) {
  st->ms.candidates += aside.ms.candidates;
  st->ms.ransac += aside.ms.ransac;
  st->iterations += aside.iterations;
}

}  // namespace

Mat6 Odometry::unconfirmed(const FrameStats& st) const {
  if (!st.registered) return Mat6::Identity();
  // Held in part: the held directions carry the fallback variance already, the others are the lines' measurement.
  if (st.held_directions > 0) return Mat6::Zero();
  Mat6 axes = Mat6::Zero();
  for (int k = 0; k < 6; ++k)
    if (!(st.observability[k] >= config_.validation.significance)) axes(k, k) = 1.0;
  return axes;
}

FrameResult Odometry::register_image(const RangeImage& image, double stamp, double organize_ms, int organized_step,
                                     const RigidTransform* guess, const Mat3* rotation_guess, SweepTimes* sweep) {
  Stopwatch total;
  FrameResult result;
  result.stamp = stamp;
  FrameStats& st = result.stats;
  st.ms.organize = organize_ms;
  FrameInputs in = begin_frame(stamp, organized_step, guess, rotation_guess, sweep);

  // 1. Features.
  FrameFeatures scan;
  extract_features(image, in, &scan, &st);
  Plane scan_ground;  // the point map takes its points on it as the ground's plane (VoxelPointMap::plane)
  const Plane* ground = ground_plane(scan.features, &scan_ground) ? &scan_ground : nullptr;

  if (state_.frames == 0) {
    enter_first_scan(scan, ground, in, &st);
  } else {
    // 2. Prediction. 3. The lines' registration.
    predict(&in, &st);
    std::optional<MapAlignment> aligned_before;
    PassOutcome outcome = register_lines(scan, in, &aligned_before, &st);
    // 4. The sweep corrected again (its points then differ from those aligned before the lines).
    if (sweep != nullptr) {
      correct_sweep_again(&scan, in, &outcome, &st);
      aligned_before.reset();
    }
    // 5. Validation. 6. Fusion with the motion model. 7. The points' refinement. 8. The covariance widened to cover
    // the other measurements of the motion (after the refinement, which weighs the points by the lines' own): the
    // point map's alignment where it judged a frame reported as good; the prediction where a flagged frame's lines
    // left directions unconfirmed (elsewhere the difference is their measurement of a changed velocity). 9. The pose
    // and the map.
    const Validated validated = validate(&scan, in, aligned_before, &outcome, &st);
    const FusedMotion fused = fuse(outcome, in, validated, &result);
    refine_on_points(scan, fused, &result);
    const bool reported_good = st.registered && !st.degenerate;
    if (validated.judged && reported_good)
      result.covariance = covering(result.covariance, result.delta, validated.by_points);
    if (!reported_good)
      result.covariance = covering(result.covariance, result.delta, in.prediction, unconfirmed(st));
    advance(scan, ground, in, fused, validated, &result);
  }
  result.pose = state_.pose;
  keep_scan(&scan, result);
  st.ms.total = total.ms() + organize_ms;
  return result;
}

Odometry::FrameInputs Odometry::begin_frame(double stamp, int organized_step, const RigidTransform* guess,
                                            const Mat3* rotation_guess, SweepTimes* sweep) {
  OdometryState& s = state_;
  const RegistrationOptions& reg = config_.registration;
  FrameInputs in;
  in.dt = stamp - s.previous_stamp;
  in.organized_step = organized_step;
  in.guess = guess;
  in.rotation_guess = rotation_guess;
  in.sweep = sweep;
  if (s.prediction.have_velocity() && in.dt > reg.max_prediction_gap) {
    // After a pause the last motion says nothing about this one: no extrapolation, find the motion afresh.
    s.prediction.drop_velocity();
    s.sweeps.forget_trend();
  }
  // A guess stands for the velocity: registered from it, fused with it, degenerate directions held at it.
  in.guessed = guess != nullptr && s.frames > 0;
  if (in.guessed) s.prediction.set_have_velocity();
  in.rotation_guessed = rotation_guess != nullptr && s.frames > 0;
  in.first_motion = !s.prediction.have_velocity();
  in.unmeasured = s.prediction.unmeasured_projector();
  // Unmeasured directions are searched on the coarse scans when they are coarser (search_unmeasured).
  in.searching = !in.first_motion && !in.guessed && !in.unmeasured.isZero();
  return in;
}

void Odometry::extract_features(const RangeImage& image, const FrameInputs& in, FrameFeatures* scan,
                                FrameStats* st) {
  const int coarse_step = config_.registration.coarse_downsample;
  const bool coarse_scan =
      in.searching && coarse_step > config_.downsample && coarse_step % in.organized_step == 0;
  FeatureRequest request;
  request.organized_step = in.organized_step;
  request.fit_step = state_.scans.fit_step;
  request.coarse = (in.first_motion && coarse_step > 0 && coarse_step != config_.downsample) || coarse_scan;
  request.surface = points_refining();
  request.points = state_.point_map.enabled();
  extract_frame_features(image, config_, request, pool_.get(), scan, st);
  state_.scans.fit_step =
      next_fitting_step(st->h_lines + st->v_lines, state_.scans.fit_step, config_.registration.max_lines);
}

void Odometry::enter_first_scan(const FrameFeatures& scan, const Plane* ground, const FrameInputs& in,
                                FrameStats* st) {
  // The first frame defines the odometry frame (with the reset pose).
  st->registered = true;
  if (in.sweep == nullptr && state_.point_map.enabled()) {
    state_.point_map.add(scan.points, ground, state_.pose, {}, {});
    st->map_entry = "pose";
  }
}

void Odometry::predict(FrameInputs* in, FrameStats* st) const {
  const RegistrationOptions& reg = config_.registration;
  in->own_prediction =
      in->guessed ? *in->guess : state_.prediction.predict(in->dt, reg.constant_velocity, &st->persistence);
  in->prediction = in->rotation_guessed ? with_rotation(in->own_prediction, *in->rotation_guess) : in->own_prediction;
  st->prediction = in->guessed                                    ? "guess"
                   : !in->first_motion && reg.constant_velocity ? "constant_velocity"
                                                                  : "standing_still";
  if (in->rotation_guessed) st->prediction += "+imu";
  in->registration = registration_frame();
}

PassOutcome Odometry::register_lines(const FrameFeatures& scan, const FrameInputs& in,
                                     std::optional<MapAlignment>* aligned_before, FrameStats* st) const {
  const OdometryState& s = state_;
  const RegistrationFrame& frame = in.registration;
  // The lines' registration (paper §6.3), searched beyond the prediction's reach where it cannot reach.
  // A scan dense enough for the points' refinement (points.max_downsample) starts the lines at its points'
  // alignment to the map: from the prediction, the candidates picked near it can hold the lines at its turn rate
  // where the car turns into a bend (the lines' pairs near the old heading out-support the right ones). The
  // validation reads the same alignment.
  st->window_scans = 1;
  const bool align_first = !in.first_motion && !in.guessed && points_refining() && s.point_map.enabled() &&
                           s.point_map.holds_last_scan() && config_.validation.enabled;
  if (align_first) {
    Stopwatch stage;
    MapAlignment& before = aligned_before->emplace();
    before.aligned = s.point_map.align(scan.points, s.point_map.place_of(s.pose), in.prediction, &before.motion,
                                       &before.matched, &before.covariance);
    st->ms.validation += stage.ms();
  }
  const bool start_aligned = aligned_before->has_value() && (*aligned_before)->aligned;
  PassOutcome outcome =
      in.first_motion ? search_.search_first_motion(s.scans.previous, s.scans.previous_coarse, scan.features,
                                                    scan.coarse, in.prediction, frame, st)
                      : register_on_window(scan.features, in.prediction,
                                           start_aligned ? (*aligned_before)->motion : in.prediction, frame, st);
  if (in.first_motion && in.rotation_guessed && !registered_in_full(outcome)) {
    // A gyro's turn a little off can cost the first motion where the search from standing still finds it (KITTI 04
    // at 1/64, 0.05 deg of yaw, held at a standstill for good): that search runs too, and is taken when it registers
    // what the gyro's did not.
    FrameStats plain_stats;
    PassOutcome plain = search_.search_first_motion(s.scans.previous, s.scans.previous_coarse, scan.features,
                                                    scan.coarse, in.own_prediction, frame, &plain_stats);
    add_times(plain_stats, st);
    if (registered_in_full(plain)) {
      outcome = plain;
      st->candidates = plain_stats.candidates;
      st->plane_candidates = plain_stats.plane_candidates;
      st->passes = plain_stats.passes;
    }
  }
  if (in.searching) {
    const bool coarse_ready = !s.scans.previous_coarse.h_lines.empty() && !scan.coarse.h_lines.empty();
    st->recovered = search_.search_unmeasured(s.scans.previous, scan.features,
                                              coarse_ready ? s.scans.previous_coarse : s.scans.previous,
                                              coarse_ready ? scan.coarse : scan.features, in.prediction,
                                              in.unmeasured, frame, &outcome, st);
  }
  if (!in.first_motion)
    st->turn_recovered = search_.search_turn(s.scans.previous, scan.features, in.prediction, s.last_inlier_weight,
                                             frame, &outcome, st);
  return outcome;
}

void Odometry::correct_sweep_again(FrameFeatures* scan, const FrameInputs& in, PassOutcome* outcome,
                                   FrameStats* st) {
  // The sweep corrected again at the registered motion (sensor.deskew_iterations).
  OdometryState& s = state_;
  auto again = [&](const PassOutcome& first) {
    const ScanFeatures merged = st->window_scans > 1 ? s.scans.window.merged(st->window_scans) : ScanFeatures{};
    return lines_.register_again(st->window_scans > 1 ? merged : s.scans.previous, scan->features, in.prediction,
                                 first.best, first, st);
  };
  st->deskewed_again = s.sweeps.correct_at_registered(&scan->features, in.sweep, in.dt, &s.scans, again, outcome, st);
}

Validated Odometry::validate(FrameFeatures* scan, const FrameInputs& in,
                             const std::optional<MapAlignment>& aligned_before, PassOutcome* outcome,
                             FrameStats* st) const {
  // Do the lines pin the motion down; the point map where they do not.
  ValidationFrame check;
  check.previous = &state_.scans.previous;
  check.current = &scan->features;
  check.points = &scan->points;
  check.previous_pose = state_.point_map.place_of(state_.pose);
  check.prediction = in.prediction;
  check.unmeasured = in.unmeasured;
  check.first_motion = in.first_motion;
  check.guessed = in.guessed;
  check.rotation_guessed = in.rotation_guessed;
  if (aligned_before.has_value()) check.aligned_before = &*aligned_before;
  check.held_travel = &state_.held_travel;
  check.registration = in.registration;
  return MotionValidation(lines_).validate(check, state_.point_map, outcome, st);
}

FusedMotion Odometry::fuse(const PassOutcome& outcome, const FrameInputs& in, const Validated& validated,
                           FrameResult* result) const {
  const RegistrationOptions& reg = config_.registration;
  FrameStats& st = result->stats;
  const FusedMotion fused =
      fuse_motion(outcome, in.prediction, validated.reference, reg, !in.first_motion, in.unmeasured);
  result->delta = fused.delta;
  result->covariance = fused.covariance;
  st.registered = fused.registered;
  st.degenerate = fused.degenerate;
  st.held_directions = fused.held_directions;
  st.failure = fused.failure;
  st.solver = fused.registered ? solver_from_ransac(outcome.stats.best_solver)
                               : st.points_aligned ? Solver::kPoints : Solver::kPrediction;
  if (fused.registered && fused.held_directions == 0 && st.unobserved != 0) {
    // Directions the lines do not pin down and nothing held: flagged, with no more confidence than a held one.
    st.degenerate = true;
    st.failure = outcome.failure;
    const double ts = reg.fallback_translation_sigma, rs = reg.fallback_rotation_sigma_deg * kPi / 180.0;
    for (int k = 0; k < 6; ++k)
      if (st.unobserved >> k & 1)
        result->covariance(k, k) = std::max(result->covariance(k, k), k < 3 ? ts * ts : rs * rs);
  }
  st.inliers = outcome.stats.inliers;
  st.plane_inliers = outcome.stats.plane_inliers;
  st.inlier_weight = outcome.stats.inlier_weight;
  st.residual_rms = outcome.stats.residual_rms;
  return fused;
}

void Odometry::refine_on_points(const FrameFeatures& scan, const FusedMotion& fused, FrameResult* result) {
  // The point-to-plane refinement (points.*) of a motion registered in full.
  FrameStats& st = result->stats;
  if (!(fused.registered && fused.held_directions == 0 && !st.degenerate && points_refining() &&
        !state_.scans.previous_surface.empty()))
    return;
  Stopwatch stage;
  const PointRefineResult refined = refine_with_points(scan.surface, state_.scans.previous_surface, result->delta,
                                                       result->covariance, config_.points);
  // The lines' covariance stays: the voxels' residuals share their surfaces' errors, and their information
  // added in made KITTI 04's NEES/6 2.2 (docs/RESULTS.md, "Covariance").
  if (refined.applied) result->delta = refined.T;
  st.points_refined = refined.applied;
  st.point_matches = refined.matched;
  st.ms.points += stage.ms();
}

void Odometry::advance(const FrameFeatures& scan, const Plane* ground, const FrameInputs& in,
                       const FusedMotion& fused, const Validated& validated, FrameResult* result) {
  OdometryState& s = state_;
  const RegistrationOptions& reg = config_.registration;
  FrameStats& st = result->stats;
  const RigidTransform previous_place = s.point_map.place_of(s.pose);
  s.pose = s.pose * result->delta;
  s.pose.R = Eigen::Quaterniond(s.pose.R).normalized().toRotationMatrix();  // orthonormal over long runs
  const bool reported_good = st.registered && !st.degenerate;
  s.last_inlier_weight = reported_good ? st.inlier_weight : 0.0;
  s.prediction.record(result->delta, fused.held_projector, st.registered, in.dt, in.first_motion, in.guessed,
                      in.rotation_guessed, reg.constant_velocity, validated.measured_velocity);
  st.unmeasured_directions = static_cast<int>(std::lround(s.prediction.unmeasured_projector().trace()));
  if (validated.travel_held) s.held_travel.record(validated.points_travel);
  else s.held_travel.forget();
  // The trend of the sweeps' velocity is taken from measured velocities only: a flagged frame's motion (a direction
  // held or left open) would bend the next sweeps by its error, and their registrations would bend back further.
  if (reported_good) s.sweeps.record_motion(result->delta, in.dt);
  else s.sweeps.forget_trend();
  // The map holds scans where the scans measured them: at the frame's pose when the lines registered it in full or
  // it was held at the point map's alignment or took it (Validated::held_at_points); a frame partly held at the
  // prediction enters where its points put it, along the directions they resolve (built on at the held motion, that
  // motion would later be confirmed by itself). A sweep with point times enters only once deskewed at a known
  // velocity: before the first motion it is used as measured, smeared along the motion by up to a sweep's travel.
  const bool at_pose = (st.registered && st.held_directions == 0) || validated.held_at_points;
  if (s.point_map.enabled() && (at_pose || validated.judged) && (in.sweep == nullptr || !in.first_motion)) {
    Stopwatch stage;
    if (!at_pose) s.point_map.reanchor(s.pose, place_on_map(validated, previous_place, result->delta));
    s.point_map.add(scan.points, ground, s.pose, in.prediction, result->delta,
                    at_pose ? validated.unconfirmed_place : 0);
    st.map_entry = at_pose ? "pose" : "points";
    st.ms.validation += stage.ms();
  } else {
    s.point_map.leave_out();
  }
}

void Odometry::keep_scan(FrameFeatures* scan, const FrameResult& result) {
  OdometryState& s = state_;
  last_points_.clear();
  if (keep_points_) {
    const RangeImage& registered = *scan->input;
    for (std::size_t i = 0; i < registered.points.size(); ++i)
      if (registered.valid[i]) last_points_.push_back(registered.points[i]);
  }
  if (points_refining()) s.scans.previous_surface = std::move(scan->surface);
  if (config_.registration.window > 1)
    s.scans.window.push(scan->features, result.delta, result.stats.registered && !result.stats.degenerate);
  s.scans.previous = std::move(scan->features);
  s.scans.previous_coarse = std::move(scan->coarse);
  s.previous_stamp = result.stamp;
  ++s.frames;
}

}  // namespace line_odom
