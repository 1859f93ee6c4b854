// Whether the lines pin the frame's motion down, and the points' answer where they do not (beyond the paper). An
// H-line and a V-line on one plane meet under any motion within that plane, so on a street of walls a wrong motion
// along the street can collect as many intersection inliers as the right one: each direction of the lines' motion is
// tested against the motion pushed either way (observability.hpp). Where one is not pinned down, where the lines
// registered nothing, and at a first motion, the scan's points are aligned to the local map of the last scans' points
// (point_map_tracker.hpp): the lines register again from there, and directions they still leave open are held at the
// points' motion, flagged, with at least the fallback covariance.
#pragma once

#include <vector>

#include "odometry/line_registration.hpp"
#include "odometry/point_map_tracker.hpp"

namespace line_odom {

struct ValidationFrame {
  const ScanFeatures* previous = nullptr;  // frame a of the registration
  ScanFeatures* current = nullptr;
  const std::vector<Vec3>* points = nullptr;  // this scan's, for the point map
  RigidTransform previous_pose;               // T_world_sensor of the previous scan
  RigidTransform prediction;
  bool first_motion = false;  // no velocity before this frame
  bool guessed = false;       // the prediction is a caller's measurement: open directions are held at it
  RegistrationFrame registration;
};

class MotionValidation {
 public:
  explicit MotionValidation(const LineRegistration& lines) : lines_(lines) {}

  // Checks *outcome and, where needed, asks the point map; returns the motion the outcome's held directions (and a
  // failed registration) take: the points' alignment when it was made, else the prediction.
  RigidTransform validate(const ValidationFrame& frame, const PointMapTracker& point_map, PassOutcome* outcome,
                          FrameStats* st) const;

 private:
  // McNemar's test of `outcome` on the last pass's candidates under its motion (filled into corr).
  Observability observe(const ValidationFrame& frame, const PassOutcome& outcome, Correspondences* corr) const;

  const LineRegistration& lines_;
};

}  // namespace line_odom
