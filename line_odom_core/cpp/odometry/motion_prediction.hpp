// The motion predicted for the next frame (docs/DESIGN.md §2): the last registered motion at constant velocity, scaled
// by the stamp interval and per axis by its measured persistence (motion_persistence.hpp), and which directions of that
// velocity no scan has measured yet (a first motion held at standing still). Its own state: the last motion, what of
// it was held, the interval and the persistence statistics.
#pragma once

#include "common/types.hpp"
#include "odometry/motion_persistence.hpp"

namespace line_odom {

// Velocity scaling of a motion: exp(alpha * log(T)) on SO(3) x R^3 (rotation angle and translation scaled).
RigidTransform scale_motion(const RigidTransform& T, double alpha);
// The directions of the subspace `a` (a projector) that the subspace `b` reaches within the angle of `cosine`, as a
// projector.
Mat6 common_directions(const Mat6& a, const Mat6& b, double cosine);
// The prediction turned by `R` instead of its own rotation, its translation along the same body-frame velocity.
RigidTransform with_rotation(const RigidTransform& prediction, const Mat3& R);

class MotionPrediction {
 public:
  explicit MotionPrediction(int persistence_window = 0) : persistence_(persistence_window) {}

  // The motion over `dt` seconds (standing still without a velocity or with constant_velocity off), and the share of
  // the last motion it carries per axis.
  RigidTransform predict(double dt, bool constant_velocity, Vec6* persistence) const;

  // A frame registered (or held) `delta` over `dt`; `held_projector`: onto its directions taken from the prediction.
  // `first_motion`: there was no velocity before it; `guessed`: the prediction was a caller's measurement;
  // `rotation_guessed`: its rotation was a gyro's; `points_measured`: the point map measured what was unmeasured.
  void record(const RigidTransform& delta, const Mat6& held_projector, bool registered, double dt, bool first_motion,
              bool guessed, bool rotation_guessed, bool constant_velocity, bool points_measured = false);
  // A pause: the last motion says nothing about the next one (found afresh, as after a reset).
  void drop_velocity();
  void reset();

  bool have_velocity() const { return have_velocity_; }
  // Onto the directions of the velocity no frame has measured since the first motion was held (standing still, a guess
  // nobody measured): searched each frame, and the motion prior does not pull towards them.
  const Mat6& unmeasured_projector() const { return unmeasured_projector_; }
  // The velocity is a measurement from now on (a caller's guess stands for it).
  void set_have_velocity() { have_velocity_ = true; }

 private:
  RigidTransform last_delta_;
  Mat6 last_held_projector_ = Mat6::Zero();  // onto the directions of last_delta_ that were the prediction's
  Mat6 unmeasured_projector_ = Mat6::Zero();
  double last_dt_ = 0.0;
  bool have_velocity_ = false;
  MotionPersistence persistence_;
};

}  // namespace line_odom
