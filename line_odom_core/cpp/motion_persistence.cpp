#include "motion_persistence.hpp"

#include <algorithm>

namespace line_odom {

void MotionPersistence::add(const Vec6& z) {
  if (window_ <= 0 || !z.allFinite()) {
    interrupt();
    return;
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
