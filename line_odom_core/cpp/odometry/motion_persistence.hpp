// How much of a frame's measured motion carries over to the next: per axis of the motion chart (t, r) of
// motion_difference, the least-squares a in z(k+1) ~ a z(k) over an exponential window of consecutive registered
// frames' velocities z (motion / stamp interval), clamped to [0, 1]. With z = v + n (estimate noise n, independent
// from frame to frame), that regression is E[v(k+1) v(k)] / (E[v v] + E[n n]): the best linear one-step predictor
// of the true velocity (Wiener). Smooth motion measured precisely (a car, a simulated camera) gives ~1, the plain
// constant-velocity prediction; a motion the estimates barely resolve (a handheld depth camera's rotation at 1/100)
// shrinks towards 0, so one wrong frame is not carried into the next ones (docs/RESULTS.md).
// Robust to single bad frames: once estimated, a velocity component beyond kClipSigmas x the window's rms enters
// clipped there, and a frame whose stamp interval is off by more than kMaxIntervalRatio from the previous one's
// (a stamp glitch: its velocity would be wrong by that factor) breaks the chain instead of entering.
#pragma once

#include "common/types.hpp"

namespace line_odom {

class MotionPersistence {
 public:
  static constexpr int kMinPairs = 10;               // consecutive pairs before the factors leave 1
  static constexpr double kClipSigmas = 3.0;
  static constexpr double kMaxIntervalRatio = 5.0;  // as the prediction's own stamp-interval scaling (odometry.cpp)

  explicit MotionPersistence(int window = 0) : window_(window) {}  // frames; 0: off, factors always 1

  void add(const Vec6& motion, double dt);  // a registered frame's motion over its stamp interval dt (s)
  void interrupt();                          // a frame without a registration: the next motion has no predecessor
  void clear();                              // and forget the statistics (a reset)
  Vec6 factors() const;                      // per axis, in [0, 1]

 private:
  int window_ = 0;
  int pairs_ = 0;
  bool have_previous_ = false;
  double previous_dt_ = 0.0;
  Vec6 previous_ = Vec6::Zero();
  Vec6 lag0_ = Vec6::Zero();  // mean of z(k)^2
  Vec6 lag1_ = Vec6::Zero();  // mean of z(k+1) z(k)
};

}  // namespace line_odom
