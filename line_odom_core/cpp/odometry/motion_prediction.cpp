#include "odometry/motion_prediction.hpp"

#include <Eigen/Eigenvalues>

#include <algorithm>
#include <cmath>

#include "registration/refine.hpp"

namespace line_odom {

namespace {

constexpr double kUnmeasuredCosine = 0.5;  // a direction not measured stays so while the held directions reach within
                                           // 60 deg of it (they wobble between x and pitch on KITTI 04 at 1/64)

}  // namespace

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

// A constant velocity turning at rate w moves the sensor by about exp(w dt / 2) v dt, so the translation turns by the
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

RigidTransform MotionPrediction::predict(double dt, bool constant_velocity, Vec6* persistence) const {
  *persistence = Vec6::Ones();
  if (!constant_velocity || !have_velocity_) return RigidTransform::identity();
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

void MotionPrediction::record(const RigidTransform& delta, const Mat6& held_projector, bool registered, double dt,
                              bool first_motion, bool guessed, bool rotation_guessed, bool constant_velocity,
                              bool points_measured) {
  last_delta_ = delta;
  last_held_projector_ = held_projector;
  // A first motion held in full measured no direction of the velocity; a later frame measures what it registers.
  // (Without constant velocity every prediction is standing still: nothing to search; a guess is a measurement, and
  // so is the point map's of the unmeasured directions.)
  if (guessed || !constant_velocity || points_measured) unmeasured_projector_ = Mat6::Zero();
  else if (first_motion) unmeasured_projector_ = held_projector;
  else unmeasured_projector_ = common_directions(unmeasured_projector_, held_projector, kUnmeasuredCosine);
  if (rotation_guessed && !unmeasured_projector_.isZero()) {
    // A gyro measured the rotation: only translations can stay unmeasured.
    Mat6 translations = Mat6::Zero();
    translations.topLeftCorner<3, 3>().setIdentity();
    unmeasured_projector_ = common_directions(unmeasured_projector_, translations, kUnmeasuredCosine);
  }
  if (registered) persistence_.add(motion_difference(delta, RigidTransform::identity()), dt);
  else persistence_.interrupt();
  if (std::isfinite(dt) && dt > 0.0) last_dt_ = dt;
  have_velocity_ = true;
}

void MotionPrediction::drop_velocity() {
  have_velocity_ = false;
  last_delta_ = RigidTransform::identity();
  persistence_.interrupt();
}

void MotionPrediction::reset() {
  last_delta_ = RigidTransform::identity();
  last_held_projector_ = Mat6::Zero();
  unmeasured_projector_ = Mat6::Zero();
  last_dt_ = 0.0;
  have_velocity_ = false;
  persistence_.clear();
}

}  // namespace line_odom
