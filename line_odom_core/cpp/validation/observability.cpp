#include "validation/observability.hpp"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <vector>

#include "registration/refine.hpp"

namespace line_odom {

double observability_push(const RigidTransform& motion, const ObservabilityOptions& options) {
  return std::max(options.tolerance, options.motion_share * motion.t.norm());
}

Observability test_observability(const Correspondences& corr, const LinePairTable& pairs, const RigidTransform& T, double threshold,
                                 double min_sine, double push, double significance) {
  Observability out;
  out.push = push;
  const int n = pairs.size();
  std::vector<std::uint8_t> at_estimate(n), pushed(n);
  pairs.inlier_mask(T, threshold, min_sine, 0, n, at_estimate.data());
  double r2 = 0.0;
  int meeting = 0;
  for (int j = 0; j < n; ++j)
    if (at_estimate[j] && pairs.weight(j) > 0.0) {
      r2 += pairs.a_d(j).cross(pairs.a_m(j)).squaredNorm();  // PluckerLine::closest_point_to_origin
      ++meeting;
    }
  out.lever = meeting > 0 ? std::max(1.0, std::sqrt(r2 / meeting)) : 1.0;
  const bool by_line = static_cast<int>(corr.lines_b_index.size()) == n;
  int lines = n;
  if (by_line) {
    lines = 0;
    for (const int l : corr.lines_b_index) lines = std::max(lines, l + 1);
  }
  std::vector<std::uint8_t> line_estimate(lines), line_pushed(lines);
  std::vector<double> line_weight(lines);
  for (int axis = 0; axis < 6; ++axis) {
    double z_axis = 1e300;
    for (const double sign : {-1.0, 1.0}) {
      Vec6 xi = Vec6::Zero();
      xi[axis] = sign * (axis < 3 ? push : push / out.lever);
      pairs.inlier_mask(se3_exp(xi) * T, threshold, min_sine, 0, n, pushed.data());
      // One observation per line of the current scan (its pairs share its errors): it meets under a motion when
      // any of its pairs does, with the largest weight of its pairs.
      std::fill(line_estimate.begin(), line_estimate.end(), 0);
      std::fill(line_pushed.begin(), line_pushed.end(), 0);
      std::fill(line_weight.begin(), line_weight.end(), 0.0);
      for (int j = 0; j < n; ++j) {
        const double w = pairs.weight(j);
        if (!(w > 0.0)) continue;
        const int l = by_line ? corr.lines_b_index[j] : j;
        line_estimate[l] |= at_estimate[j];
        line_pushed[l] |= pushed[j];
        line_weight[l] = std::max(line_weight[l], w);
      }
      double only_estimate = 0.0, only_pushed = 0.0, variance = 0.0;
      for (std::size_t l = 0; l < line_weight.size(); ++l) {
        const double w = line_weight[l];
        if (!(w > 0.0) || line_estimate[l] == line_pushed[l]) continue;
        (line_estimate[l] ? only_estimate : only_pushed) += w;
        variance += w * w;
      }
      const double z = variance > 0.0 ? (only_estimate - only_pushed) / std::sqrt(variance) : 0.0;
      z_axis = std::min(z_axis, z);
    }
    out.z[axis] = z_axis;
    if (z_axis < significance) out.unobserved |= 1 << axis;
  }
  return out;
}

}  // namespace line_odom
