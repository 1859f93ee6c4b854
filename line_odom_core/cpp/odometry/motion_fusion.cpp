#include "odometry/motion_fusion.hpp"

#include <Eigen/Eigenvalues>

#include <algorithm>

#include "registration/refine.hpp"

namespace line_odom {

Mat6 motion_covariance(double translation_sigma, double rotation_sigma) {
  Mat6 covariance = Mat6::Zero();
  const double t2 = translation_sigma * translation_sigma, r2 = rotation_sigma * rotation_sigma;
  covariance.diagonal() << t2, t2, t2, r2, r2, r2;
  return covariance;
}

Mat6 reference_covariance(const RegistrationOptions& reg, bool have_velocity) {
  if (have_velocity && reg.motion_prior_translation_sigma > 0.0)
    return motion_covariance(reg.motion_prior_translation_sigma, reg.motion_prior_rotation_sigma_deg * kPi / 180.0);
  return motion_covariance(reg.fallback_translation_sigma, reg.fallback_rotation_sigma_deg * kPi / 180.0);
}

FusedMotion fuse_motion(const PassOutcome& outcome, const RigidTransform& prediction, const RigidTransform& reference,
                        const RegistrationOptions& reg, bool have_velocity, const Mat6& unmeasured) {
  FusedMotion out;
  const MotionStats& stats = outcome.stats;
  const double ts = reg.fallback_translation_sigma, rs = reg.fallback_rotation_sigma_deg * kPi / 180.0;
  if (!(outcome.have && !stats.degenerate && stats.covariance.allFinite())) {
    out.failure = outcome.failure;
    if (outcome.have && out.failure.empty()) out.failure = "degenerate constraints (ill-conditioned refinement)";
    if (out.failure.empty()) out.failure = "registration failed";
    out.delta = reference;
    out.covariance = motion_covariance(ts, rs);
    if (outcome.have) out.covariance = out.covariance.cwiseMax(stats.covariance);
    out.degenerate = true;
    out.held_directions = 6;
    out.held_projector = Mat6::Identity();
    return out;
  }
  out.registered = true;
  out.delta = outcome.best;
  const int constraints = std::max(1, stats.inliers + stats.plane_inliers);
  out.covariance =
      stats.covariance * (reg.covariance_per_inlier ? reg.covariance_scale * constraints : reg.covariance_scale);
  const double pt = reg.motion_prior_translation_sigma, pr = reg.motion_prior_rotation_sigma_deg * kPi / 180.0;
  const Mat6 prior = motion_covariance(pt, pr);
  const bool fuse_prior = have_velocity && pt > 0.0;
  if (outcome.held_directions > 0) {
    const Vec6 xi = motion_difference(outcome.best, reference);
    // A partial estimate says nothing along the held directions (covariance zero there, refine.hpp): fused in
    // information form, the reference alone speaks there; then at least the fallback variance along them. They are
    // the covariance's held_directions smallest eigen-directions: their rounding residue can exceed 1e-12 of the
    // largest and must not pass for information.
    Eigen::SelfAdjointEigenSolver<Mat6> es(out.covariance);
    const double lmax = std::max(es.eigenvalues()(5), 1e-300);
    Vec6 inv = Vec6::Zero();
    Mat6 held = Mat6::Zero();
    int held_count = 0;
    for (int k = 0; k < 6; ++k) {
      if (k >= outcome.held_directions && es.eigenvalues()(k) > 1e-12 * lmax) inv(k) = 1.0 / es.eigenvalues()(k);
      else held.col(held_count++) = es.eigenvectors().col(k);
    }
    const Mat6 information = es.eigenvectors() * inv.asDiagonal() * es.eigenvectors().transpose();
    out.held_projector = held * held.transpose();
    // The estimate's error is (I - G) e_lines + G e_reference (G = held_sensitivity): the free directions are coupled
    // to the held ones, so the reference's error reaches them too. Fused, K = fused P_f^-1:
    // error (I - K + K G) e_reference + K (I - G) e_lines.
    const Mat6& G = outcome.held_sensitivity;
    Mat6 gain = Mat6::Identity();
    if (fuse_prior) {
      const Mat6 fused_covariance = (prior.inverse() + information).inverse();
      const Vec6 fused = fused_covariance * (information * xi);
      if (fused.allFinite() && fused_covariance.allFinite()) {
        out.delta = apply_motion_difference(fused, reference);
        gain = fused_covariance * information;
      }
    }
    const Mat6 from_reference = Mat6::Identity() - gain + gain * G;
    const Mat6 propagated = from_reference * reference_covariance(reg, have_velocity) * from_reference.transpose() +
                            gain * out.covariance * gain.transpose();
    if (propagated.allFinite()) out.covariance = propagated;
    for (int k = 0; k < held_count; ++k) {
      const Vec6 u = held.col(k);
      const double floor = ts * ts * u.head<3>().squaredNorm() + rs * rs * u.tail<3>().squaredNorm();
      const double variance = u.dot(out.covariance * u);
      if (variance < floor) out.covariance += (floor - variance) * u * u.transpose();
    }
    out.covariance = 0.5 * (out.covariance + out.covariance.transpose());
    out.degenerate = true;
    out.held_directions = outcome.held_directions;
    out.failure = outcome.failure;
  } else if (fuse_prior) {
    const Vec6 xi = motion_difference(outcome.best, prediction);
    // MAP fusion with the constant-velocity prior on the left perturbation exp(xi) * prediction: directions the lines
    // observe poorly (large covariance) stay with the prediction. Covariance (I - K) P of the Kalman update with
    // H = I, K = P (P + C)^-1: (P^-1 + C^-1)^-1, below both the prior's and the estimate's.
    Mat6 gain = prior * (prior + out.covariance).inverse();
    Mat6 fused_covariance = (Mat6::Identity() - gain) * prior;
    if (!unmeasured.isZero()) {
      // No prior along a velocity nobody measured (its prediction is standing still): there the estimate stands.
      const Mat6 free = Mat6::Identity() - unmeasured;
      const Mat6 information = out.covariance.inverse();
      fused_covariance = (free * prior.inverse() * free + information).inverse();
      gain = fused_covariance * information;
    }
    const Vec6 fused = gain * xi;
    if (fused.allFinite() && fused_covariance.allFinite()) {
      out.delta = apply_motion_difference(fused, prediction);
      out.covariance = 0.5 * (fused_covariance + fused_covariance.transpose());
    }
  }
  return out;
}

Mat6 covering(const Mat6& covariance, const RigidTransform& delta, const RigidTransform& other, const Mat6& along) {
  const Vec6 difference = along * motion_difference(other, delta);
  if (!difference.allFinite()) return covariance;
  return covariance + difference * difference.transpose();
}

}  // namespace line_odom
