#include "odometry/odometry.hpp"

#include <Eigen/Eigenvalues>
#include <Eigen/QR>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <numeric>
#include <stdexcept>
#include <string>
#include <thread>

#include "common/splitmix64.hpp"
#include "common/stopwatch.hpp"
#include "features/line_selection.hpp"
#include "odometry/engine_settings.hpp"
#include "registration/line_pair_table.hpp"
#include "registration/refine.hpp"

namespace line_odom {

namespace {

constexpr double kHeldAxisCosine = 0.9;  // an axis this close to the held directions counts as held
constexpr double kRivalRotation = 0.5 * kPi / 180.0;  // first motions closer than this (and the inlier threshold)
                                                      // are one
constexpr double kUnmeasuredCosine = 0.5;  // a direction not measured stays so while the held directions reach within
                                           // 60 deg of it (they wobble between x and pitch on KITTI 04 at 1/64)
constexpr int kRoundsAgain = 2;
constexpr double kEvidenceLever = 20.0;  // m: a rotation's reach at the distance most of a scan's points lie within  // candidates re-associated and refined after a sweep is deskewed again

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


// The prediction turned by `R` instead of its own rotation, its translation along the same body-frame velocity: a
// constant velocity turning at rate w moves the sensor by about exp(w dt / 2) v dt, so the translation turns by the
// half-angle difference (a 10 deg/frame turn reversed: 10 deg, 0.09 m at 0.5 m a frame).
RigidTransform with_rotation(const RigidTransform& prediction, const Mat3& R) {
  const Eigen::AngleAxisd own(prediction.R), turned(R);
  const Mat3 half_own = Eigen::AngleAxisd(0.5 * own.angle(), own.axis()).toRotationMatrix();
  const Mat3 half_turned = Eigen::AngleAxisd(0.5 * turned.angle(), turned.axis()).toRotationMatrix();
  RigidTransform out;
  out.R = R;
  out.t = half_turned * half_own.transpose() * prediction.t;
  return out;
}

// `velocity` for a sweep deskewed at `own`: a turn measured over the sweep itself (a gyro's) stays its own.
SweepVelocity keeping_measured_rate(const SweepVelocity& own, SweepVelocity velocity) {
  if (own.measured_rate) velocity.rate = own.rate, velocity.measured_rate = true;
  return velocity;
}

// The orthogonal projector onto the span of the (independent) columns of `basis`.
Mat6 subspace_projector(const Eigen::Matrix<double, 6, Eigen::Dynamic>& basis) {
  if (basis.cols() == 0) return Mat6::Zero();
  const Eigen::HouseholderQR<Eigen::Matrix<double, 6, Eigen::Dynamic>> qr(basis);
  const Eigen::Matrix<double, 6, Eigen::Dynamic> q =
      qr.householderQ() * Eigen::Matrix<double, 6, Eigen::Dynamic>::Identity(6, basis.cols());
  return q * q.transpose();
}

// Independent sigmas per axis: translation (m) on x y z, rotation (rad) on rx ry rz.
Mat6 motion_covariance(double translation_sigma, double rotation_sigma) {
  Mat6 covariance = Mat6::Zero();
  const double t2 = translation_sigma * translation_sigma, r2 = rotation_sigma * rotation_sigma;
  covariance.diagonal() << t2, t2, t2, r2, r2, r2;
  return covariance;
}


const char* solver_name(int solver) {
  switch (solver) {
    case 0: return "7L";
    case 1: return "3L1P";
    case 2: return "1L2P";
    case -2: return "refine";
    default: return "none";
  }
}

std::uint64_t mix_seed(std::uint64_t seed, std::uint64_t frame, std::uint64_t pass) {
  return splitmix64_mix(seed + kSplitmix64Gamma * (frame * 16 + pass + 1));
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

bool registered_in_full(const PassOutcome& outcome) {
  return outcome.have && !outcome.stats.degenerate && outcome.held_directions == 0 &&
         outcome.stats.covariance.allFinite();
}

RigidTransform scale_motion(const RigidTransform& T, double alpha) {
  Eigen::AngleAxisd aa(T.R);
  RigidTransform out;
  out.R = Eigen::AngleAxisd(aa.angle() * alpha, aa.axis()).toRotationMatrix();
  out.t = T.t * alpha;
  return out;
}

Mat6 common_directions(const Mat6& a, const Mat6& b, double cosine) {
  Mat6 out = Mat6::Zero();
  if (a.isZero() || b.isZero()) return out;
  const Eigen::SelfAdjointEigenSolver<Mat6> es(a * b * a);
  for (int k = 0; k < 6; ++k)
    if (es.eigenvalues()(k) >= cosine * cosine)
      out += es.eigenvectors().col(k) * es.eigenvectors().col(k).transpose();
  return out;
}

Odometry::Odometry(const OdometryConfig& config) : config_(config), sensor_(make_sensor_model(config.sensor)) {
  odometry_settings().validate(config_);
  persistence_ = MotionPersistence(config_.registration.persistence_window);
  window_ = FeatureWindow(config_.registration.window);
  const EvidenceOptions& ev = config_.evidence;
  local_map_ = LocalMap(ev.map_scans, ev.map_points, ev.voxel);
  const int threads = config_.threads > 0 ? config_.threads : static_cast<int>(std::thread::hardware_concurrency());
  if (threads > 1) pool_ = std::make_shared<WorkerPool>(threads);
}

void Odometry::reset(const RigidTransform& pose) {
  pose_ = pose;
  last_delta_ = RigidTransform::identity();
  last_held_projector_ = Mat6::Zero();
  unmeasured_projector_ = Mat6::Zero();
  last_inlier_weight_ = 0.0;
  persistence_.clear();
  last_dt_ = 0.0;
  prev_stamp_ = 0.0;
  have_velocity_ = false;
  frames_ = 0;
  fit_step_ = 1;
  prev_features_ = ScanFeatures{};
  prev_coarse_features_ = ScanFeatures{};
  window_.clear();
  prev_sweep_ = SweepTimes{};
  have_prev_sweep_ = false;
  registered_velocities_.clear();
  prev_surface_ = SurfaceMap{};
  local_map_.clear();
}

RigidTransform Odometry::predict(double stamp, Vec6* persistence) const {
  *persistence = Vec6::Ones();
  if (!config_.registration.constant_velocity || !have_velocity_) return RigidTransform::identity();
  const double dt = stamp - prev_stamp_;
  double alpha = 1.0;
  if (std::isfinite(dt) && dt > 0.0 && last_dt_ > 0.0) alpha = std::clamp(dt / last_dt_, 0.0, 5.0);
  *persistence = persistence_.factors();
  if (*persistence == Vec6::Ones()) return scale_motion(last_delta_, alpha);
  // What the last frame took from its own prediction was scaled then: scaled again it would decay frame by frame
  // along a direction the lines keep not observing (a corridor), so only the measured part is scaled.
  const Vec6 last = motion_difference(last_delta_, RigidTransform::identity());
  const Vec6 held = last_held_projector_ * last;
  const Vec6 carried = persistence->cwiseProduct(last - held) + held;
  return scale_motion(apply_motion_difference(carried, RigidTransform::identity()), alpha);
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
  have_prev_sweep_ = false;
  Stopwatch watch;
  const int step = organize_step(stamp, guess != nullptr);
  const RangeImage image =
      organize_points_downsampled(data, count, stride, ring, sensor_, config_.sensor.limits, step);
  if (frames_ > 0)
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
  have_prev_sweep_ = false;
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
  if (rows == 0 && frames_ > 0)
    check_fills_rows(image, data, count, stride, config_.sensor.limits, sensor_, config_.features.lines.min_points_v);
  SweepTimes sweep;
  sweep.velocity = sweep_velocity(stamp, guess, rotation_guess, sweep_rate);
  if (count > 0) {
    const auto [first, last] = std::minmax_element(time, time + count);
    sweep.first = *first, sweep.last = *last;
  }
  sweep.column_time = column_times(image, time, std::max(1, config_.downsample / step));

  Stopwatch deskew_watch;
  const bool previous_again = have_prev_sweep_ && deskew_previous_again(sweep.velocity);
  if (sweep.velocity.moving()) sweep.velocity = with_trend(sweep.velocity);
  deskew_image(&image, time, sweep.velocity);
  const double deskew_ms = deskew_watch.ms();
  FrameResult result = register_image(image, stamp, watch.ms(), step, guess, rotation_guess, &sweep);
  result.stats.deskewed = sweep.velocity.moving();
  result.stats.previous_deskewed_again = result.stats.previous_deskewed_again || previous_again;
  result.stats.ms.deskew += deskew_ms;  // (part of organize, which register_image was given)
  prev_sweep_ = std::move(sweep);
  have_prev_sweep_ = true;
  return result;
}

SweepVelocity Odometry::sweep_velocity(double stamp, const RigidTransform* guess, const Mat3* rotation_guess,
                                      const Vec3* sweep_rate) const {
  const double dt = stamp - prev_stamp_;
  SweepVelocity velocity;
  if (frames_ > 0 && std::isfinite(dt) && dt > 0.0) {
    const bool moving = have_velocity_ && dt <= config_.registration.max_prediction_gap;
    Vec6 persistence;
    RigidTransform motion = moving ? predict(stamp, &persistence) : RigidTransform::identity();
    if (guess != nullptr) motion = *guess;
    else if (rotation_guess != nullptr) motion = with_rotation(motion, *rotation_guess);
    if (moving || guess != nullptr || rotation_guess != nullptr) velocity = SweepVelocity::over(motion, dt);
  }
  if (sweep_rate != nullptr) velocity.rate = *sweep_rate, velocity.measured_rate = true;
  return velocity;
}

// Both scans of a registration must be deskewed alike: deskewed at different velocities, the pair would differ by the
// change (simulated distorted sweeps: each scan at the velocity of the frame before made the error grow frame by
// frame, 0.003 -> 0.05 m a frame at 1/36; the pair alike: 0.0018 m, as with the true velocity). The previous scan's
// features are moved rather than fitted again: the difference is millimetres, a rigid motion per column's time.
bool Odometry::deskew_previous_again(const SweepVelocity& velocity) {
  const SweepTimes& prev = prev_sweep_;
  const SweepVelocity target = keeping_measured_rate(prev.velocity, velocity);
  if (corrected_alike(prev.velocity, target, prev.first, prev.last)) return false;
  move_features(&prev_features_, prev, target);
  if (config_.registration.window > 1) window_.replace_newest(prev_features_);
  prev_sweep_.velocity = target;
  return true;
}

// Before its stamp a sweep moves at the motion being registered (T_prev_curr over the stamp interval), which the
// registration knows better than the prediction it was deskewed at when the velocity changed (a turn reversed, a
// vehicle braking); after the stamp it moves at the next frame's, which no registration knows yet. So the part of a
// sweep before its stamp is compared (a sweep stamped at its start has none: iterating those did not help,
// docs/RESULTS.md, "Deskew"), and both scans of the pair are corrected alike at the registered velocity (the previous
// scan at its own registered motion fed each frame's error into the next).
bool Odometry::corrected_alike(const SweepVelocity& a, const SweepVelocity& b, double first, double last) const {
  constexpr double kLever = 20.0;  // m: a point this far away stands for the scan's lines (most lie within 20 m)
  return deskew_difference(a, b, first, last, kLever) <= config_.sensor.deskew_tolerance;
}

// Two scans corrected at one velocity differ from their sweeps by the change of velocity between them (first order);
// adding the change the recent frames show leaves its change (second order). The velocity itself stays common to
// the pair: a frame's error in it moves both alike (docs/NODE.md, "Motion distortion").
SweepVelocity Odometry::with_trend(SweepVelocity velocity) const {
  const int n = std::min<int>(config_.sensor.deskew_trend, static_cast<int>(registered_velocities_.size()));
  if (n < 3) return velocity;
  const double mean_age = (n - 1) / 2.0;
  Vec3 mean_rate = Vec3::Zero(), mean_speed = Vec3::Zero();
  for (int i = 0; i < n; ++i) mean_rate += registered_velocities_[i].rate, mean_speed += registered_velocities_[i].speed;
  mean_rate /= n, mean_speed /= n;
  Vec3 rate_slope = Vec3::Zero(), speed_slope = Vec3::Zero();
  double spread = 0.0;
  for (int i = 0; i < n; ++i) {
    const double x = mean_age - i;  // frames after the mean age (the newest, i = 0, is the latest)
    rate_slope += x * (registered_velocities_[i].rate - mean_rate);
    speed_slope += x * (registered_velocities_[i].speed - mean_speed);
    spread += x * x;
  }
  velocity.speed += speed_slope / spread;
  if (!velocity.measured_rate) velocity.rate += rate_slope / spread;
  return velocity;
}

int Odometry::deskew_at_registered(ScanFeatures* features, SweepTimes* sweep, double dt,
                                   const RigidTransform& prediction, PassOutcome* outcome, FrameStats* st) {
  int again = 0;
  if (!(std::isfinite(dt) && dt > 0.0) || !(sweep->first < 0.0)) return again;
  while (again < config_.sensor.deskew_iterations && registered_in_full(*outcome)) {
    const SweepVelocity registered = keeping_measured_rate(sweep->velocity, SweepVelocity::over(outcome->best, dt));
    const SweepVelocity own = with_trend(registered);
    if (corrected_alike(sweep->velocity, own, sweep->first, std::min(sweep->last, 0.0))) break;
    Stopwatch watch;
    move_features(features, *sweep, own);
    sweep->velocity = own;
    if (have_prev_sweep_ && deskew_previous_again(registered)) st->previous_deskewed_again = true;
    st->ms.deskew += watch.ms();
    ++again;
    const PassOutcome next = register_again(*features, prediction, outcome->best, *outcome, st);
    if (!registered_in_full(next)) break;
    *outcome = next;
  }
  return again;
}

PassOutcome Odometry::register_again(const ScanFeatures& cur, const RigidTransform& prediction,
                                     const RigidTransform& start, const PassOutcome& first, FrameStats* st) const {
  const ScanFeatures merged = st->window_scans > 1 ? window_.merged() : ScanFeatures{};
  const ScanFeatures& prev = st->window_scans > 1 ? merged : prev_features_;
  const RegistrationOptions& reg = config_.registration;
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

namespace {

// Translation and rotation (at kEvidenceLever) between two motions, in metres.
double motion_distance(const RigidTransform& a, const RigidTransform& b) {
  const RigidTransform d = a.inverse() * b;
  return d.t.norm() + kEvidenceLever * rotation_angle(d.R);
}

// Every `step`-th valid point of the image, at most `budget` of them.
std::vector<Vec3> spread_points(const RangeImage& image, int budget) {
  const std::size_t valid = static_cast<std::size_t>(std::count(image.valid.begin(), image.valid.end(), 1));
  const std::size_t step = std::max<std::size_t>(1, (valid + budget - 1) / std::max(1, budget));
  std::vector<Vec3> out;
  out.reserve(valid / step + 1);
  std::size_t k = 0;
  for (std::size_t i = 0; i < image.points.size(); ++i)
    if (image.valid[i] && k++ % step == 0) out.push_back(image.points[i]);
  return out;
}

// The unit translations along which `outcome` holds the prediction (its held directions), or, when it registered
// nothing, the prediction's own direction of travel and the horizontal axes of the sensor.
std::vector<Vec3> unobserved_translations(const PassOutcome& outcome, const RigidTransform& prediction) {
  std::vector<Vec3> axes;
  auto add = [&axes](const Vec3& v) {
    if (v.norm() < 0.3) return;  // mostly a rotation
    const Vec3 u = v.normalized();
    for (const Vec3& a : axes)
      if (std::abs(a.dot(u)) > 0.9) return;
    axes.push_back(u);
  };
  if (outcome.have && outcome.held_directions > 0) {
    const Eigen::SelfAdjointEigenSolver<Mat6> es(outcome.held_projector);
    for (int k = 0; k < 6; ++k)
      if (es.eigenvalues()(k) > 0.5) add(es.eigenvectors().col(k).head<3>());
  } else if (!outcome.have) {
    if (prediction.t.norm() > 1e-3) add(prediction.t);
    add(Vec3::UnitX());
    add(Vec3::UnitY());
  }
  return axes;
}

}  // namespace

// The lines' outcome is checked on evidence they did not produce: this scan's points on the local map's planes. Each
// of the lines' motion, the prediction and standing still starts a point fit (and, where the lines leave translations
// unobserved, the best-supported shift along them); the fit whose points' support gains most over the lines' motion
// (McNemar's test, support_gain) contradicts it when the gain is significant for the number of motions compared and
// the two are farther apart than the points resolve (evidence.inlier_distance). A contradicted frame keeps its
// motion and is flagged: on a sparse scan the points' fit can slide along a street as the lines' can, so it is no
// motion to take instead.
void Odometry::check_with_points(const ScanFeatures& cur, const std::vector<Vec3>& points,
                                 const RigidTransform& prediction, PassOutcome* outcome, FrameStats* st) {
  const EvidenceOptions& ev = config_.evidence;
  SurfaceMap& map = local_map_.surface();
  const RigidTransform reference_motion = outcome->have ? outcome->best : prediction;
  const PointSupport reference = point_support(map, points, reference_motion, ev);
  st->evidence_matches = reference.matched;
  st->evidence_inliers = reference.inliers;
  if (reference.matched < ev.min_matches) {
    st->evidence = "no_map";
    return;
  }

  std::vector<RigidTransform> starts{reference_motion, prediction, RigidTransform::identity()};
  const double step = 0.5 * ev.voxel;  // a fit reaches about half a voxel
  const int steps = static_cast<int>(std::floor(ev.search_range / step));
  int compared = 0;  // motions whose gain over the lines' was measured, the best of which is tested
  for (const Vec3& u : unobserved_translations(*outcome, prediction)) {
    compared += 2 * steps;
    RigidTransform best_shift = reference_motion;
    double best_gain = 0.0;
    for (int k = -steps; k <= steps; ++k) {
      if (k == 0) continue;
      RigidTransform shifted = reference_motion;
      shifted.t += (k * step) * u;
      const double gain = support_gain(points, reference, point_support(map, points, shifted, ev));
      if (gain > best_gain) best_gain = gain, best_shift = shifted;
    }
    starts.push_back(best_shift);
  }
  PointSupport best;
  double best_gain = -1e300;
  for (std::size_t i = 0; i < starts.size(); ++i) {
    bool repeated = false;
    for (std::size_t j = 0; j < i; ++j) repeated = repeated || motion_distance(starts[i], starts[j]) < 1e-6;
    if (repeated) continue;
    ++compared;
    PointSupport fit = fit_points(map, points, starts[i], ev);
    const double gain = support_gain(points, reference, fit);
    if (gain > best_gain) best_gain = gain, best = std::move(fit);
  }
  st->evidence_z = best_gain;
  // The best of `compared` gains is tested: the one-sided tail p ~ phi(z) / z divided among them (Bonferroni) raises
  // z^2 by about 2 ln(compared).
  const double threshold = std::sqrt(ev.significance * ev.significance + 2.0 * std::log(std::max(1, compared)));
  if (best_gain <= threshold || motion_distance(best.T, reference_motion) <= ev.inlier_distance) {
    st->evidence = "agrees";
    return;
  }
  char z[32];
  std::snprintf(z, sizeof z, "%.1f", best_gain);
  st->evidence = "contradicted";
  st->failure = std::string("the local map's points support another motion (McNemar z ") + z + " > " +
                std::to_string(threshold).substr(0, 4) + ", evidence.significance for the motions compared)";
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

CandidateOptions Odometry::last_pass_candidates() const {
  const RegistrationOptions& reg = config_.registration;
  CandidateOptions copt = config_.candidates;
  const double last_pass_scale = std::pow(reg.pass_distance_scale, reg.passes - 1);
  copt.max_distance *= last_pass_scale;
  copt.plane_max_distance *= last_pass_scale;
  return copt;
}

RefineOptions Odometry::refine_options() const {
  RefineOptions ropt;
  ropt.iterations = config_.ransac.refine_iterations;
  ropt.line_threshold = config_.ransac.inlier_threshold;
  ropt.plane_angle_threshold = config_.ransac.plane_angle_threshold_deg * kPi / 180.0;
  ropt.plane_distance_threshold = config_.ransac.plane_distance_threshold;
  ropt.huber_delta = config_.ransac.huber_delta > 0.0 ? config_.ransac.huber_delta : config_.ransac.inlier_threshold;
  ropt.degeneracy_threshold = config_.ransac.degeneracy_threshold;
  return ropt;
}

// registration.window: the scan registered against the last scans' lines (feature_window.hpp), kept when every
// direction of that motion is observed by the pairs with the last scan alone; else (a sparse highway, a corridor,
// where the older scans' lines make the motion along the road look observed when it is not) against the last scan.
PassOutcome Odometry::register_on_window(const ScanFeatures& cur, const RigidTransform& prediction,
                                         FrameStats* st) const {
  if (window_.size() > 1 && unmeasured_projector_.isZero()) {
    FrameStats window_stats = *st;
    PassOutcome on_window = register_features(window_.merged(), cur, prediction, prediction, true, &window_stats);
    const bool kept = on_window.have && !on_window.stats.degenerate && on_window.held_directions == 0 &&
                      observes_every_direction(prev_features_, cur, on_window.best, &window_stats);
    st->ms = window_stats.ms;
    st->iterations = window_stats.iterations;
    if (kept) {
      *st = window_stats;
      st->window_scans = static_cast<int>(window_.size());
      return on_window;
    }
  }
  return register_features(prev_features_, cur, prediction, prediction, true, st);
}

// Precise lines meet their partners under the right motion; noisy ones leave only the sample and a few chance pairs
// within the threshold, whatever motion they are fitted to. The share must be shown, not just reached: two binomial
// standard deviations above registration.min_inlier_ratio (a few dozen candidates prove little).
bool Odometry::too_few_pairs_meet(const Correspondences& corr, const LinePairTable& table, const RigidTransform& T,
                                  int* inliers) const {
  score_motion(table, T, config_.ransac.inlier_threshold, RefineOptions{}.min_line_sine, inliers);
  const double pairs = static_cast<double>(corr.lines_a.size());
  const double r = config_.registration.min_inlier_ratio;
  return pairs > 0.0 && r > 0.0 && *inliers < r * pairs + 2.0 * std::sqrt(pairs * r * (1.0 - r));
}

// The axes a push along which keeps the inliers (refine.hpp: axis_support): motions the intersections do not observe,
// however well-conditioned the coincidental pairs make J^T W J look.
int Odometry::unobserved_axes_at(const LinePairTable& table, const RigidTransform& T) const {
  const RegistrationOptions& reg = config_.registration;
  if (!(reg.max_axis_support < 1.0 || reg.max_axis_pair_support < 1.0)) return 0;
  AxisShares shares;
  axis_support(table, T, config_.ransac.inlier_threshold, RefineOptions{}.min_line_sine, nullptr, &shares);
  int axes = 0;
  for (int axis = 0; axis < 6; ++axis)
    if ((reg.max_axis_support < 1.0 && shares.weight[axis] >= reg.max_axis_support) ||
        (reg.max_axis_pair_support < 1.0 && shares.pairs[axis] >= reg.max_axis_pair_support))
      axes |= 1 << axis;
  return axes;
}

// Whether the pairs of `prev` and `cur` alone (picked under T at the last pass's candidate distance) observe every
// direction of T: a well-conditioned refinement, enough of them meeting, no axis a push along which keeps them.
bool Odometry::observes_every_direction(const ScanFeatures& prev, const ScanFeatures& cur, const RigidTransform& T,
                                        FrameStats* st) const {
  CandidateIndex index(prev);
  const LastPassFit fit = refit_last_pass(index, cur, T, st);
  Stopwatch checks;
  int inliers = 0;
  const bool observed = fit.converged && !fit.refined.degenerate &&
                        !too_few_pairs_meet(fit.corr, fit.table, T, &inliers) && unobserved_axes_at(fit.table, T) == 0;
  st->ms.ransac += checks.ms();
  return observed;
}

Odometry::LastPassFit Odometry::refit_last_pass(CandidateIndex& index, const ScanFeatures& cur,
                                                const RigidTransform& T, FrameStats* st) const {
  LastPassFit fit;
  Stopwatch stage;
  build_candidates(index, cur, T, last_pass_candidates(), &fit.corr, &fit.stats, pool_.get());
  st->ms.candidates += stage.ms();
  stage = Stopwatch();
  fit.table = LinePairTable(fit.corr);
  fit.converged = refine_motion(fit.corr, fit.table, T, refine_options(), &fit.refined);
  st->ms.ransac += stage.ms();
  return fit;
}

bool Odometry::within_reach(const RigidTransform& prediction, const RigidTransform& T) const {
  if (!T.is_finite()) return false;
  const RigidTransform deviation = prediction.inverse() * T;
  return deviation.t.norm() <= config_.registration.max_translation &&
         rotation_angle(deviation.R) <= config_.registration.max_rotation_deg * kPi / 180.0;
}

PassOutcome Odometry::register_features(const ScanFeatures& prev, const ScanFeatures& cur,
                                      const RigidTransform& prediction, const RigidTransform& start,
                                      bool limit_pairs, FrameStats* st) const {
  const RegistrationOptions& reg = config_.registration;
  Stopwatch stage;
  RigidTransform best = start;
  MotionStats best_stats;
  bool have = false;
  CandidateOptions copt = config_.candidates;
  if (!limit_pairs) copt.max_pairs_per_line = reg.first_motion_pairs_per_line;
  Correspondences corr;
  LinePairTable table;  // corr's line pairs, for the pass and the checks after the last one
  CandidateStats cstats;
  std::string failure;
  const RefineOptions ropt = refine_options();
  std::unique_ptr<CandidateIndex> prev_index;  // frame a never moves: indexed once for all passes
  RefineResult last_refined;  // the refined guess of the last pass, when it converged
  bool last_refine_converged = false;
  bool have_rival = false;
  RigidTransform rival;
  for (int pass = 0; pass < reg.passes; ++pass) {
    stage = Stopwatch();
    if (!prev_index) prev_index = std::make_unique<CandidateIndex>(prev);
    build_candidates(*prev_index, cur, best, copt, &corr, &cstats, pool_.get());
    st->ms.candidates += stage.ms();
    st->candidates = cstats.line_pairs;
    st->plane_candidates = cstats.plane_pairs;

    stage = Stopwatch();
    table = LinePairTable(corr);
    MotionOptions mopt = config_.ransac;
    mopt.seed = mix_seed(config_.seed, static_cast<std::uint64_t>(frames_), static_cast<std::uint64_t>(pass));
    // The guess itself, refined on this pass's candidates, competes with the RANSAC samples: it is scored first
    // and whichever has the larger weighted inlier count on the same candidates is kept (paper §6.3).
    // An ill-conditioned refined guess still competes: a sample must out-support it to win, or the pass fails.
    RefineResult refined;
    const bool refine_converged =
        refine_motion(corr, table, best, ropt, &refined) && within_reach(prediction, refined.T);
    const bool refined_ok = refine_converged && !refined.degenerate && refined.line_inliers >= reg.min_inliers;
    last_refined = refined;
    last_refine_converged = refine_converged;
    RigidTransform estimate;
    MotionStats ms;
    // Without a motion guess (the first motion, searched from standing still) the refined guess may sit on a
    // wrong shift that most pairs support: it must not cut the sampling short, so it only competes afterwards.
    const bool guessed = limit_pairs || have;
    bool ok = estimate_motion(corr, best, mopt, &estimate, &ms, refine_converged && guessed ? &refined.T : nullptr) &&
              within_reach(prediction, estimate) && ms.inliers >= reg.min_inliers;
    st->iterations += ms.iterations;
    const double thr = config_.ransac.inlier_threshold;
    int sample_pairs = 0, guess_pairs = 0;
    double score_ransac = ok ? score_motion(table, estimate, thr, ropt.min_line_sine, &sample_pairs) : -1.0;
    const double score_guess = refine_converged ? score_motion(table, refined.T, thr, ropt.min_line_sine, &guess_pairs)
                                                : -1.0;
    if (ok && refine_converged && guessed && ms.best_solver >= 0 &&
        sample_pairs < reg.min_sample_pair_share * guess_pairs) {
      // A sample that out-weighs the refined guess on a few heavily weighted (small) normal clusters while losing
      // the pairs of the others is a wrong motion, not a correction: a right one keeps those pairs too.
      ok = false;
      score_ransac = -1.0;
    }
    const double score_prior = have ? score_motion(table, best, thr, ropt.min_line_sine) : -1.0;
    const double score_refined = refined_ok ? score_guess : -1.0;
    if (!guessed && ok && refined_ok) {
      const bool sample_won = score_ransac > score_refined;
      rival = sample_won ? refined.T : estimate;
      const RigidTransform difference = rival.inverse() * (sample_won ? estimate : refined.T);
      have_rival = difference.t.norm() > thr || rotation_angle(difference.R) > kRivalRotation;
    }
    st->ms.ransac += stage.ms();

    copt.max_distance *= reg.pass_distance_scale;
    copt.plane_max_distance *= reg.pass_distance_scale;
    copt.max_pairs_per_line = config_.candidates.max_pairs_per_line;
    if (!ok && !refined_ok) {
      if (refine_converged && refined.degenerate && refined.line_inliers >= reg.min_inliers) {
        char condition[64];
        std::snprintf(condition, sizeof condition, "%.1e < ransac.degeneracy_threshold %.1e", refined.condition,
                      ropt.degeneracy_threshold);
        failure = "ill-conditioned constraints (" + std::to_string(refined.line_inliers) + " inliers, condition " +
                  condition + ")";
      } else {
        failure = ms.inliers < reg.min_inliers && ms.inliers > 0
                      ? "too few inliers (" + std::to_string(ms.inliers) + " < " + std::to_string(reg.min_inliers) + ")"
                      : "no model with enough support (" + std::to_string(cstats.line_pairs) + " candidates)";
      }
      continue;
    }
    // Ties go to the guess (the constant-velocity prediction carries the weakly observed directions).
    const double margin = 1.0 + reg.guess_preference;
    if (score_ransac > margin * score_refined && score_ransac > margin * score_prior) {
      best = estimate;
      best_stats = ms;
    } else if (score_refined > score_prior) {
      best = refined.T;
      copy_refinement_stats(refined, &best_stats);
      best_stats.covariance = refined.covariance;
      if (!have) best_stats.best_solver = -2;
    } else {
      continue;
    }
    have = true;
    ++st->passes;
    failure.clear();
  }

  auto too_few_meet = [&](const RigidTransform& T, int* inliers) {
    return too_few_pairs_meet(corr, table, T, inliers);
  };
  auto unobserved_axes = [&](const RigidTransform& T) { return unobserved_axes_at(table, T); };
  int inliers = 0;
  int axes = 0;
  if (have && !best_stats.degenerate) {
    if (too_few_meet(best, &inliers)) {
      best_stats.degenerate = true;
      failure = "too few candidate pairs meet (" + std::to_string(inliers) + " of " +
                std::to_string(corr.lines_a.size()) + " < registration.min_inlier_ratio)";
    } else if ((axes = unobserved_axes(best)) != 0) {
      best_stats.degenerate = true;
      failure = "unobservable motion (a push along one axis keeps the inliers)";
    }
  }

  PassOutcome out;
  // What the pairs do observe of a degenerate motion is kept, the rest follows the motion model (refine.hpp:
  // refine_motion_partial): the unobserved axes of an estimate, or the weak directions of an ill-conditioned
  // refined guess. The result must pass the same checks along the directions it does not hold.
  const RigidTransform* partial_from = nullptr;
  bool lock_weak = false;
  const bool partial = reg.partial_updates && have_velocity_;  // no velocity yet: the prediction holds nothing
  if (partial && have && best_stats.degenerate && axes != 0) {
    partial_from = &best;
  } else if (partial && !have && last_refine_converged && last_refined.line_inliers >= reg.min_inliers) {
    partial_from = &last_refined.T;
    lock_weak = true;
  }
  for (int round = 0; partial_from && round < 2; ++round) {
    RefineResult partial;
    if (!refine_motion_partial(corr, table, *partial_from, prediction, axes, lock_weak, ropt, &partial) ||
        !within_reach(prediction, partial.T) || partial.degenerate || partial.line_inliers < reg.min_inliers ||
        too_few_meet(partial.T, &inliers))
      break;
    // An unobserved axis the held directions already (nearly) contain is held; another one is held too, once.
    int uncovered = 0;
    const int unobserved = unobserved_axes(partial.T);
    for (int axis = 0; axis < 6; ++axis)
      if ((unobserved >> axis & 1) &&
          partial.locked_basis.leftCols(partial.locked_directions).row(axis).norm() < kHeldAxisCosine)
        uncovered |= 1 << axis;
    if (uncovered != 0) {
      axes |= uncovered;
      continue;
    }
    best = partial.T;
    copy_refinement_stats(partial, &best_stats);
    best_stats.covariance = partial.covariance;
    best_stats.degenerate = false;
    if (!have) best_stats.best_solver = -2;
    have = true;
    out.held_directions = partial.locked_directions;
    out.held_sensitivity = partial.held_sensitivity;
    out.held_projector = subspace_projector(partial.locked_basis.leftCols(partial.locked_directions));
    failure = "partly unobserved motion: " + std::to_string(partial.locked_directions) +
              " of 6 directions held by the motion model";
    break;
  }

  out.best = best;
  out.stats = best_stats;
  out.have = have;
  out.failure = failure;
  out.have_rival = have_rival;
  out.rival = rival;
  return out;
}

// Organize only the rows and columns downsampling keeps; while the first motion is searched at
// registration.coarse_downsample, or unmeasured directions are scanned there (coarser than the configured step), the
// rows and columns both steps need.
int Odometry::organize_step(double stamp, bool guessed) const {
  const int step = std::max(1, config_.downsample);
  const int coarse = config_.registration.coarse_downsample;
  // (the first frame's coarse features serve the next frame's first motion, guessed or not)
  const bool first_motion = (!guessed || frames_ == 0) &&
                            (!have_velocity_ || stamp - prev_stamp_ > config_.registration.max_prediction_gap);
  const bool coarse_scan = !guessed && !unmeasured_projector_.isZero() && coarse > step;
  return (first_motion || coarse_scan) && coarse > 0 && coarse != step ? std::gcd(step, coarse) : step;
}

FrameResult Odometry::register_range_image(const RangeImage& image, double stamp, double organize_ms,
                                           int organized_step, const RigidTransform* guess,
                                           const Mat3* rotation_guess) {
  return register_image(image, stamp, organize_ms, organized_step, guess, rotation_guess, nullptr);
}

FrameResult Odometry::register_image(const RangeImage& image, double stamp, double organize_ms, int organized_step,
                                     const RigidTransform* guess, const Mat3* rotation_guess, SweepTimes* sweep) {
  check_guess(guess);
  check_rotation_guess(rotation_guess, guess);
  Stopwatch total;
  FrameResult result;
  result.stamp = stamp;
  FrameStats& st = result.stats;
  st.ms.organize = organize_ms;
  if (have_velocity_ && stamp - prev_stamp_ > config_.registration.max_prediction_gap) {
    // After a pause the last motion says nothing about this one: no extrapolation, find the motion afresh.
    have_velocity_ = false;
    last_delta_ = RigidTransform::identity();
    persistence_.interrupt();
    registered_velocities_.clear();
  }
  // A guess stands for the velocity: registered from it, fused with it, degenerate directions held at it.
  const bool guessed = guess != nullptr && frames_ > 0;
  if (guessed) have_velocity_ = true;
  const bool rotation_guessed = rotation_guess != nullptr && frames_ > 0;

  Stopwatch stage;
  RangeImage sparse;
  const RangeImage* input = &image;
  if (config_.downsample > organized_step) {
    sparse = downsample(image, config_.downsample / organized_step);
    input = &sparse;
  }
  st.ms.downsample = stage.ms();
  st.points = static_cast<int>(std::count(input->valid.begin(), input->valid.end(), std::uint8_t{1}));

  stage = Stopwatch();
  FeatureStats fstats;
  ScanFeatures features =
      extract_features(*input, config_.features, &fstats, fit_step_, config_.registration.max_lines, pool_.get());
  st.ms.features = stage.ms();
  st.ms.lines = fstats.lines_ms;
  st.ms.normals = fstats.normals_ms;
  st.ms.planes = fstats.planes_ms;
  st.fit_step = fit_step_;
  st.h_lines = fstats.fitted_h_lines;
  st.v_lines = fstats.fitted_v_lines;
  st.planes = static_cast<int>(features.planes.size());
  st.line_step = fstats.line_step;
  st.registered_lines = static_cast<int>(features.h_lines.size() + features.v_lines.size());
  fit_step_ = next_fitting_step(st.h_lines + st.v_lines, fit_step_, config_.registration.max_lines);

  ScanFeatures coarse_features;
  const int coarse_step = config_.registration.coarse_downsample;
  // Unmeasured directions are searched (search_unmeasured) on the coarse scans when they are coarser.
  const bool searching = have_velocity_ && !guessed && !unmeasured_projector_.isZero();
  const bool coarse_scan = searching && coarse_step > config_.downsample && coarse_step % organized_step == 0;
  if ((!have_velocity_ && coarse_step > 0 && coarse_step != config_.downsample) || coarse_scan) {
    stage = Stopwatch();
    coarse_features =
        extract_features(downsample(image, coarse_step / organized_step), config_.features, nullptr, 1, 0, pool_.get());
    st.ms.features += stage.ms();
  }

  std::vector<Vec3> checked_points;  // this scan's, for the local map's check (evidence.*)
  if (config_.evidence.enabled) checked_points = spread_points(*input, config_.evidence.max_points);

  SurfaceMap surface;  // this scan's, for the point-to-plane refinement (points.weight)
  if (points_refining()) {
    stage = Stopwatch();
    surface.build(*input, config_.points.voxel, config_.points.stride);
    st.ms.points = stage.ms();
  }

  if (frames_ == 0) {  // first frame: it defines the odometry frame (with the reset pose)
    result.pose = pose_;
    result.delta = RigidTransform::identity();
    result.covariance = Mat6::Zero();
    st.solver = "none";
    st.registered = true;
  } else {
    const double dt = stamp - prev_stamp_;
    const bool first_motion_frame = !have_velocity_;
    const RigidTransform own_prediction = guessed ? *guess : predict(stamp, &st.persistence);
    const RigidTransform prediction =
        rotation_guessed ? with_rotation(own_prediction, *rotation_guess) : own_prediction;
    st.prediction = guessed ? "guess"
                    : have_velocity_ && config_.registration.constant_velocity ? "constant_velocity"
                                                                                : "standing_still";
    if (rotation_guessed) st.prediction += "+imu";
    const RegistrationOptions& reg = config_.registration;
    st.window_scans = 1;
    PassOutcome outcome = have_velocity_ ? register_on_window(features, prediction, &st)
                                         : search_first_motion(features, coarse_features, prediction, &st);
    if (!have_velocity_ && rotation_guessed && !registered_in_full(outcome)) {
      // A gyro's turn a little off can cost the first motion where the search from standing still finds it: KITTI 04
      // at 1/64, 0.05 deg of yaw, held at a standstill for good. So that search runs too, and is taken when it
      // registers what the gyro's did not.
      FrameStats plain_stats;
      PassOutcome plain = search_first_motion(features, coarse_features, own_prediction, &plain_stats);
      st.ms.candidates += plain_stats.ms.candidates;
      st.ms.ransac += plain_stats.ms.ransac;
      st.iterations += plain_stats.iterations;
      if (registered_in_full(plain)) {
        outcome = plain;
        st.candidates = plain_stats.candidates;
        st.plane_candidates = plain_stats.plane_candidates;
        st.passes = plain_stats.passes;
      }
    }
    if (searching) {
      const bool coarse_ready = !prev_coarse_features_.h_lines.empty() && !coarse_features.h_lines.empty();
      st.recovered = search_unmeasured(prev_features_, features, coarse_ready ? prev_coarse_features_ : prev_features_,
                                       coarse_ready ? coarse_features : features, prediction, &outcome, &st);
    }
    // (kept with a rotation guess: it starts only where the registration failed or lost support, never on the
    // yaw-flip drive with a gyro 5 deg off; a gyro turned the wrong way, 24 frames: 8.4 -> 0.23 deg mean, NODE.md)
    if (!first_motion_frame) st.turn_recovered = search_turn(prev_features_, features, prediction, &outcome, &st);
    if (sweep != nullptr) st.deskewed_again = deskew_at_registered(&features, sweep, dt, prediction, &outcome, &st);
    if (config_.evidence.enabled && !local_map_.empty()) {
      stage = Stopwatch();
      check_with_points(features, checked_points, prediction, &outcome, &st);
      st.ms.evidence += stage.ms();
    }
    const RigidTransform& best = outcome.best;
    const MotionStats& best_stats = outcome.stats;
    const bool have = outcome.have;
    std::string failure = outcome.failure;
    const double ts = reg.fallback_translation_sigma, rs = reg.fallback_rotation_sigma_deg * kPi / 180.0;
    Mat6 held_projector = Mat6::Zero();  // onto the directions of this frame's motion taken from the prediction
    if (have && !best_stats.degenerate && best_stats.covariance.allFinite()) {
      result.delta = best;
      const int constraints = std::max(1, best_stats.inliers + best_stats.plane_inliers);
      result.covariance = best_stats.covariance * (reg.covariance_per_inlier ? reg.covariance_scale * constraints
                                                                             : reg.covariance_scale);
      const double pt = reg.motion_prior_translation_sigma, pr = reg.motion_prior_rotation_sigma_deg * kPi / 180.0;
      const Mat6 prior = motion_covariance(pt, pr);
      const bool fuse_prior = have_velocity_ && pt > 0.0;
      const Vec6 xi = motion_difference(best, prediction);
      if (outcome.held_directions > 0) {
        // A partial estimate says nothing along the held directions (covariance zero there, refine.hpp): fused in
        // information form, the prior alone speaks there; then at least the fallback variance along them. They are
        // the covariance's held_directions smallest eigen-directions: their rounding residue can exceed 1e-12 of
        // the largest (KITTI 04 at 1/36, frame 8: a variance of 3.5e-16) and must not pass for information.
        Eigen::SelfAdjointEigenSolver<Mat6> es(result.covariance);
        const double lmax = std::max(es.eigenvalues()(5), 1e-300);
        Vec6 inv = Vec6::Zero();
        Mat6 held = Mat6::Zero();
        int held_count = 0;
        for (int k = 0; k < 6; ++k) {
          if (k >= outcome.held_directions && es.eigenvalues()(k) > 1e-12 * lmax) inv(k) = 1.0 / es.eigenvalues()(k);
          else held.col(held_count++) = es.eigenvectors().col(k);
        }
        const Mat6 information = es.eigenvectors() * inv.asDiagonal() * es.eigenvectors().transpose();
        held_projector = held * held.transpose();
        // The estimate's error is (I - G) e_lines + G e_prediction (G = held_sensitivity): the free directions
        // are coupled to the held ones, so the prediction's error reaches them too. Fused, K = fused P_f^-1:
        // error (I - K + K G) e_prediction + K (I - G) e_lines.
        const Mat6 prediction_covariance = fuse_prior ? prior : motion_covariance(ts, rs);
        const Mat6& G = outcome.held_sensitivity;
        Mat6 gain = Mat6::Identity();
        if (fuse_prior) {
          const Mat6 fused_covariance = (prior.inverse() + information).inverse();
          const Vec6 fused = fused_covariance * (information * xi);
          if (fused.allFinite() && fused_covariance.allFinite()) {
            result.delta = apply_motion_difference(fused, prediction);
            gain = fused_covariance * information;
          }
        }
        const Mat6 from_prediction = Mat6::Identity() - gain + gain * G;
        const Mat6 propagated = from_prediction * prediction_covariance * from_prediction.transpose() +
                                gain * result.covariance * gain.transpose();
        if (propagated.allFinite()) result.covariance = propagated;
        for (int k = 0; k < held_count; ++k) {
          const Vec6 u = held.col(k);
          const double floor = ts * ts * u.head<3>().squaredNorm() + rs * rs * u.tail<3>().squaredNorm();
          const double variance = u.dot(result.covariance * u);
          if (variance < floor) result.covariance += (floor - variance) * u * u.transpose();
        }
        result.covariance = 0.5 * (result.covariance + result.covariance.transpose());
        st.degenerate = true;
        st.held_directions = outcome.held_directions;
        st.failure = failure;
      } else if (fuse_prior) {
        // MAP fusion with the constant-velocity prior on the left perturbation exp(xi) * prediction: directions
        // the lines observe poorly (large covariance) stay with the prediction. Covariance (I - K) P of the Kalman
        // update with H = I, K = P (P + C)^-1: (P^-1 + C^-1)^-1, below both the prior's and the estimate's.
        Mat6 gain = prior * (prior + result.covariance).inverse();
        Mat6 fused_covariance = (Mat6::Identity() - gain) * prior;
        if (!unmeasured_projector_.isZero()) {
          // No prior along a velocity nobody measured (its prediction is standing still): there the estimate stands.
          const Mat6 free = Mat6::Identity() - unmeasured_projector_;
          const Mat6 information = result.covariance.inverse();
          fused_covariance = (free * prior.inverse() * free + information).inverse();
          gain = fused_covariance * information;
        }
        const Vec6 fused = gain * xi;
        if (fused.allFinite() && fused_covariance.allFinite()) {
          result.delta = apply_motion_difference(fused, prediction);
          result.covariance = 0.5 * (fused_covariance + fused_covariance.transpose());
        }
      }
      if (outcome.held_directions == 0 && points_refining() && !prev_surface_.empty()) {
        stage = Stopwatch();
        const PointRefineResult refined =
            refine_with_points(surface, prev_surface_, result.delta, result.covariance, config_.points);
        // The lines' covariance stays: the voxels' residuals share their surfaces' errors, and their information
        // added in made KITTI 04's NEES/6 2.2 (docs/RESULTS.md, "Covariance").
        if (refined.applied) result.delta = refined.T;
        st.points_refined = refined.applied;
        st.point_matches = refined.matched;
        st.ms.points += stage.ms();
      }
      st.solver = solver_name(best_stats.best_solver);
      st.registered = true;
      if (st.evidence == "contradicted") {  // flagged, with no more confidence than a held prediction
        st.degenerate = true;
        result.covariance = result.covariance.cwiseMax(motion_covariance(ts, rs));
      }
    } else {
      if (have && failure.empty()) failure = "degenerate constraints (ill-conditioned refinement)";
      result.delta = prediction;
      result.covariance = motion_covariance(ts, rs);
      if (have) result.covariance = result.covariance.cwiseMax(best_stats.covariance);
      st.solver = "prediction";
      st.degenerate = true;
      st.held_directions = 6;
      held_projector = Mat6::Identity();
      st.failure = failure.empty() ? "registration failed" : failure;
    }
    st.inliers = best_stats.inliers;
    st.plane_inliers = best_stats.plane_inliers;
    st.inlier_weight = best_stats.inlier_weight;
    st.residual_rms = best_stats.residual_rms;

    pose_ = pose_ * result.delta;
    // Keep R orthonormal over long runs.
    Eigen::Quaterniond q(pose_.R);
    pose_.R = q.normalized().toRotationMatrix();
    result.pose = pose_;
    last_delta_ = result.delta;
    last_held_projector_ = held_projector;
    last_inlier_weight_ = st.registered && !st.degenerate ? st.inlier_weight : 0.0;
    // A first motion held in full measured no direction of the velocity; a later frame measures what it registers.
    // (Without constant velocity every prediction is standing still: nothing to search; a guess is a measurement.)
    if (guessed || !reg.constant_velocity) unmeasured_projector_ = Mat6::Zero();
    else if (first_motion_frame) unmeasured_projector_ = held_projector;
    else unmeasured_projector_ = common_directions(unmeasured_projector_, held_projector, kUnmeasuredCosine);
    if (rotation_guessed && !unmeasured_projector_.isZero()) {
      // A gyro measured the rotation: only translations can stay unmeasured.
      Mat6 translations = Mat6::Zero();
      translations.topLeftCorner<3, 3>().setIdentity();
      unmeasured_projector_ = common_directions(unmeasured_projector_, translations, kUnmeasuredCosine);
    }
    st.unmeasured_directions = static_cast<int>(std::lround(unmeasured_projector_.trace()));
    if (st.registered)
      persistence_.add(motion_difference(result.delta, RigidTransform::identity()), dt);
    else
      persistence_.interrupt();
    last_dt_ = (std::isfinite(dt) && dt > 0.0) ? dt : last_dt_;
    if (config_.sensor.deskew_trend > 0 && std::isfinite(dt) && dt > 0.0) {
      registered_velocities_.push_front(SweepVelocity::over(result.delta, dt));
      while (static_cast<int>(registered_velocities_.size()) > config_.sensor.deskew_trend)
        registered_velocities_.pop_back();
    }
    have_velocity_ = true;
  }

  if (config_.evidence.enabled) {
    stage = Stopwatch();
    if (st.registered && !st.degenerate) local_map_.add(spread_points(*input, config_.evidence.map_points), pose_);
    else if (!local_map_.empty()) local_map_.anchor(pose_);
    st.ms.evidence += stage.ms();
  }
  if (points_refining()) prev_surface_ = std::move(surface);
  if (config_.registration.window > 1) window_.push(features, result.delta, st.registered && !st.degenerate);
  prev_features_ = std::move(features);
  prev_coarse_features_ = std::move(coarse_features);
  prev_stamp_ = stamp;
  ++frames_;
  st.ms.total = total.ms() + organize_ms;
  return result;
}

}  // namespace line_odom
