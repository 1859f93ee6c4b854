// The registration of one scan's lines against a previous scan's (paper §6.3): candidate pairs under a start, the
// hybrid RANSAC over {7L, 3L1P, 1L2P} and the refinement, in passes each seeded with the best estimate so far; then the
// checks that the pairs observe the motion, and the partial estimate (registration.partial_updates) that keeps what
// they do observe and holds the rest at the prediction.
#pragma once

#include <cstdint>
#include <memory>
#include <string>

#include "common/scan_features.hpp"
#include "common/types.hpp"
#include "common/worker_pool.hpp"
#include "odometry/frame_result.hpp"
#include "odometry/odometry_config.hpp"
#include "registration/candidates.hpp"
#include "registration/line_pair_table.hpp"
#include "registration/motion_estimation.hpp"
#include "registration/refine.hpp"

namespace line_odom {

struct PassOutcome {
  RigidTransform best;
  MotionStats stats;
  bool have = false;
  std::string failure;
  int held_directions = 0;  // of a partial estimate: directions of xi held at the prediction
  Mat6 held_sensitivity = Mat6::Zero();  // ... and how it moves with the prediction (RefineResult)
  Mat6 held_projector = Mat6::Zero();    // ... onto those directions (xi coordinates)
  // Searched without a guess: the first pass's loser of the RANSAC sample and the refined guess, when the two
  // are different motions (the candidates, picked near the guess, favour it: motion_search.cpp first_motion).
  bool have_rival = false;
  RigidTransform rival;
  // The last pass's candidate pairs (built under its start, close to `best`), for the checks after the passes.
  std::shared_ptr<const Correspondences> candidates;
};

// An estimate of every direction of the motion (none held at the prediction).
bool registered_in_full(const PassOutcome& outcome);

// The orthogonal projector onto the span of the (independent) columns of `basis`.
Mat6 subspace_projector(const Eigen::Matrix<double, 6, Eigen::Dynamic>& basis);

// Which frame is registered: it seeds the RANSAC, and a partial estimate holds directions only at a velocity.
struct RegistrationFrame {
  std::uint64_t index = 0;
  bool have_velocity = false;
};

class LineRegistration {
 public:
  LineRegistration(const OdometryConfig& config, WorkerPool* pool) : config_(&config), pool_(pool) {}

  // The passes of paper §6.3 from `start`; `prediction` bounds the accepted estimates. `limit_pairs`: the candidates
  // keep candidates.max_pairs_per_line partners per line from the first pass (else
  // registration.first_motion_pairs_per_line on the first).
  PassOutcome register_features(const ScanFeatures& prev, const ScanFeatures& cur, const RigidTransform& prediction,
                                const RigidTransform& start, bool limit_pairs, const RegistrationFrame& frame,
                                FrameStats* st) const;
  // ... against the lines `prev_index` holds (its listings near cur's lines kept for later searches).
  PassOutcome register_features(CandidateIndex& prev_index, const ScanFeatures& cur, const RigidTransform& prediction,
                                const RigidTransform& start, bool limit_pairs, const RegistrationFrame& frame,
                                FrameStats* st) const;
  // `cur` registered again from `start` (a registered estimate) against `prev`: the candidates re-associated and
  // refined, no RANSAC; `have` only when it observes every direction within reach of `prediction`.
  PassOutcome register_again(const ScanFeatures& prev, const ScanFeatures& cur, const RigidTransform& prediction,
                             const RigidTransform& start, const PassOutcome& first, FrameStats* st) const;
  // Whether the pairs of `cur` with `subset` of the lines `index` holds alone (picked under T at the last pass's
  // candidate distance) observe every direction of T: a well-conditioned refinement, enough of them meeting, no axis a
  // push along which keeps them. (A window's index and its newest scan: that scan's pairs, its listings shared.)
  bool observes_every_direction(CandidateIndex& index, const CandidateSubset& subset, const ScanFeatures& cur,
                                const RigidTransform& T, FrameStats* st) const;
  // Weighted count of the candidate pairs (built under T as in the first pass after a guess) that meet under T.
  // (threshold_scale: of the inlier threshold; max_distance > 0: instead of candidates.max_distance)
  double support(CandidateIndex& index, const ScanFeatures& cur, const RigidTransform& T, double threshold_scale = 1.0,
                 double max_distance = 0.0) const;
  // The last pass's candidate pairs of `index` and `cur` under T, refined from T (their times into st).
  struct LastPassFit {
    Correspondences corr;
    CandidateStats stats;
    LinePairTable table;
    RefineResult refined;
    bool converged = false;  // refine_motion's answer
  };
  LastPassFit refit_last_pass(CandidateIndex& index, const ScanFeatures& cur, const RigidTransform& T,
                              FrameStats* st, const CandidateSubset& subset = CandidateSubset{}) const;
  CandidateOptions last_pass_candidates() const;  // the candidates of the last pass: its distance
  RefineOptions refine_options() const;
  // Finite and within registration.max_translation / max_rotation_deg of `prediction`.
  bool within_reach(const RigidTransform& prediction, const RigidTransform& T) const;
  // `outcome` with the directions of `axes` (bits of xi) and of `projector` (nullable, xi coordinates) held at
  // `held`, the others refined on `corr` from the outcome's estimate (refine.hpp: refine_motion_partial); false when
  // that refinement does not hold (nothing, or everything, to hold).
  bool hold_directions(const Correspondences& corr, const LinePairTable& table, const RigidTransform& held, int axes,
                       const Mat6* projector, PassOutcome* outcome) const;
  const OdometryConfig& config() const { return *config_; }
  WorkerPool* pool() const { return pool_; }

 private:
  struct Passes;  // (line_registration.cpp)
  void run_pass(int pass, CandidateIndex& prev_index, const ScanFeatures& cur, const RigidTransform& prediction,
                bool limit_pairs, const RegistrationFrame& frame, Passes* s, FrameStats* st) const;
  int unobserved_after_passes(Passes* s) const;
  void hold_unobserved(const RigidTransform& prediction, const RegistrationFrame& frame, int axes, Passes* s,
                       PassOutcome* out) const;
  bool too_few_pairs_meet(const Correspondences& corr, const LinePairTable& table, const RigidTransform& T,
                          int* inliers) const;
  int unobserved_axes_at(const LinePairTable& table, const RigidTransform& T) const;

  const OdometryConfig* config_;
  WorkerPool* pool_;
};

}  // namespace line_odom
