#include "odometry/held_travel.hpp"

#include <algorithm>
#include <cmath>

namespace line_odom {

bool HeldTravel::contradicted(double points_travel, double held, double resolution, double significance,
                              double* mean) const {
  const int n = count_ + 1;
  *mean = (sum_ + points_travel) / n;
  if (n < 2) return false;  // one frame's difference is the single-frame check's (motion_validation.cpp)
  const double spread =
      std::max(0.0, (sum_squares_ + points_travel * points_travel - n * *mean * *mean) / (n - 1));
  const double per_frame = std::max(spread, std::pow(resolution / significance, 2));
  return std::abs(*mean - held) > significance * std::sqrt(per_frame / n);
}

void HeldTravel::record(double points_travel) {
  ++count_;
  sum_ += points_travel;
  sum_squares_ += points_travel * points_travel;
}

void HeldTravel::forget() { *this = HeldTravel(); }

}  // namespace line_odom
