#include "odometry/motion_persistence.hpp"

#include <algorithm>
#include <cmath>

namespace line_odom {

void MotionPersistence::add(const Vec6& motion, double dt) {
  const bool positive = std::isfinite(dt) && dt > 0.0;
  const bool interval_ok = positive && (previous_dt_ <= 0.0 || (dt <= kMaxIntervalRatio * previous_dt_ &&
                                                                previous_dt_ <= kMaxIntervalRatio * dt));
  const bool usable = window_ > 0 && interval_ok && motion.allFinite();
  if (positive) previous_dt_ = dt;
  if (!usable) {
    interrupt();
    return;
  }
  Vec6 z = motion / dt;
  if (pairs_ >= kMinPairs)
    for (int k = 0; k < 6; ++k) {
      const double limit = kClipSigmas * std::sqrt(lag0_(k));
      z(k) = std::clamp(z(k), -limit, limit);
    }
  if (have_previous_) {
    ++pairs_;
    const double w = 1.0 / std::min(pairs_, window_);
    lag0_ += w * (previous_.cwiseProduct(previous_) - lag0_);
    lag1_ += w * (z.cwiseProduct(previous_) - lag1_);
  }
  previous_ = z;
  have_previous_ = true;
}

void MotionPersistence::interrupt() { have_previous_ = false; }

void MotionPersistence::clear() {
  pairs_ = 0;
  have_previous_ = false;
  previous_dt_ = 0.0;
  previous_ = lag0_ = lag1_ = Vec6::Zero();
}

Vec6 MotionPersistence::factors() const {
  Vec6 a = Vec6::Ones();
  if (window_ <= 0 || pairs_ < kMinPairs) return a;
  for (int k = 0; k < 6; ++k)
    if (lag0_(k) > 0.0) a(k) = std::clamp(lag1_(k) / lag0_(k), 0.0, 1.0);
  return a;
}

}  // namespace line_odom
