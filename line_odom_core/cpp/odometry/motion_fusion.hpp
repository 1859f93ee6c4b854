// The frame's motion and covariance from the registration's outcome and the motion model: fused with the
// constant-velocity prior (registration.motion_prior_*), a partial estimate's held directions taken from the reference
// they were held at with at least the fallback variance, a failed registration holding the reference in full.
#pragma once

#include <string>

#include "common/types.hpp"
#include "odometry/line_registration.hpp"
#include "odometry/odometry_config.hpp"

namespace line_odom {

struct FusedMotion {
  RigidTransform delta;                 // T_prev_curr
  Mat6 covariance = Mat6::Zero();       // of delta (x y z rx ry rz)
  Mat6 held_projector = Mat6::Zero();   // onto the directions taken from the reference, not the scans
  bool registered = false;              // an estimate was accepted
  bool degenerate = false;              // ... but held the reference in some direction, or nothing was accepted
  int held_directions = 0;              // 6: nothing accepted
  std::string failure;
};

// Independent sigmas per axis: translation (m) on x y z, rotation (rad) on rx ry rz.
Mat6 motion_covariance(double translation_sigma, double rotation_sigma);

// How far the reference a frame's held directions are held at may be off: the constant-velocity prior's sigmas when a
// velocity is known and the prior is fused (registration.motion_prior_*), else the fallback's.
Mat6 reference_covariance(const RegistrationOptions& options, bool have_velocity);

// `reference`: what the outcome's held directions were held at, and what a failed registration holds (the prediction,
// or the points' motion); `prediction`: the constant-velocity prior; `fuse_prior`: a velocity was known before this
// frame; `unmeasured`: the velocity's directions nobody measured (no prior pulls there).
FusedMotion fuse_motion(const PassOutcome& outcome, const RigidTransform& prediction, const RigidTransform& reference,
                        const RegistrationOptions& options, bool fuse_prior, const Mat6& unmeasured);

// `covariance` of `delta` widened to cover `other`, an independent measurement of the same motion: plus d d^T, d the
// difference of the two (motion_difference). Two independent estimates differ by the sum of their errors, so their
// difference is a sample of the error the covariance must allow; with it, `other` lies within one standard deviation.
// `along` (a projector onto directions of x y z rx ry rz): only the difference along those.
Mat6 covering(const Mat6& covariance, const RigidTransform& delta, const RigidTransform& other,
              const Mat6& along = Mat6::Identity());

}  // namespace line_odom
