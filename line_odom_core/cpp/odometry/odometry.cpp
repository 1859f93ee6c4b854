#include "odometry/odometry.hpp"

#include <Eigen/Geometry>

#include <algorithm>
#include <cmath>
#include <numeric>
#include <stdexcept>
#include <string>
#include <thread>

#include "common/stopwatch.hpp"
#include "features/line_selection.hpp"
#include "features/scan_directions.hpp"
#include "odometry/engine_settings.hpp"
#include "odometry/frame_features.hpp"
#include "odometry/motion_fusion.hpp"
#include "odometry/motion_validation.hpp"
#include "registration/point_refine.hpp"

namespace line_odom {

namespace {

// The caller's motion guess: finite, with an orthonormal rotation of determinant +1.
// A finite orthonormal matrix with determinant +1.
bool is_rotation(const Mat3& R) {
  return R.allFinite() && (R.transpose() * R - Mat3::Identity()).cwiseAbs().maxCoeff() < 1e-6 && R.determinant() > 0.0;
}

void check_guess(const RigidTransform* guess) {
  if (guess == nullptr) return;
  if (!(guess->t.allFinite() && is_rotation(guess->R)))
    throw std::invalid_argument("guess: expected a finite rigid transform T_prev_curr (orthonormal rotation, "
                                "determinant +1)");
}

// The caller's rotation guess (a gyro's R_prev_curr): finite, orthonormal, determinant +1; not beside a full guess.
void check_rotation_guess(const Mat3* rotation_guess, const RigidTransform* guess) {
  if (rotation_guess == nullptr) return;
  if (guess != nullptr)
    throw std::invalid_argument("rotation_guess: expected no guess beside it (guess replaces the whole prediction, "
                                "rotation_guess only its rotation); pass one of them");
  if (!is_rotation(*rotation_guess))
    throw std::invalid_argument("rotation_guess: expected a finite rotation matrix R_prev_curr (orthonormal, "
                                "determinant +1)");
}


// Whether any point of the cloud is finite and within the range limits.
template <typename Scalar>
bool any_in_range(const Scalar* data, std::size_t count, std::size_t stride, const RangeLimits& limits) {
  for (std::size_t i = 0; i < count; ++i) {
    const Vec3 p(data[i * stride], data[i * stride + 1], data[i * stride + 2]);
    const double r = p.norm();
    if (std::isfinite(r) && r >= limits.min_range && r <= limits.max_range) return true;
  }
  return false;
}

// A scan the sensor model organizes into fewer rows than a V-line needs points (a 2D laser's single ring, a cloud of
// another sensor; also one whose points all lie in rows the downsampling drops) cannot be registered: refused at any
// frame before it touches the odometry's state. A scan with no point in range is held as a failed registration.
template <typename Scalar>
void check_fills_rows(const RangeImage& image, const Scalar* data, std::size_t count, std::size_t stride,
                      const RangeLimits& limits, const SensorModel& sensor, int min_points_v) {
  int rows = 0;
  for (int r = 0; r < image.rows; ++r)
    for (int c = 0; c < image.cols; ++c)
      if (image.is_valid(r, c)) {
        ++rows;
        break;
      }
  if (rows >= min_points_v || (rows == 0 && !any_in_range(data, count, stride, limits))) return;
  throw std::invalid_argument("xyz: the cloud's points fill " + std::to_string(rows) + " of the " +
                              std::to_string(image.rows) + " rows the sensor model '" + sensor.name +
                              "' keeps of it; a scan needs points in at least lines.min_points_v = " +
                              std::to_string(min_points_v) + " rows (a 2D laser or another sensor's cloud?)");
}


}  // namespace

const char* solver_name(Solver solver) {
  switch (solver) {
    case Solver::k7L: return "7L";
    case Solver::k3L1P: return "3L1P";
    case Solver::k1L2P: return "1L2P";
    case Solver::kRefinedGuess: return "refine";
    case Solver::kPoints: return "points";
    case Solver::kPrediction: return "prediction";
    case Solver::kNone: break;
  }
  return "none";
}

Solver solver_from_ransac(int best_solver) {
  switch (best_solver) {
    case 0: return Solver::k7L;
    case 1: return Solver::k3L1P;
    case 2: return Solver::k1L2P;
    case -2: return Solver::kRefinedGuess;
    default: return Solver::kNone;
  }
}

namespace {

std::shared_ptr<WorkerPool> make_pool(const OdometryConfig& config) {
  const int threads = config.threads > 0 ? config.threads : static_cast<int>(std::thread::hardware_concurrency());
  return threads > 1 ? std::make_shared<WorkerPool>(threads) : nullptr;
}

const OdometryConfig& validated(const OdometryConfig& config) {
  odometry_settings().validate(config);
  return config;
}

}  // namespace

Odometry::Odometry(const OdometryConfig& config)
    : config_(validated(config)),
      sensor_(make_sensor_model(config_.sensor)),
      pool_(make_pool(config_)),
      lines_(config_, pool_.get()),
      search_(lines_),
      state_(config_) {}

void Odometry::reset(const RigidTransform& pose) {
  state_.pose = pose;
  state_.previous_stamp = 0.0;
  state_.frames = 0;
  state_.last_inlier_weight = 0.0;
  state_.prediction.reset();
  state_.scans.clear();
  state_.sweeps.reset();
  state_.point_map.reset();
}

RegistrationFrame Odometry::registration_frame() const {
  return {static_cast<std::uint64_t>(state_.frames), state_.prediction.have_velocity()};
}

SensorModel make_sensor_model(const SensorOptions& options) {
  SensorModel model;
  if (options.model == "uniform") {
    if (options.rows < 2 || options.max_elevation_deg <= options.min_elevation_deg)
      throw std::invalid_argument("sensor: a uniform model needs rows >= 2 and max_elevation_deg > min_elevation_deg");
    model.name = "uniform";
    model.rows = options.rows;
    model.cols = 2048;
    model.max_elevation = options.max_elevation_deg * kPi / 180.0;
    model.min_elevation = options.min_elevation_deg * kPi / 180.0;
  } else {
    model = sensor_preset(options.model);
  }
  if (options.cols > 0) model.cols = options.cols;
  return model;
}


template <typename Scalar>
FrameResult Odometry::register_points(const Scalar* data, std::size_t count, std::size_t stride,
                                      const std::int32_t* ring, double stamp, const RigidTransform* guess,
                                      const Mat3* rotation_guess, const double* time, const Vec3* sweep_rate) {
  if (time != nullptr && config_.sensor.deskew)
    return register_sweep(data, count, stride, ring, 0, 0, stamp, guess, rotation_guess, time, sweep_rate);
  check_rotation_guess(rotation_guess, guess);
  state_.sweeps.no_sweep();
  Stopwatch watch;
  const int step = organize_step(stamp, guess != nullptr);
  const RangeImage image =
      organize_points_downsampled(data, count, stride, ring, sensor_, config_.sensor.limits, step);
  if (state_.frames > 0)
    check_fills_rows(image, data, count, stride, config_.sensor.limits, sensor_, config_.features.lines.min_points_v);
  return register_range_image(image, stamp, watch.ms(), step, guess, rotation_guess);
}

template <typename Scalar>
FrameResult Odometry::register_organized(const Scalar* data, int rows, int cols, std::size_t stride, double stamp,
                                         const RigidTransform* guess, const Mat3* rotation_guess,
                                         const double* time, const Vec3* sweep_rate) {
  if (time != nullptr && config_.sensor.deskew) {
    if (rows < 0 || cols < 0) throw std::invalid_argument("xyz: expected a non-negative number of rows and columns");
    return register_sweep(data, static_cast<std::size_t>(rows) * static_cast<std::size_t>(cols), stride, nullptr,
                          rows, cols, stamp, guess, rotation_guess, time, sweep_rate);
  }
  check_rotation_guess(rotation_guess, guess);
  state_.sweeps.no_sweep();
  Stopwatch watch;
  const RangeImage image = organize_cloud(data, rows, cols, stride, config_.sensor.limits);
  return register_range_image(image, stamp, watch.ms(), 1, guess, rotation_guess);
}

template <typename Scalar>
FrameResult Odometry::register_sweep(const Scalar* data, std::size_t count, std::size_t stride,
                                     const std::int32_t* ring, int rows, int cols, double stamp,
                                     const RigidTransform* guess, const Mat3* rotation_guess, const double* time,
                                     const Vec3* sweep_rate) {
  Stopwatch watch;
  check_guess(guess);  // (before the previous scan is touched)
  check_rotation_guess(rotation_guess, guess);
  if (sweep_rate != nullptr && !(sweep_rate->allFinite() && sweep_rate->norm() < 100.0))
    throw std::invalid_argument("sweep_rate: expected the sensor's finite angular velocity during the sweep (rad/s, "
                                "under 100)");
  constexpr double kLongestSweep = 10.0;  // s: a sweep's times, not clock times (line_odom.convert.sweep_times)
  for (std::size_t i = 0; i < count; ++i)
    if (!(std::abs(time[i]) <= kLongestSweep))
      throw std::invalid_argument("time: expected finite seconds within 10 s of the stamp for every point, got " +
                                  std::to_string(time[i]) + " at point " + std::to_string(i));
  const int step = rows > 0 ? 1 : organize_step(stamp, guess != nullptr);
  RangeImage image = rows > 0 ? organize_cloud(data, rows, cols, stride, config_.sensor.limits)
                              : organize_points_downsampled(data, count, stride, ring, sensor_, config_.sensor.limits,
                                                            step);
  if (rows == 0 && state_.frames > 0)
    check_fills_rows(image, data, count, stride, config_.sensor.limits, sensor_, config_.features.lines.min_points_v);
  SweepTimes sweep;
  sweep.velocity = sweep_velocity(stamp, guess, rotation_guess, sweep_rate);
  if (count > 0) {
    const auto [first, last] = std::minmax_element(time, time + count);
    sweep.first = *first, sweep.last = *last;
  }
  sweep.column_time = column_times(image, time, std::max(1, config_.downsample / step));

  Stopwatch deskew_watch;
  const bool previous_again = state_.sweeps.correct_previous(sweep.velocity, &state_.scans);
  if (sweep.velocity.moving()) sweep.velocity = state_.sweeps.with_trend(sweep.velocity);
  deskew_image(&image, time, sweep.velocity);
  const double deskew_ms = deskew_watch.ms();
  FrameResult result = register_image(image, stamp, watch.ms(), step, guess, rotation_guess, &sweep);
  result.stats.deskewed = sweep.velocity.moving();
  result.stats.previous_deskewed_again = result.stats.previous_deskewed_again || previous_again;
  result.stats.ms.deskew += deskew_ms;  // (part of organize, which register_image was given)
  state_.sweeps.finish_sweep(std::move(sweep));
  return result;
}

SweepVelocity Odometry::sweep_velocity(double stamp, const RigidTransform* guess, const Mat3* rotation_guess,
                                      const Vec3* sweep_rate) const {
  const double dt = stamp - state_.previous_stamp;
  if (state_.frames == 0 || !(std::isfinite(dt) && dt > 0.0))
    return SweepCorrection::velocity_over(nullptr, dt, sweep_rate);
  const bool moving = state_.prediction.have_velocity() && dt <= config_.registration.max_prediction_gap;
  Vec6 persistence;
  RigidTransform motion = moving ? state_.prediction.predict(dt, config_.registration.constant_velocity, &persistence)
                                 : RigidTransform::identity();
  if (guess != nullptr) motion = *guess;
  else if (rotation_guess != nullptr) motion = with_rotation(motion, *rotation_guess);
  const bool known = moving || guess != nullptr || rotation_guess != nullptr;
  return SweepCorrection::velocity_over(known ? &motion : nullptr, dt, sweep_rate);
}

// registration.window: the scan registered against the last scans' lines (feature_window.hpp), kept when every
// direction of that motion is observed by the pairs with the last scan alone; else (a sparse highway, a corridor,
// where the older scans' lines make the motion along the road look observed when it is not) against the last scan.
PassOutcome Odometry::register_on_window(const ScanFeatures& cur, const RigidTransform& prediction,
                                         const RigidTransform& start, const RegistrationFrame& frame,
                                         FrameStats* st) const {
  const ScanHistory& scans = state_.scans;
  const std::size_t window_scans = scans.window.scans_within(config_.registration.max_lines);
  if (window_scans > 1 && state_.prediction.unmeasured_projector().isZero()) {
    FrameStats window_stats = *st;
    PassOutcome on_window = lines_.register_features(scans.window.merged(window_scans), cur, prediction, start, true,
                                                     frame, &window_stats);
    const bool kept = on_window.have && !on_window.stats.degenerate && on_window.held_directions == 0 &&
                      lines_.observes_every_direction(scans.previous, cur, on_window.best, &window_stats);
    st->ms = window_stats.ms;
    st->iterations = window_stats.iterations;
    if (kept) {
      *st = window_stats;
      st->window_scans = static_cast<int>(window_scans);
      return on_window;
    }
  }
  return lines_.register_features(scans.previous, cur, prediction, start, true, frame, st);
}

FrameResult Odometry::register_depth(const float* depth, int rows, int cols, const Mat3& K, double stamp,
                                     const RigidTransform* guess, const Mat3* rotation_guess) {
  check_rotation_guess(rotation_guess, guess);
  Stopwatch watch;
  const int step = organize_step(stamp, guess != nullptr);
  const RangeImage image = organize_depth_downsampled(depth, rows, cols, K, config_.sensor.limits, step);
  return register_range_image(image, stamp, watch.ms(), step, guess, rotation_guess);
}

template <typename Scalar>
std::vector<Vec3> Odometry::downsampled_points(const Scalar* data, std::size_t count, std::size_t stride,
                                               const std::int32_t* ring) const {
  const RangeImage image = downsample(organize_points(data, count, stride, ring, sensor_, config_.sensor.limits),
                                      std::max(1, config_.downsample));
  std::vector<Vec3> out;
  for (std::size_t i = 0; i < image.points.size(); ++i)
    if (image.valid[i]) out.push_back(image.points[i]);
  return out;
}

template FrameResult Odometry::register_points(const float*, std::size_t, std::size_t, const std::int32_t*, double,
                                               const RigidTransform*, const Mat3*, const double*, const Vec3*);
template FrameResult Odometry::register_points(const double*, std::size_t, std::size_t, const std::int32_t*, double,
                                               const RigidTransform*, const Mat3*, const double*, const Vec3*);
template FrameResult Odometry::register_organized(const float*, int, int, std::size_t, double, const RigidTransform*,
                                                  const Mat3*, const double*, const Vec3*);
template FrameResult Odometry::register_organized(const double*, int, int, std::size_t, double, const RigidTransform*,
                                                  const Mat3*, const double*, const Vec3*);
template std::vector<Vec3> Odometry::downsampled_points(const float*, std::size_t, std::size_t,
                                                        const std::int32_t*) const;
template std::vector<Vec3> Odometry::downsampled_points(const double*, std::size_t, std::size_t,
                                                        const std::int32_t*) const;


// Organize only the rows and columns downsampling keeps; while the first motion is searched at
// registration.coarse_downsample, or unmeasured directions are scanned there (coarser than the configured step), the
// rows and columns both steps need.
int Odometry::organize_step(double stamp, bool guessed) const {
  const int step = std::max(1, config_.downsample);
  const int coarse = config_.registration.coarse_downsample;
  // (the first frame's coarse features serve the next frame's first motion, guessed or not)
  const bool first_motion = (!guessed || state_.frames == 0) &&
                            (!state_.prediction.have_velocity() ||
                             stamp - state_.previous_stamp > config_.registration.max_prediction_gap);
  const bool coarse_scan = !guessed && !state_.prediction.unmeasured_projector().isZero() && coarse > step;
  return (first_motion || coarse_scan) && coarse > 0 && coarse != step ? std::gcd(step, coarse) : step;
}

FrameResult Odometry::register_range_image(const RangeImage& image, double stamp, double organize_ms,
                                           int organized_step, const RigidTransform* guess,
                                           const Mat3* rotation_guess) {
  return register_image(image, stamp, organize_ms, organized_step, guess, rotation_guess, nullptr);
}


namespace {

// Adds the candidate and RANSAC times and hypotheses of a registration made aside into the frame's.
void add_times(const FrameStats& aside, FrameStats* st) {
  st->ms.candidates += aside.ms.candidates;
  st->ms.ransac += aside.ms.ransac;
  st->iterations += aside.iterations;
}

}  // namespace

FrameResult Odometry::register_image(const RangeImage& image, double stamp, double organize_ms, int organized_step,
                                     const RigidTransform* guess, const Mat3* rotation_guess, SweepTimes* sweep) {
  check_guess(guess);
  check_rotation_guess(rotation_guess, guess);
  Stopwatch total;
  FrameResult result;
  result.stamp = stamp;
  FrameStats& st = result.stats;
  st.ms.organize = organize_ms;
  OdometryState& s = state_;
  const RegistrationOptions& reg = config_.registration;
  const double dt = stamp - s.previous_stamp;
  if (s.prediction.have_velocity() && dt > reg.max_prediction_gap) {
    // After a pause the last motion says nothing about this one: no extrapolation, find the motion afresh.
    s.prediction.drop_velocity();
    s.sweeps.forget_trend();
  }
  // A guess stands for the velocity: registered from it, fused with it, degenerate directions held at it.
  const bool guessed = guess != nullptr && s.frames > 0;
  if (guessed) s.prediction.set_have_velocity();
  const bool rotation_guessed = rotation_guess != nullptr && s.frames > 0;
  const bool first_motion = !s.prediction.have_velocity();
  const Mat6 unmeasured = s.prediction.unmeasured_projector();
  // Unmeasured directions are searched on the coarse scans when they are coarser (search_unmeasured).
  const bool searching = !first_motion && !guessed && !unmeasured.isZero();
  const int coarse_step = reg.coarse_downsample;
  const bool coarse_scan = searching && coarse_step > config_.downsample && coarse_step % organized_step == 0;

  // 1. Features.
  FrameFeatures scan;
  FeatureRequest request;
  request.organized_step = organized_step;
  request.fit_step = s.scans.fit_step;
  request.coarse = (first_motion && coarse_step > 0 && coarse_step != config_.downsample) || coarse_scan;
  request.surface = points_refining();
  request.points = s.point_map.enabled();
  extract_frame_features(image, config_, request, pool_.get(), &scan, &st);
  Plane scan_ground;  // the point map takes its points on it as the ground's plane (VoxelPointMap::plane)
  const Plane* ground = ground_plane(scan.features, &scan_ground) ? &scan_ground : nullptr;
  s.scans.fit_step = next_fitting_step(st.h_lines + st.v_lines, s.scans.fit_step, reg.max_lines);

  if (s.frames == 0) {  // first frame: it defines the odometry frame (with the reset pose)
    result.pose = s.pose;
    st.registered = true;
  } else {
    // 2. Prediction.
    const RigidTransform own_prediction =
        guessed ? *guess : s.prediction.predict(dt, reg.constant_velocity, &st.persistence);
    const RigidTransform prediction =
        rotation_guessed ? with_rotation(own_prediction, *rotation_guess) : own_prediction;
    st.prediction = guessed ? "guess" : !first_motion && reg.constant_velocity ? "constant_velocity" : "standing_still";
    if (rotation_guessed) st.prediction += "+imu";

    // 3. The lines' registration (paper §6.3), searched beyond the prediction's reach where it cannot reach.
    // A scan dense enough for the points' refinement (points.max_downsample) starts the lines at its points'
    // alignment to the map: from the prediction, the candidates picked near it can hold the lines at its turn rate
    // where the car turns into a bend (the lines' pairs near the old heading out-support the right ones). The
    // validation reads the same alignment.
    const RegistrationFrame frame = registration_frame();
    st.window_scans = 1;
    MapAlignment aligned_before;
    const bool align_first = !first_motion && !guessed && points_refining() && s.point_map.enabled() &&
                             s.point_map.holds_last_scan() && config_.validation.enabled;
    if (align_first) {
      Stopwatch stage;
      aligned_before.aligned =
          s.point_map.align(scan.points, s.point_map.place_of(s.pose), prediction, &aligned_before.motion,
                            &aligned_before.matched, &aligned_before.covariance);
      st.ms.validation += stage.ms();
    }
    PassOutcome outcome =
        first_motion ? search_.search_first_motion(s.scans.previous, s.scans.previous_coarse, scan.features,
                                                   scan.coarse, prediction, frame, &st)
                     : register_on_window(scan.features, prediction,
                                          aligned_before.aligned ? aligned_before.motion : prediction, frame, &st);
    if (first_motion && rotation_guessed && !registered_in_full(outcome)) {
      // A gyro's turn a little off can cost the first motion where the search from standing still finds it (KITTI 04
      // at 1/64, 0.05 deg of yaw, held at a standstill for good): that search runs too, and is taken when it registers
      // what the gyro's did not.
      FrameStats plain_stats;
      PassOutcome plain = search_.search_first_motion(s.scans.previous, s.scans.previous_coarse, scan.features,
                                                      scan.coarse, own_prediction, frame, &plain_stats);
      add_times(plain_stats, &st);
      if (registered_in_full(plain)) {
        outcome = plain;
        st.candidates = plain_stats.candidates;
        st.plane_candidates = plain_stats.plane_candidates;
        st.passes = plain_stats.passes;
      }
    }
    if (searching) {
      const bool coarse_ready = !s.scans.previous_coarse.h_lines.empty() && !scan.coarse.h_lines.empty();
      st.recovered = search_.search_unmeasured(s.scans.previous, scan.features,
                                               coarse_ready ? s.scans.previous_coarse : s.scans.previous,
                                               coarse_ready ? scan.coarse : scan.features, prediction, unmeasured,
                                               frame, &outcome, &st);
    }
    if (!first_motion)
      st.turn_recovered =
          search_.search_turn(s.scans.previous, scan.features, prediction, s.last_inlier_weight, frame, &outcome, &st);

    // 4. The sweep corrected again at the registered motion (sensor.deskew_iterations).
    if (sweep != nullptr) {
      auto again = [&](const PassOutcome& first) {
        const ScanFeatures merged = st.window_scans > 1 ? s.scans.window.merged(st.window_scans) : ScanFeatures{};
        return lines_.register_again(st.window_scans > 1 ? merged : s.scans.previous, scan.features, prediction,
                                     first.best, first, &st);
      };
      st.deskewed_again = s.sweeps.correct_at_registered(&scan.features, sweep, dt, &s.scans, again, &outcome, &st);
    }

    // 5. Validation: do the lines pin the motion down; the point map where they do not.
    ValidationFrame check;
    check.previous = &s.scans.previous;
    check.current = &scan.features;
    check.points = &scan.points;
    check.previous_pose = s.point_map.place_of(s.pose);
    check.prediction = prediction;
    check.unmeasured = unmeasured;
    check.first_motion = first_motion;
    check.guessed = guessed;
    check.rotation_guessed = rotation_guessed;
    if (align_first && sweep == nullptr) check.aligned_before = &aligned_before;  // points not deskewed again since
    check.registration = frame;
    const Validated validated = MotionValidation(lines_).validate(check, s.point_map, &outcome, &st);

    // 6. Fusion with the motion model.
    const FusedMotion fused = fuse_motion(outcome, prediction, validated.reference, reg, !first_motion, unmeasured);
    result.delta = fused.delta;
    result.covariance = fused.covariance;
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
        if (st.unobserved >> k & 1) result.covariance(k, k) = std::max(result.covariance(k, k), k < 3 ? ts * ts : rs * rs);
    }

    // 7. The point-to-plane refinement (points.*) of a motion registered in full.
    if (fused.registered && fused.held_directions == 0 && !st.degenerate && points_refining() &&
        !s.scans.previous_surface.empty()) {
      Stopwatch stage;
      const PointRefineResult refined = refine_with_points(scan.surface, s.scans.previous_surface, result.delta,
                                                           result.covariance, config_.points);
      // The lines' covariance stays: the voxels' residuals share their surfaces' errors, and their information
      // added in made KITTI 04's NEES/6 2.2 (docs/RESULTS.md, "Covariance").
      if (refined.applied) result.delta = refined.T;
      st.points_refined = refined.applied;
      st.point_matches = refined.matched;
      st.ms.points += stage.ms();
    }
    st.inliers = outcome.stats.inliers;
    st.plane_inliers = outcome.stats.plane_inliers;
    st.inlier_weight = outcome.stats.inlier_weight;
    st.residual_rms = outcome.stats.residual_rms;

    // 8. The pose, and what the next frame predicts from.
    s.pose = s.pose * result.delta;
    s.pose.R = Eigen::Quaterniond(s.pose.R).normalized().toRotationMatrix();  // orthonormal over long runs
    s.last_inlier_weight = st.registered && !st.degenerate ? st.inlier_weight : 0.0;
    s.prediction.record(result.delta, fused.held_projector, st.registered, dt, first_motion, guessed, rotation_guessed,
                        reg.constant_velocity, validated.measured_velocity);
    st.unmeasured_directions = static_cast<int>(std::lround(s.prediction.unmeasured_projector().trace()));
    s.sweeps.record_motion(result.delta, dt);
    // The map holds scans where the scans measured them: at the frame's pose when the lines registered it in full or
    // it was held at the point map's alignment or took it (Validated::held_at_points); a frame partly held at the
    // prediction enters where its points put it, along the directions they resolve (built on at the held motion, that
    // motion would later be confirmed by itself). A sweep with point times enters only once deskewed at a known
    // velocity: before the first motion it is used as measured, smeared along the motion by up to a sweep's travel.
    const bool at_pose = (st.registered && st.held_directions == 0) || validated.held_at_points;
    if (s.point_map.enabled() && (at_pose || validated.judged) && (sweep == nullptr || !first_motion)) {
      Stopwatch stage;
      if (!at_pose) s.point_map.reanchor(s.pose, place_on_map(validated, check.previous_pose, result.delta));
      s.point_map.add(scan.points, ground, s.pose, prediction, result.delta);
      st.map_entry = at_pose ? "pose" : "points";
      st.ms.validation += stage.ms();
    } else {
      s.point_map.leave_out();
    }
  }
  if (s.frames == 0) {
    if (sweep == nullptr && s.point_map.enabled()) {
      s.point_map.add(scan.points, ground, s.pose, {}, {});
      st.map_entry = "pose";
    }
  }
  result.pose = s.pose;

  last_points_.clear();
  if (keep_points_) {
    const RangeImage& registered = *scan.input;
    for (std::size_t i = 0; i < registered.points.size(); ++i)
      if (registered.valid[i]) last_points_.push_back(registered.points[i]);
  }
  if (points_refining()) s.scans.previous_surface = std::move(scan.surface);
  if (reg.window > 1) s.scans.window.push(scan.features, result.delta, st.registered && !st.degenerate);
  s.scans.previous = std::move(scan.features);
  s.scans.previous_coarse = std::move(scan.coarse);
  s.previous_stamp = stamp;
  ++s.frames;
  st.ms.total = total.ms() + organize_ms;
  return result;
}

}  // namespace line_odom
