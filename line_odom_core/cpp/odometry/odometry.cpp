#include "odometry/odometry.hpp"

#include <algorithm>
#include <cmath>
#include <numeric>
#include <stdexcept>
#include <string>
#include <thread>

#include "common/stopwatch.hpp"
#include "odometry/engine_settings.hpp"

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
                      const std::int32_t* ring, const RangeLimits& limits, const SensorModel& sensor,
                      int min_points_v) {
  int rows = 0;
  for (int r = 0; r < image.rows; ++r)
    for (int c = 0; c < image.cols; ++c)
      if (image.is_valid(r, c)) {
        ++rows;
        break;
      }
  if (rows >= min_points_v || (rows == 0 && !any_in_range(data, count, stride, limits))) return;
  // A ring field holding one value (a converter that fills it with 0) puts a whole cloud in one row.
  const std::string named =
      ring != nullptr ? "ring: the ring field puts the cloud's points in " : "xyz: the cloud's points fill ";
  const std::string hint = ring != nullptr ? " (a ring field of one value, or a 2D laser? Without the ring field the "
                                             "rows come from the points' elevations)"
                                           : " (a 2D laser or another sensor's cloud?)";
  throw std::invalid_argument(named + std::to_string(rows) + " of the " + std::to_string(image.rows) +
                              " rows the sensor model '" + sensor.name +
                              "' keeps of it; a scan needs points in at least lines.min_points_v = " +
                              std::to_string(min_points_v) + " rows" + hint);
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
  check_fills_rows(image, data, count, stride, ring, config_.sensor.limits, sensor_,
                   config_.features.lines.min_points_v);
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
  if (rows == 0)
    check_fills_rows(image, data, count, stride, ring, config_.sensor.limits, sensor_,
                     config_.features.lines.min_points_v);
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
    const ScanFeatures merged = scans.window.merged(window_scans);
    CandidateIndex window_index(merged);
    PassOutcome on_window =
        lines_.register_features(window_index, cur, prediction, start, true, frame, &window_stats);
    // The window's newest scan is the last scan (merged first): its pairs from the window's index and its listings.
    const CandidateSubset last_scan{scans.previous.h_lines.size(), scans.previous.v_lines.size(),
                                    scans.previous.planes.size()};
    const bool kept = on_window.have && !on_window.stats.degenerate && on_window.held_directions == 0 &&
                      lines_.observes_every_direction(window_index, last_scan, cur, on_window.best, &window_stats);
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
  check_guess(guess);
  check_rotation_guess(rotation_guess, guess);
  return register_image(image, stamp, organize_ms, organized_step, guess, rotation_guess, nullptr);
}

}  // namespace line_odom
