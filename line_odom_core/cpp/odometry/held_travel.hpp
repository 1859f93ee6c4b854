// The velocity along the travel that consecutive frames hold at the prediction (their lines leave it open), set by
// the last frame that measured it, against what the point map's alignment measured in each of those frames. One
// frame's alignment confirms a held motion within a third of validation.tolerance (motion_validation.hpp), the
// resolution at which it resolves an axis; n frames' mean is read to that resolution / sqrt(n), or to their own
// spread where that is wider. A held velocity their mean lies farther from than validation.significance times that
// is contradicted by the scans: taken from their mean, it does not persist for the rest of a highway.
#pragma once

namespace line_odom {

class HeldTravel {
 public:
  // Whether the points' travel in the frames recorded so far and in this one (`points_travel`, m along the travel)
  // contradict the `held` travel (the prediction's); their mean into *mean.
  bool contradicted(double points_travel, double held, double resolution, double significance, double* mean) const;
  void record(double points_travel);  // a judged frame holding the travel, whose points resolve it
  void forget();                      // a frame that does not hold it: the next held velocity starts afresh

 private:
  int count_ = 0;
  double sum_ = 0.0, sum_squares_ = 0.0;
};

}  // namespace line_odom
