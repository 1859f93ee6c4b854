#include "odometry/sweep_correction.hpp"

#include <algorithm>
#include <cmath>

#include "common/stopwatch.hpp"

namespace line_odom {

namespace {

// `velocity` for a sweep deskewed at `own`: a turn measured over the sweep itself (a gyro's) stays its own.
SweepVelocity keeping_measured_rate(const SweepVelocity& own, SweepVelocity velocity) {
  if (own.measured_rate) velocity.rate = own.rate, velocity.measured_rate = true;
  return velocity;
}

}  // namespace

SweepVelocity SweepCorrection::velocity_over(const RigidTransform* motion, double dt, const Vec3* sweep_rate) {
  SweepVelocity velocity;
  if (motion != nullptr && std::isfinite(dt) && dt > 0.0) velocity = SweepVelocity::over(*motion, dt);
  if (sweep_rate != nullptr) velocity.rate = *sweep_rate, velocity.measured_rate = true;
  return velocity;
}

// Both scans of a registration must be deskewed alike: deskewed at different velocities, the pair would differ by the
// change (simulated distorted sweeps: each scan at the velocity of the frame before made the error grow frame by
// frame; the pair alike: as with the true velocity, docs/RESULTS.md "Deskew"). The previous scan's features are moved
// rather than fitted again: the difference is millimetres, a rigid motion per column's time.
bool SweepCorrection::correct_previous(const SweepVelocity& velocity, ScanHistory* history) {
  if (!have_previous_) return false;
  const SweepVelocity target = keeping_measured_rate(previous_.velocity, velocity);
  if (corrected_alike(previous_.velocity, target, previous_.first, previous_.last)) return false;
  move_features(&history->previous, previous_, target);
  if (history->window.size() > 0) history->window.replace_newest(history->previous);
  previous_.velocity = target;
  return true;
}

// Before its stamp a sweep moves at the motion being registered (T_prev_curr over the stamp interval), which the
// registration knows better than the prediction it was deskewed at when the velocity changed (a turn reversed, a
// vehicle braking); after the stamp it moves at the next frame's, which no registration knows yet. So the part of a
// sweep before its stamp is compared (a sweep stamped at its start has none: iterating those did not help,
// docs/RESULTS.md, "Deskew"), and both scans of the pair are corrected alike at the registered velocity (the previous
// scan at its own registered motion fed each frame's error into the next).
bool SweepCorrection::corrected_alike(const SweepVelocity& a, const SweepVelocity& b, double first,
                                      double last) const {
  constexpr double kLever = 20.0;  // m: a point this far away stands for the scan's lines (most lie within 20 m)
  return deskew_difference(a, b, first, last, kLever) <= options_.deskew_tolerance;
}

// Two scans corrected at one velocity differ from their sweeps by the change of velocity between them (first order);
// adding the change the recent frames show leaves its change (second order). The velocity itself stays common to
// the pair: a frame's error in it moves both alike (docs/NODE.md, "Motion distortion").
SweepVelocity SweepCorrection::with_trend(SweepVelocity velocity) const {
  const int n = std::min<int>(options_.deskew_trend, static_cast<int>(registered_velocities_.size()));
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

int SweepCorrection::correct_at_registered(ScanFeatures* features, SweepTimes* sweep, double dt, ScanHistory* history,
                                           const std::function<PassOutcome(const PassOutcome&)>& register_again,
                                           PassOutcome* outcome, FrameStats* st) {
  int again = 0;
  if (!(std::isfinite(dt) && dt > 0.0) || !(sweep->first < 0.0)) return again;
  while (again < options_.deskew_iterations && registered_in_full(*outcome)) {
    const SweepVelocity registered = keeping_measured_rate(sweep->velocity, SweepVelocity::over(outcome->best, dt));
    const SweepVelocity own = with_trend(registered);
    if (corrected_alike(sweep->velocity, own, sweep->first, std::min(sweep->last, 0.0))) break;
    Stopwatch watch;
    move_features(features, *sweep, own);
    sweep->velocity = own;
    if (correct_previous(registered, history)) st->previous_deskewed_again = true;
    st->ms.deskew += watch.ms();
    ++again;
    const PassOutcome next = register_again(*outcome);
    if (!registered_in_full(next)) break;
    *outcome = next;
  }
  return again;
}

void SweepCorrection::record_motion(const RigidTransform& delta, double dt) {
  if (options_.deskew_trend <= 0 || !(std::isfinite(dt) && dt > 0.0)) return;
  registered_velocities_.push_front(SweepVelocity::over(delta, dt));
  while (static_cast<int>(registered_velocities_.size()) > options_.deskew_trend) registered_velocities_.pop_back();
}

void SweepCorrection::finish_sweep(SweepTimes sweep) {
  previous_ = std::move(sweep);
  have_previous_ = true;
}

void SweepCorrection::reset() {
  previous_ = SweepTimes{};
  have_previous_ = false;
  registered_velocities_.clear();
}

}  // namespace line_odom
