// The motion searched beyond the candidates' reach from the prediction (paper §6.3 needs a guess within the candidate
// distance): the first motion with no velocity yet, a velocity no scan has measured, a turn the prediction missed.
#pragma once

#include <utility>
#include <vector>

#include "odometry/line_registration.hpp"

namespace line_odom {

class MotionSearch {
 public:
  explicit MotionSearch(const LineRegistration& lines) : lines_(lines) {}

  // No velocity yet: a registration on the coarse scans (registration.coarse_downsample) finds the first motion, the
  // configured resolution refines it from there (or from standing still) and from other starts (first_motion).
  PassOutcome search_first_motion(const ScanFeatures& prev, const ScanFeatures& prev_coarse, const ScanFeatures& cur,
                                  const ScanFeatures& coarse_cur, const RigidTransform& prediction,
                                  const RegistrationFrame& frame, FrameStats* st) const;
  // While the velocity along `unmeasured_projector` was never measured: register from the best-supported shift of the
  // estimate along those translations (scanned on prev_scanned / cur_scanned: the coarse scans when coarser) and take
  // that motion instead when it observes every direction and the candidates picked near it support it clearly more.
  // True when it did.
  bool search_unmeasured(const ScanFeatures& prev, const ScanFeatures& cur, const ScanFeatures& prev_scanned,
                         const ScanFeatures& cur_scanned, const RigidTransform& prediction,
                         const Mat6& unmeasured_projector, const RegistrationFrame& frame, PassOutcome* outcome,
                         FrameStats* st) const;
  // When the registration failed, holds a direction with a rotation in it or kept little of the last frame's support
  // (`last_inlier_weight`): register from the best-supported heading of the estimate about the ground's up axis and
  // take that motion instead when it observes every direction and the candidates picked near it support it clearly
  // more. True when it did.
  bool search_turn(const ScanFeatures& prev, const ScanFeatures& cur, const RigidTransform& prediction,
                   double last_inlier_weight, const RegistrationFrame& frame, PassOutcome* outcome,
                   FrameStats* st) const;

 private:
  const OdometryConfig& config() const { return lines_.config(); }
  // register_features from the coarse search's motion (or without a guess), and again from other starts; the result
  // the candidates picked near it support most.
  PassOutcome first_motion(const ScanFeatures& prev, const ScanFeatures& cur, const RigidTransform& prediction,
                           const RigidTransform* coarse_motion, const RegistrationFrame& frame, FrameStats* st) const;
  // Registers from `start` and replaces *outcome (held: `held`) with that motion when it observes every direction and
  // the candidates picked near it support it kRecoveryMargin times as much as `held`. True when it did.
  bool adopt_if_better(const ScanFeatures& prev, const ScanFeatures& cur, const RigidTransform& prediction,
                       const RigidTransform& held, const RigidTransform& start, const RegistrationFrame& frame,
                       PassOutcome* outcome, FrameStats* st) const;
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

  const LineRegistration& lines_;
};

}  // namespace line_odom
