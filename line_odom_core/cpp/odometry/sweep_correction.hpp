// Sweeps measured while the sensor moved, corrected alike on both scans of a registration (deskew.hpp): at the
// predicted velocity plus the trend of the last registered ones, and again at the registered motion. Its own state:
// the previous sweep's times and the velocity it was corrected at, and the last registered velocities.
#pragma once

#include <deque>
#include <functional>

#include "odometry/frame_result.hpp"
#include "odometry/line_registration.hpp"
#include "odometry/odometry_config.hpp"
#include "odometry/scan_history.hpp"
#include "scan/deskew.hpp"

namespace line_odom {

class SweepCorrection {
 public:
  explicit SweepCorrection(const SensorOptions& options) : options_(options) {}

  // The velocity a sweep is corrected at: `motion` (the prediction, the guess or the gyro's turn) over `dt`, standing
  // still when null; turning at `sweep_rate` when given (a gyro's over this sweep).
  static SweepVelocity velocity_over(const RigidTransform* motion, double dt, const Vec3* sweep_rate);
  // `velocity` plus how much faster this sweep moves than the previous one: the least-squares slope per frame of the
  // last sensor.deskew_trend registered velocities; the rate's only when it is not a gyro's over the sweep.
  SweepVelocity with_trend(SweepVelocity velocity) const;
  // When the previous scan was corrected at a velocity that puts its points more than sensor.deskew_tolerance from
  // where `velocity` puts them: moves its features (history->previous and the window's newest) there. True when it did.
  bool correct_previous(const SweepVelocity& velocity, ScanHistory* history);
  // sensor.deskew_iterations: while the velocity of the registered motion (over `dt`) puts the sweep's points before
  // its stamp more than sensor.deskew_tolerance from where sweep->velocity put them, moves this scan's features (and
  // the previous scan's) to it and registers again (`register_again` from the outcome). Returns how many times.
  int correct_at_registered(ScanFeatures* features, SweepTimes* sweep, double dt, ScanHistory* history,
                            const std::function<PassOutcome(const PassOutcome&)>& register_again,
                            PassOutcome* outcome, FrameStats* st);

  void record_motion(const RigidTransform& delta, double dt);  // a frame's motion, for the trend
  void finish_sweep(SweepTimes sweep);  // this scan's sweep: the previous one of the next frame
  void no_sweep() { have_previous_ = false; }  // this scan had no times
  void forget_trend() { registered_velocities_.clear(); }
  void reset();

 private:
  // Whether sweep times [first, last] corrected at `a` and at `b` put a point 20 m away within
  // sensor.deskew_tolerance of each other.
  bool corrected_alike(const SweepVelocity& a, const SweepVelocity& b, double first, double last) const;

  SensorOptions options_;
  SweepTimes previous_;
  bool have_previous_ = false;
  std::deque<SweepVelocity> registered_velocities_;  // of the last sensor.deskew_trend frames, newest first
};

}  // namespace line_odom
