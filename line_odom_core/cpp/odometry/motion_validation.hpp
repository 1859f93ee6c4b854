// Each frame's motion checked against evidence the intersection inliers did not produce (beyond the paper). An H-line
// and a V-line on one plane meet under any motion within that plane, so on a street of walls a wrong motion along the
// street can collect as many inliers as the right one. The scan's points are aligned to the local map of the last
// scans' points (point_map_tracker.hpp) from the prediction: along the directions where that motion and the lines'
// differ by more than validation.tolerance, the lines' motion is not taken: held at the points' motion, the frame
// flagged with at least the fallback covariance there. Without the point map, and at a first motion (when the map holds
// one scan), the lines' own test decides (each direction against the motion pushed either way, observability.hpp).
// Where the lines registered nothing, or at a first motion they did not confirm, they register again from the points'
// motion. Rotations the lines' refinement holds (too weakly constrained) are held at the points' rotation where the
// points resolve it, not at the prediction's.
#pragma once

#include <vector>

#include "odometry/held_travel.hpp"
#include "odometry/line_registration.hpp"
#include "odometry/point_map_tracker.hpp"

namespace line_odom {

// A scan's points aligned to the point map from the prediction (PointMapTracker::align).
struct MapAlignment {
  bool aligned = false;
  RigidTransform motion;
  int matched = 0;
  Mat6 covariance = Mat6::Zero();
};

struct ValidationFrame {
  const ScanFeatures* previous = nullptr;  // frame a of the registration
  ScanFeatures* current = nullptr;
  const std::vector<Vec3>* points = nullptr;  // this scan's, for the point map
  RigidTransform previous_pose;               // of the previous scan on the point map (PointMapTracker::place_of)
  RigidTransform prediction;
  Mat6 unmeasured = Mat6::Zero();  // onto the prediction's directions no frame measured (MotionPrediction)
  bool first_motion = false;  // no velocity before this frame
  bool guessed = false;       // the prediction is a caller's measurement: open directions are held at it
  bool rotation_guessed = false;  // the prediction's rotation is a gyro's measurement
  const MapAlignment* aligned_before = nullptr;  // nullable: this frame's alignment, made before the lines
  const HeldTravel* held_travel = nullptr;  // nullable: the travel the frames before held, and their points'
  RegistrationFrame registration;
};

struct Validated {
  RigidTransform reference;  // what the outcome's held directions (and a failed registration) take: the points'
                             // alignment where they were held at it or it was taken, else the prediction
  // The directions held were held at the point map's alignment, which measured them (all six where it was taken; a
  // first motion's only beyond the alignment kernel's width of standing still): the scan enters the map at its pose.
  bool held_at_points = false;
  // The translations of the velocity no frame measured were taken from the point map's alignment: measured now.
  bool measured_velocity = false;
  // The frame held its travel (the prediction's direction), at the prediction or at the points' mean over the frames
  // holding it, and the points resolved it there: their travel (m), for HeldTravel::record.
  bool travel_held = false;
  double points_travel = 0.0;
  // Where the map judged this frame: the points' motion from the previous scan's place and the axes along which they
  // resolve it (a third of the tolerance).
  bool judged = false;
  RigidTransform by_points;
  int resolved = 0;
  // A frame the map did not judge, flagged at its lines' motion: the axes (bits) along which nothing confirmed it, where
  // the scan sits on the map at the lines' motion alone (PointMapTracker::last_scan_unconfirmed).
  int unconfirmed_place = 0;
};

// Where a judged frame whose motion was partly held at the prediction sits on the point map, from the previous scan's
// `previous_place`: the points' motion along the axes they resolve, the frame's `delta` along the others.
RigidTransform place_on_map(const Validated& validated, const RigidTransform& previous_place,
                            const RigidTransform& delta);

class MotionValidation {
 public:
  explicit MotionValidation(const LineRegistration& lines) : lines_(lines) {}

  // Checks *outcome and, where needed, asks the point map.
  Validated validate(const ValidationFrame& frame, const PointMapTracker& point_map, PassOutcome* outcome,
                     FrameStats* st) const;

 private:
  struct Judgement;  // what the checks found of a registration (motion_validation.cpp)
  // This scan's points aligned to the map (not aligned for a guessed frame); *travelled: a first motion's alignment
  // the points showed the scan travelled to.
  MapAlignment align_to_map(const ValidationFrame& frame, const PointMapTracker& point_map, bool* travelled) const;
  // The directions a registration in full leaves open (judgement.open) held, taken from the points, or flagged.
  void settle_open_directions(const ValidationFrame& frame, const PointMapTracker& point_map,
                              const Judgement& judgement, const MapAlignment& points, bool judged, bool travelled,
                              int off_guess, PassOutcome* outcome, Validated* out) const;
  // observe and open_directions of `outcome`, into *judgement.
  void judge(const ValidationFrame& frame, const PassOutcome& outcome, const PointMapTracker& point_map,
             const RigidTransform* points, const Mat6& points_covariance, Judgement* judgement) const;
  // The lines registered again from the points' motion `by_points`: taken, with its judgement, where it leaves fewer
  // directions open.
  void register_from_points(const ValidationFrame& frame, const PointMapTracker& point_map,
                            const RigidTransform& by_points, const Mat6& points_covariance, PassOutcome* outcome,
                            Judgement* judgement, FrameStats* st) const;
  // McNemar's test of `outcome` on the last pass's candidates under its motion (filled into corr).
  Observability observe(const ValidationFrame& frame, const PassOutcome& outcome, Correspondences* corr) const;
  // Into judgement->open, the directions (bits of xi) along which `outcome` is not confirmed (judgement->obs, McNemar's
  // test, already in): those the points' motion (nullable) puts farther than the tolerance, where they resolve it
  // (points_covariance) and do not fit the lines' motion as well, and the resolved translation axes along which they
  // lie on the other side of standing still (also into ->reversed); without it, and at a first motion, those `obs`
  // leaves open. Where the points lie short of the lines' translation within the alignment kernel's width of standing
  // still (a lean), or anywhere within it while it is wider than the tolerance, they do not judge: those axes `obs`
  // leaves open are open, into ->leaning (flagged at the lines' motion, not held at the points'). Directions `obs`
  // leaves open that the points resolve outside that width and put farther than a third of the tolerance from the
  // lines' are open too, into ->unpinned. A judged frame's axes the points put on the other side of standing still
  // while fitting the lines' motion as well, not better by validation.significance, stay open, into ->two_way
  // (flagged at the lines' motion).
  void open_directions(const ValidationFrame& frame, const PassOutcome& outcome, const PointMapTracker& point_map,
                       const RigidTransform* by_points, const Mat6& points_covariance, Judgement* judgement) const;

  // A judged frame whose refinement held directions: its rotations held at the point map's alignment `by_points`, the
  // velocity's unmeasured translations and the side of the travel (held_side) too, where the points resolve them.
  void hold_at_the_map(const ValidationFrame& frame, const RigidTransform& by_points, const Mat6& points_covariance,
                       PassOutcome* outcome, Validated* out) const;
  // Whether the travel (the prediction's direction) the frame holds at the prediction is contradicted by the points'
  // travel over the frames holding it (HeldTravel, frame.held_travel): then *step (motion_difference at the
  // prediction) moves the travel to their mean. Fills out->travel_held and points_travel.
  bool held_travel(const ValidationFrame& frame, const PassOutcome& outcome, const RigidTransform& by_points,
                   const Mat6& points_covariance, double tolerance, Vec6* step, Validated* out) const;
  // The side of the travel (unit) where holding the lines' weak directions at the prediction would pass on more of
  // its error there than the points' own variance; else zero.
  Vec3 held_side(const ValidationFrame& frame, const PassOutcome& outcome, const Mat6& points_covariance,
                 double tolerance) const;

  const LineRegistration& lines_;
};

}  // namespace line_odom
