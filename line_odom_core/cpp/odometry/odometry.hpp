// Frame-to-frame odometry with state (docs/DESIGN.md §2): organize -> downsample -> features -> predict (constant
// velocity) -> candidates -> hybrid RANSAC + refinement, 3 passes each seeded with the best estimate so far
// (paper §6.3) -> compose the pose. A failed or degenerate registration holds the prediction, inflates the
// covariance and says so in the stats; the pose is never NaN.
#pragma once

#include <cstddef>
#include <cstdint>
#include <deque>
#include <memory>
#include <string>
#include <utility>
#include <vector>

#include "common/scan_features.hpp"
#include "common/types.hpp"
#include "common/worker_pool.hpp"
#include "features/feature_extraction.hpp"
#include "features/feature_window.hpp"
#include "odometry/motion_persistence.hpp"
#include "registration/candidates.hpp"
#include "registration/motion_estimation.hpp"
#include "registration/point_refine.hpp"
#include "registration/refine.hpp"
#include "scan/deskew.hpp"
#include "scan/range_image.hpp"
#include "validation/local_map.hpp"
#include "validation/point_evidence.hpp"

namespace line_odom {

struct RegistrationOptions {
  int passes = 3;                       // paper §6.3
  double pass_distance_scale = 1.0;     // candidate distance multiplier from one pass to the next
  int min_inliers = 12;                 // fewer: failed, hold the prediction
  double max_translation = 5.0;         // reject estimates this far (m) from the prediction
  double max_rotation_deg = 30.0;       // ... or rotated this much from it
  bool constant_velocity = true;        // false: predict identity
  int persistence_window = 0;           // frames: the prediction scales the last motion per axis by its measured
                                        // persistence (motion_persistence.hpp); 0: the last motion as it was
  double max_axis_support = 0.97;       // degenerate when a push along one axis keeps this share of the inliers
  double max_axis_pair_support = 0.995;  // ... or this share of the inlier pairs, each counted once
  double min_inlier_ratio = 0.3;        // degenerate when fewer of the last pass's candidate pairs are inliers
  double max_prediction_gap = 1.0;      // s; a longer stamp gap drops the velocity (start as after a reset)
  double min_sample_pair_share = 0.95;  // ... and keep at least this share of its inlier pairs (unweighted)
  double guess_preference = 0.0;        // the RANSAC winner must beat the refined guess's weighted inliers by
                                        // this fraction to replace it
  double covariance_scale = 1.0;        // multiplies the refinement's covariance (it ignores candidate errors)
  bool covariance_per_inlier = false;   // ... once per inlier constraint: sigma^2 (H / n)^-1, a frame's error that
                                        // does not shrink with the number of constraints (docs/RESULTS.md)
  double motion_prior_translation_sigma = 0.0;  // constant-velocity prior per frame (m); 0: no fusion
  double motion_prior_rotation_sigma_deg = 0.5;
  int max_lines = 3000;                 // lines registered per scan: past this, those of every s-th row and column
                                        // (line_selection.hpp); 0: all
  int window = 1;                       // previous scans registered against (feature_window.hpp); 1: the last one
  int first_motion_pairs_per_line = 0;  // no motion guess yet: the k closest partners of each line (0: all within
                                        // candidates.max_distance, paper §6.3)
  int coarse_downsample = 6;            // no velocity yet: register at this step first (0 / = downsample: off)
  bool partial_updates = true;          // degenerate: keep what the pairs observe, hold only the rest (refine.hpp)
  double fallback_translation_sigma = 0.5;    // covariance reported when the prediction is held
  double fallback_rotation_sigma_deg = 5.0;
};

// Which SensorModel organizes unorganized clouds: a preset ("hdl64", "vlp16", "os128"), or "uniform" with
// rows beams evenly spaced between max/min elevation. cols > 0 overrides the preset's azimuth bins.
struct SensorOptions {
  std::string model = "hdl64";
  int rows = 0;
  int cols = 0;
  double max_elevation_deg = 2.0;
  double min_elevation_deg = -24.9;
  RangeLimits limits;
  bool deskew = true;              // points with times: moved into the frame at the stamp (deskew.hpp)
  double deskew_tolerance = 0.005;  // m: the previous scan is deskewed again when the velocity changed by more
  int deskew_trend = 3;             // frames: a sweep is corrected at the pair's velocity plus the change from the
                                    // previous sweep's, the slope of the last n registered velocities (0: off)
  int deskew_iterations = 1;        // a sweep with times before its stamp (stamped at its end) is deskewed again at the
                                    // motion registered for it, when that differs by more than deskew_tolerance, and
                                    // registered again, at most this many times; 0: at the prediction only
};

// The SensorModel the options describe; throws std::invalid_argument when they are inconsistent.
SensorModel make_sensor_model(const SensorOptions& options);

struct OdometryConfig {
  int downsample = 1;  // keep every n-th row and column (paper §6.1)
  std::uint64_t seed = 0;
  int threads = 1;  // of the line fit and the line-pair search (worker_pool.hpp); 0: one per hardware thread. Same
                    // results.
  SensorOptions sensor;
  FeatureConfig features;  // lines.*, normals.*, planes.*
  CandidateOptions candidates;
  MotionOptions ransac;
  RegistrationOptions registration;
  PointRefineOptions points;  // points.*: the point-to-plane refinement (point_refine.hpp)
  EvidenceOptions evidence;   // evidence.*: each motion checked against the local map's points (point_evidence.hpp)
};

struct StageMilliseconds {
  double organize = 0, downsample = 0, features = 0, candidates = 0, ransac = 0, total = 0;
  double lines = 0, normals = 0, planes = 0;  // parts of features
  double points = 0;  // the point-to-plane refinement, its surface built for the next frame included
  double evidence = 0;  // checking the motion against the local map, and updating the map
  double deskew = 0;  // correcting both scans' sweeps (before the registration: part of organize; after it, at the
                      // registered motion: besides the stages)
};

struct FrameStats {
  std::string solver = "none";  // "7L", "3L1P", "1L2P"; "none" on the first frame; "prediction" when held
  int points = 0;               // valid points after downsampling
  int h_lines = 0, v_lines = 0, planes = 0;
  int fit_step = 1;             // h_lines, v_lines fitted on every fit_step-th row and column (line_selection.hpp)
  int line_step = 1;            // of them, those of every line_step-th row and column kept (registration.max_lines)
  int registered_lines = 0;     // of h_lines + v_lines
  int candidates = 0, plane_candidates = 0;  // of the last pass
  int inliers = 0, plane_inliers = 0;
  double inlier_weight = 0.0;
  double residual_rms = 0.0;
  int iterations = 0;           // RANSAC hypotheses over all passes
  int passes = 0;               // passes that produced an estimate
  bool registered = false;      // an estimate was accepted for this frame
  bool degenerate = false;      // registration failed or was ill-conditioned: the prediction was held (in full, or
                                // along held_directions)
  int held_directions = 0;      // 1..5: a partial estimate, these directions from the prediction; 6: held in full
  Vec6 persistence = Vec6::Ones();  // share of the last motion predicted for this frame, per axis (x y z rx ry rz)
  std::string prediction = "none";  // where the prediction came from: "constant_velocity", "guess" (the caller's),
                                    // "standing_still" (no velocity yet, or registration.constant_velocity off);
                                    // "+imu" appended when its rotation is the caller's rotation_guess
  std::string failure;          // why, when degenerate
  int unmeasured_directions = 0;  // of the velocity, never measured since the first motion was held (at standing
                                  // still): searched on the next frames
  bool recovered = false;       // this frame's motion was found by that search
  bool turn_searched = false;   // the registration failed, held a rotation or kept under a third of the last frame's
                                // inlier weight: the heading was scanned (search_turn)
  bool turn_recovered = false;  // ... and the motion registered from the best-supported heading replaced it
  int window_scans = 0;         // previous scans the motion was registered against (registration.window; 0: none)
  bool deskewed = false;        // the points had times and were moved to the stamp at the predicted velocity
  bool previous_deskewed_again = false;  // ... and the previous scan, deskewed at another velocity, was again at this
                                         // one (its features moved), so that both scans are corrected alike
  int deskewed_again = 0;  // times the sweep was deskewed again at the motion registered for it, and registered again
                           // (sensor.deskew_iterations)
  bool points_refined = false;  // the point-to-plane refinement (points.weight) moved the lines' estimate
  int point_matches = 0;        // ... with this many of the scan's voxel means on a planar voxel of the previous scan
  // The points' verdict on the frame's motion (evidence.*): "agrees", "contradicted" (the points support another
  // motion significantly more: the frame is flagged, degenerate with the fallback covariance), "no_map" (too few
  // points on the map's planes to tell), "off"
  std::string evidence = "off";
  int evidence_matches = 0;     // this scan's checked points on a planar voxel of the local map, at the frame's motion
  int evidence_inliers = 0;     // ... within evidence.inlier_distance of it
  double evidence_z = 0.0;      // McNemar's z of the points' best motion over the lines' (> evidence.significance:
                                // the lines' motion is contradicted)
  StageMilliseconds ms;
};

struct FrameResult {
  double stamp = 0.0;
  RigidTransform pose;   // T_world_sensor
  RigidTransform delta;  // T_prev_curr
  Mat6 covariance = Mat6::Zero();  // of delta, order (x y z rx ry rz)
  FrameStats stats;
};

struct PassOutcome {
  RigidTransform best;
  MotionStats stats;
  bool have = false;
  std::string failure;
  int held_directions = 0;  // of a partial estimate: directions of xi held at the prediction
  Mat6 held_sensitivity = Mat6::Zero();  // ... and how it moves with the prediction (RefineResult)
  Mat6 held_projector = Mat6::Zero();    // ... onto those directions (xi coordinates)
  // Searched without a guess: the first pass's loser of the RANSAC sample and the refined guess, when the two
  // are different motions (the candidates, picked near the guess, favour it: odometry.cpp first_motion).
  bool have_rival = false;
  RigidTransform rival;
};

// An estimate of every direction of the motion (none held at the prediction).
bool registered_in_full(const PassOutcome& outcome);

class Odometry {
 public:
  explicit Odometry(const OdometryConfig& config);

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
  // Registers an already organized range image (full resolution; downsampling is applied here).
  // `image` organized at `organized_step` (1 = full resolution; the step divides config.downsample).
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
  const RigidTransform& pose() const { return pose_; }
  int frames() const { return frames_; }
  const ScanFeatures& last_features() const { return prev_features_; }

 private:
  RigidTransform predict(double stamp, Vec6* persistence) const;  // and the per-axis share it carried
  // The velocity a scan at `stamp` is deskewed at: the prediction's (the guess's; turned by the rotation guess) over
  // the stamp interval; standing still on the first frame and while there is no velocity (but the rotation guess's
  // turn); turning at `sweep_rate` when given.
  SweepVelocity sweep_velocity(double stamp, const RigidTransform* guess, const Mat3* rotation_guess,
                               const Vec3* sweep_rate) const;
  // When the previous scan was deskewed at a velocity that puts its points more than sensor.deskew_tolerance from where
  // `velocity` puts them: moves its features to where `velocity` would have put them (each line's ends by the
  // difference at their columns' times, planes at mid-sweep). True when it did.
  bool deskew_previous_again(const SweepVelocity& velocity);
  // `velocity` plus how much faster this sweep moves than the previous one (sensor.deskew_trend): the least-squares
  // slope per frame of the last registered velocities; the rate's only when it is not a gyro's over the sweep.
  SweepVelocity with_trend(SweepVelocity velocity) const;
  // Whether sweep times [first, last] deskewed at `a` and at `b` put a point 20 m away within
  // sensor.deskew_tolerance of each other.
  bool corrected_alike(const SweepVelocity& a, const SweepVelocity& b, double first, double last) const;
  // sensor.deskew_iterations: while the velocity of the registered motion (over `dt`) puts the sweep's points before
  // its stamp more than sensor.deskew_tolerance from where sweep->velocity put them, moves the scan's features (and the
  // previous scan's) to it and registers again from the estimate. Returns how many times it did.
  int deskew_at_registered(ScanFeatures* features, SweepTimes* sweep, double dt, const RigidTransform& prediction,
                           PassOutcome* outcome, FrameStats* st);
  // The registration of `cur` again from `start` (a registered estimate): against the scans it was registered on
  // (st->window_scans), the candidates re-associated and refined, no RANSAC; `have` only when it observes every
  // direction within registration.max_translation / max_rotation_deg of `prediction`.
  PassOutcome register_again(const ScanFeatures& cur, const RigidTransform& prediction, const RigidTransform& start,
                             const PassOutcome& first, FrameStats* st) const;
  // register_range_image; `sweep` (nullable): the image's sweep times, deskewed at sweep->velocity (updated by
  // deskew_at_registered).
  FrameResult register_image(const RangeImage& image, double stamp, double organize_ms, int organized_step,
                             const RigidTransform* guess, const Mat3* rotation_guess, SweepTimes* sweep);
  template <typename Scalar>
  FrameResult register_sweep(const Scalar* data, std::size_t count, std::size_t stride, const std::int32_t* ring,
                             int rows, int cols, double stamp, const RigidTransform* guess,
                             const Mat3* rotation_guess, const double* time, const Vec3* sweep_rate);
  // The passes of paper §6.3 from `start`; `prediction` bounds the accepted estimates.
  PassOutcome register_features(const ScanFeatures& prev, const ScanFeatures& cur, const RigidTransform& prediction,
                                const RigidTransform& start, bool limit_pairs, FrameStats* st) const;
  // register_features from the coarse search's motion (or without a guess), and again from other starts
  // (odometry.cpp); the result the candidates picked near it support most.
  PassOutcome first_motion(const ScanFeatures& prev, const ScanFeatures& cur, const RigidTransform& prediction,
                           const RigidTransform* coarse_motion, FrameStats* st) const;
  // No velocity yet: the coarse scans' registration, then first_motion from it (or from `prediction`).
  PassOutcome search_first_motion(const ScanFeatures& cur, const ScanFeatures& coarse_cur,
                                  const RigidTransform& prediction, FrameStats* st) const;
  PassOutcome register_on_window(const ScanFeatures& cur, const RigidTransform& prediction, FrameStats* st) const;
  bool observes_every_direction(const ScanFeatures& prev, const ScanFeatures& cur, const RigidTransform& T,
                                FrameStats* st) const;
  bool too_few_pairs_meet(const Correspondences& corr, const LinePairTable& table, const RigidTransform& T,
                          int* inliers) const;
  int unobserved_axes_at(const LinePairTable& table, const RigidTransform& T) const;
  CandidateOptions last_pass_candidates() const;  // the candidates of the last pass: its distance
  // The last pass's candidate pairs of `index` and `cur` under T, refined from T (their times into st).
  struct LastPassFit {
    Correspondences corr;
    CandidateStats stats;
    LinePairTable table;
    RefineResult refined;
    bool converged = false;  // refine_motion's answer
  };
  LastPassFit refit_last_pass(CandidateIndex& index, const ScanFeatures& cur, const RigidTransform& T,
                              FrameStats* st) const;
  // Finite and within registration.max_translation / max_rotation_deg of `prediction`.
  bool within_reach(const RigidTransform& prediction, const RigidTransform& T) const;
  RefineOptions refine_options() const;
  bool weak_translation_peak(CandidateIndex& index, const ScanFeatures& cur, const RigidTransform& estimate,
                             const Mat6* covariance, const RigidTransform& prediction, RigidTransform* peak) const;
  // The best-supported shift of each (origin, unit direction) of `scans`, when one out-supports `estimate`.
  bool translation_peak(CandidateIndex& index, const ScanFeatures& cur, const RigidTransform& estimate,
                        const std::vector<std::pair<RigidTransform, Vec3>>& scans, RigidTransform* peak) const;
  // A motion moved by an amount along a unit axis (shifted, or turned about it).
  using MoveMotion = RigidTransform (*)(const RigidTransform&, const Vec3&, double);
  // The best-supported of the motions `move` gives each (origin, unit axis) of `scans` every `step` out to `steps` per
  // side, scored with `tolerance` inlier thresholds, when one out-supports `estimate`.
  bool support_peak(CandidateIndex& index, const ScanFeatures& cur, const RigidTransform& estimate,
                    const std::vector<std::pair<RigidTransform, Vec3>>& scans, MoveMotion move, double step, int steps,
                    double tolerance, RigidTransform* peak) const;
  // While the velocity along unmeasured_projector_ was never measured: register from the best-supported shift of the
  // estimate along those translations (scanned on prev_scanned / cur_scanned: the coarse scans when coarser) and take
  // that motion instead when it observes every direction and the candidates picked near it support it clearly more
  // (odometry.cpp). True when it did.
  bool search_unmeasured(const ScanFeatures& prev, const ScanFeatures& cur, const ScanFeatures& prev_scanned,
                         const ScanFeatures& cur_scanned, const RigidTransform& prediction, PassOutcome* outcome,
                         FrameStats* st) const;
  // When the registration failed, holds a direction with a rotation in it or kept little of the last frame's support:
  // register from the best-supported heading of the estimate about the ground's up axis and take that motion instead
  // when it observes every direction and the candidates picked near it support it clearly more (odometry.cpp). True
  // when it did.
  bool search_turn(const ScanFeatures& prev, const ScanFeatures& cur, const RigidTransform& prediction,
                   PassOutcome* outcome, FrameStats* st) const;
  // Registers from `start` and replaces *outcome (held: `held`) with that motion when it observes every direction and
  // the candidates picked near it support it kRecoveryMargin times as much as `held`. True when it did.
  bool adopt_if_better(const ScanFeatures& prev, const ScanFeatures& cur, const RigidTransform& prediction,
                       const RigidTransform& held, const RigidTransform& start, PassOutcome* outcome,
                       FrameStats* st) const;
  // The points' check of the lines' outcome (point_evidence.hpp): st->evidence "contradicted" when the local map's
  // points support another motion significantly more; `points`: this scan's checked points.
  void check_with_points(const ScanFeatures& cur, const std::vector<Vec3>& points, const RigidTransform& prediction,
                         PassOutcome* outcome, FrameStats* st);
  // Weighted count of the candidate pairs (built under T as in the first pass after a guess) that meet under T.
  // (threshold_scale: of the inlier threshold; max_distance > 0: instead of candidates.max_distance)
  double support(CandidateIndex& index, const ScanFeatures& cur, const RigidTransform& T,
                 double threshold_scale = 1.0, double max_distance = 0.0) const;

  OdometryConfig config_;
  SensorModel sensor_;
  RigidTransform pose_;
  RigidTransform last_delta_;
  MotionPersistence persistence_;
  Mat6 last_held_projector_ = Mat6::Zero();  // onto the directions of last_delta_ that were the prediction's
  // onto the directions of the velocity no frame has measured since the first motion was held (standing still, a
  // guess nobody measured): searched each frame, and the motion prior does not pull towards them
  Mat6 unmeasured_projector_ = Mat6::Zero();
  double last_inlier_weight_ = 0.0;  // of the last frame when it was registered in full (search_turn), else 0
  double last_dt_ = 0.0;
  double prev_stamp_ = 0.0;
  bool have_velocity_ = false;
  int frames_ = 0;
  int fit_step_ = 1;  // rows and columns the next scan's lines are fitted on (line_selection.hpp)
  ScanFeatures prev_features_;
  ScanFeatures prev_coarse_features_;
  FeatureWindow window_;  // the last registration.window scans' features, in the previous scan's frame
  SweepTimes prev_sweep_;  // the previous scan's, when it had times (sensor.deskew)
  std::deque<SweepVelocity> registered_velocities_;  // of the last sensor.deskew_trend frames, newest first
  bool have_prev_sweep_ = false;
  SurfaceMap prev_surface_;  // the previous scan's surface (points.weight > 0)
  LocalMap local_map_;       // the last registered scans' points, in the previous scan's frame (evidence.*)
  std::shared_ptr<WorkerPool> pool_;  // null with one thread; copies of an Odometry take turns on it
};

// Velocity scaling of a motion: exp(alpha * log(T)) on SO(3) x R^3 (rotation angle and translation scaled).
RigidTransform scale_motion(const RigidTransform& T, double alpha);
// The directions of the subspace `a` (a projector) that the subspace `b` reaches within the angle of `cosine`, as a
// projector.
Mat6 common_directions(const Mat6& a, const Mat6& b, double cosine);

}  // namespace line_odom
