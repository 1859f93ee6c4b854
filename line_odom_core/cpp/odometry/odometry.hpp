// Frame-to-frame odometry with state (docs/DESIGN.md §2). Each frame is a short recipe over components
// (register_image, frame_pipeline.cpp):
// organize -> (deskew) -> features -> predict -> register the lines (paper §6.3, motion_search.hpp beyond the
// prediction's reach) -> check the lines pin the motion down, the local point map where they do not (validation) ->
// fuse with the motion model -> refine on the points -> compose the pose. A failed or degenerate registration holds
// what is known, inflates the covariance and says so in the stats; the pose is never NaN.
#pragma once

#include <cstddef>
#include <cstdint>
#include <memory>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "common/scan_features.hpp"
#include "common/types.hpp"
#include "common/worker_pool.hpp"
#include "odometry/frame_features.hpp"
#include "odometry/frame_result.hpp"
#include "odometry/line_registration.hpp"
#include "odometry/motion_fusion.hpp"
#include "odometry/motion_prediction.hpp"
#include "odometry/motion_search.hpp"
#include "odometry/motion_validation.hpp"
#include "odometry/odometry_config.hpp"
#include "odometry/point_map_tracker.hpp"
#include "odometry/scan_history.hpp"
#include "odometry/sweep_correction.hpp"
#include "scan/deskew.hpp"
#include "scan/range_image.hpp"

namespace line_odom {

// Everything the odometry carries from one frame to the next, one component each.
struct OdometryState {
  RigidTransform pose;        // T_world_sensor of the last frame
  double previous_stamp = 0.0;
  int frames = 0;
  double last_inlier_weight = 0.0;  // of the last frame when it was registered in full (search_turn), else 0
  MotionPrediction prediction;
  ScanHistory scans;
  SweepCorrection sweeps;
  PointMapTracker point_map;
  HeldTravel held_travel;  // the travel the last frames held, and their points' (motion_validation.hpp)

  explicit OdometryState(const OdometryConfig& config)
      : prediction(config.registration.persistence_window),
        sweeps(config.sensor),
        point_map(config.point_map, config.sensor.limits.max_range) {
    scans.window = FeatureWindow(config.registration.window);
  }
};

class Odometry {
 public:
  explicit Odometry(const OdometryConfig& config);
  Odometry(const Odometry&) = delete;  // its components refer to its configuration and pool
  Odometry& operator=(const Odometry&) = delete;

  // `guess` (nullable): the sensor's motion since the previous frame from another source (wheel odometry, an
  // IMU), T_prev_curr. It replaces the constant-velocity prediction: the registration starts from it, the motion
  // prior is centred on it and degenerate directions are held at it. Throws std::invalid_argument when it is
  // not a finite rigid transform. Ignored on the first frame.
  // `rotation_guess` (nullable, not with `guess`): the sensor's rotation since the previous frame, R_prev_curr (a
  // gyro's). It replaces the rotation of the prediction; the translation stays the prediction's (with_rotation).
  // Also without a velocity yet: the first motion is searched from standing still turned by it.
  // Unorganized points: xyz at data[i * stride + 0..2]; `ring` (nullable) gives the beam of each point.
  // `time` (nullable): when each point was measured, in seconds from `stamp`; with sensor.deskew the sweep is
  // corrected for the motion during it (deskew.hpp) at the predicted velocity, and so is the previous scan when it was
  // corrected at another one; points before the stamp once more at the registered motion
  // (sensor.deskew_iterations). Throws std::invalid_argument on a non-finite time. `sweep_rate` (nullable, with
  // `time`): the sensor's angular velocity during this sweep (rad/s, a gyro's): the turn of the correction, this
  // scan's own.
  template <typename Scalar>
  FrameResult register_points(const Scalar* data, std::size_t count, std::size_t stride, const std::int32_t* ring,
                              double stamp, const RigidTransform* guess = nullptr,
                              const Mat3* rotation_guess = nullptr, const double* time = nullptr,
                              const Vec3* sweep_rate = nullptr);
  // Organized cloud (rows x cols, row-major, `stride` elements per point); non-finite points are holes. `time`
  // (nullable): rows x cols, as for register_points.
  template <typename Scalar>
  FrameResult register_organized(const Scalar* data, int rows, int cols, std::size_t stride, double stamp,
                                 const RigidTransform* guess = nullptr, const Mat3* rotation_guess = nullptr,
                                 const double* time = nullptr, const Vec3* sweep_rate = nullptr);
  // Depth image in metres (row-major rows x cols, 0 / non-finite = no measurement) and intrinsics K.
  FrameResult register_depth(const float* depth, int rows, int cols, const Mat3& K, double stamp,
                             const RigidTransform* guess = nullptr, const Mat3* rotation_guess = nullptr);
  // The valid points of an unorganized cloud after organizing and downsampling, as the pipeline sees them.
  template <typename Scalar>
  std::vector<Vec3> downsampled_points(const Scalar* data, std::size_t count, std::size_t stride,
                                       const std::int32_t* ring) const;
  // Registers an already organized range image, organized at `organized_step` (1 = full resolution; the step divides
  // config.downsample); downsampling is applied here.
  FrameResult register_range_image(const RangeImage& image, double stamp, double organize_ms = 0.0,
                                   int organized_step = 1, const RigidTransform* guess = nullptr,
                                   const Mat3* rotation_guess = nullptr);
  int organize_step(double stamp, bool guessed = false) const;  // the step the next frame is organized at
  // The point-to-plane refinement runs: points.weight > 0 at a downsampling step within points.max_downsample.
  bool points_refining() const {
    return config_.points.weight > 0.0 && config_.downsample <= config_.points.max_downsample;
  }

  void reset(const RigidTransform& pose = RigidTransform::identity());

  const OdometryConfig& config() const { return config_; }
  const SensorModel& sensor_model() const { return sensor_; }
  const RigidTransform& pose() const { return state_.pose; }
  int frames() const { return state_.frames; }
  const ScanFeatures& last_features() const { return state_.scans.previous; }
  // While on, each frame keeps the points it was registered with (after organizing, downsampling and deskewing, in
  // its sensor frame) for last_points(): a view's (rviz ~/scan), off by default.
  void keep_points(bool keep) { keep_points_ = keep; }
  const std::vector<Vec3>& last_points() const { return last_points_; }

 private:
  // One frame's circumstances: fixed before its features are fitted (begin_frame), its prediction added (predict).
  struct FrameInputs {
    double dt = 0.0;  // since the previous frame
    int organized_step = 1;
    const RigidTransform* guess = nullptr;  // nullable, as register_points' arguments
    const Mat3* rotation_guess = nullptr;
    SweepTimes* sweep = nullptr;  // nullable: the image's sweep times (register_image)
    bool guessed = false;           // a guess stands for the velocity
    bool rotation_guessed = false;  // the prediction's turn is a gyro's
    bool first_motion = false;      // no velocity before this frame
    bool searching = false;         // the velocity's unmeasured directions are searched (search_unmeasured)
    Mat6 unmeasured = Mat6::Zero();  // onto those directions
    RigidTransform own_prediction;   // the motion model's, or the guess
    RigidTransform prediction;       // turned by the rotation guess
    RegistrationFrame registration;
  };

  // register_range_image (the guesses checked); `sweep` (nullable): the image's sweep times, deskewed at
  // sweep->velocity (moved again by the sweep correction at the registered motion). The recipe over the steps below
  // (frame_pipeline.cpp).
  FrameResult register_image(const RangeImage& image, double stamp, double organize_ms, int organized_step,
                             const RigidTransform* guess, const Mat3* rotation_guess, SweepTimes* sweep);
  // The frame's inputs; drops a velocity older than registration.max_prediction_gap and takes a guess as one.
  FrameInputs begin_frame(double stamp, int organized_step, const RigidTransform* guess, const Mat3* rotation_guess,
                          SweepTimes* sweep);
  // Its lines, planes, points (and coarse scan, surface) fitted; the next frame's fitting step chosen.
  void extract_features(const RangeImage& image, const FrameInputs& in, FrameFeatures* scan, FrameStats* st);
  // The first frame defines the odometry frame at the (reset) pose; its points enter the map there.
  void enter_first_scan(const FrameFeatures& scan, const Plane* ground, const FrameInputs& in, FrameStats* st);
  // The motion model's prediction (or the guess), turned by the rotation guess.
  void predict(FrameInputs* in, FrameStats* st) const;
  // The lines' registration, searched beyond the prediction's reach where it cannot reach (motion_search.hpp);
  // `aligned_before`: set where the points were aligned to the map first (full resolution), the lines' start there.
  PassOutcome register_lines(const FrameFeatures& scan, const FrameInputs& in,
                             std::optional<MapAlignment>* aligned_before, FrameStats* st) const;
  // The sweep corrected again at the registered motion (sensor.deskew_iterations), the lines registered again.
  void correct_sweep_again(FrameFeatures* scan, const FrameInputs& in, PassOutcome* outcome, FrameStats* st);
  // Do the lines pin the motion down; the point map where they do not (motion_validation.hpp).
  Validated validate(FrameFeatures* scan, const FrameInputs& in, const std::optional<MapAlignment>& aligned_before,
                     PassOutcome* outcome, FrameStats* st) const;
  // The frame's motion and covariance, fused with the motion model; unconfirmed directions flagged and inflated.
  FusedMotion fuse(const PassOutcome& outcome, const FrameInputs& in, const Validated& validated,
                   FrameResult* result) const;
  // Onto the directions of a flagged frame's motion that its lines left unconfirmed: all of a frame not registered,
  // none of one held in part, else those the lines' own test left under validation.significance.
  Mat6 unconfirmed(const FrameStats& st) const;
  // The point-to-plane refinement (points.*) of a motion registered in full.
  void refine_on_points(const FrameFeatures& scan, const FusedMotion& fused, FrameResult* result);
  // The pose composed, the motion model and the sweep's trend told the motion, the scan entered into the point map.
  void advance(const FrameFeatures& scan, const Plane* ground, const FrameInputs& in, const FusedMotion& fused,
               const Validated& validated, FrameResult* result);
  // The scan kept as the previous one (and in the window) for the next frame.
  void keep_scan(FrameFeatures* scan, const FrameResult& result);
  template <typename Scalar>
  FrameResult register_sweep(const Scalar* data, std::size_t count, std::size_t stride, const std::int32_t* ring,
                             int rows, int cols, double stamp, const RigidTransform* guess,
                             const Mat3* rotation_guess, const double* time, const Vec3* sweep_rate);
  // The velocity a scan at `stamp` is deskewed at: the prediction's (the guess's; turned by the rotation guess) over
  // the stamp interval; standing still on the first frame and while there is no velocity (but the rotation guess's
  // turn); turning at `sweep_rate` when given.
  SweepVelocity sweep_velocity(double stamp, const RigidTransform* guess, const Mat3* rotation_guess,
                               const Vec3* sweep_rate) const;
  // The lines' registration of `cur` from `start` against the window of previous scans when it observes every
  // direction with the last scan alone (registration.window), else against the last scan.
  PassOutcome register_on_window(const ScanFeatures& cur, const RigidTransform& prediction, const RigidTransform& start,
                                 const RegistrationFrame& frame, FrameStats* st) const;
  RegistrationFrame registration_frame() const;

  OdometryConfig config_;
  SensorModel sensor_;
  std::shared_ptr<WorkerPool> pool_;  // null with one thread; copies of an Odometry take turns on it
  LineRegistration lines_;
  MotionSearch search_;
  OdometryState state_;
  bool keep_points_ = false;
  std::vector<Vec3> last_points_;
};


}  // namespace line_odom
