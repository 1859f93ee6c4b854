#include "features/scan_directions.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <vector>

namespace line_odom {

bool ground_plane(const ScanFeatures& features, Plane* ground) {
  int best = 0;
  for (const PlaneFeature& plane : features.planes) {
    const Vec3 n = plane.plane.n.normalized();
    if (plane.support > best && std::abs(n.z()) > std::sqrt(0.5)) {
      best = plane.support;
      const Plane unit = plane.plane.normalized();
      *ground = n.z() > 0.0 ? unit : Plane{-unit.n, -unit.delta};
    }
  }
  return best > 0;
}

Vec3 ground_up(const ScanFeatures& features) {
  Plane ground;
  return ground_plane(features, &ground) ? ground.n : Vec3::UnitZ();
}

Vec3 dominant_line_direction(const ScanFeatures& features, const Vec3& up) {
  constexpr int kBins = 180;
  // a basis of the ground's plane: the sensor's x axis projected onto it, and up x that
  Vec3 e1 = Vec3::UnitX() - up.x() * up;
  if (!(e1.norm() > 1e-6)) e1 = Vec3::UnitY() - up.y() * up;
  e1.normalize();
  const Vec3 e2 = up.cross(e1);
  std::array<double, kBins> length{};
  for (const auto* lines : {&features.h_lines, &features.v_lines})
    for (const LineFeature& line : *lines) {
      const Vec3 d = line.segment.b - line.segment.a;
      const double u = d.dot(e1), v = d.dot(e2);
      const double horizontal = std::hypot(u, v);
      if (!(horizontal > 2.0 * std::abs(d.dot(up)))) continue;  // steeper than 27 degrees
      double angle = std::atan2(v, u);
      if (angle < 0.0) angle += kPi;
      length[std::min(kBins - 1, static_cast<int>(angle / kPi * kBins))] += horizontal;
    }
  int best = 0;
  double best_length = -1.0;
  for (int bin = 0; bin < kBins; ++bin) {
    const double smoothed = length[(bin + kBins - 1) % kBins] + length[bin] + length[(bin + 1) % kBins];
    if (smoothed > best_length) best_length = smoothed, best = bin;
  }
  const double angle = (best + 0.5) * kPi / kBins;
  return std::cos(angle) * e1 + std::sin(angle) * e2;
}

double median_line_range(const ScanFeatures& features) {
  std::vector<double> ranges;
  for (const auto* lines : {&features.h_lines, &features.v_lines})
    for (const LineFeature& line : *lines) ranges.push_back((0.5 * (line.segment.a + line.segment.b)).norm());
  if (ranges.empty()) return 1.0;
  std::nth_element(ranges.begin(), ranges.begin() + ranges.size() / 2, ranges.end());
  return std::max(ranges[ranges.size() / 2], 1e-3);
}

std::vector<Vec3> travel_directions(const ScanFeatures& features) {
  constexpr double kSameDirectionCosine = 0.999;
  std::vector<Vec3> directions{Vec3::UnitX(), Vec3::UnitY(), Vec3::UnitZ()};
  const Vec3 up = ground_up(features);
  const Vec3 level_x = (Vec3::UnitX() - up.x() * up).normalized();
  for (const Vec3& direction : {level_x, dominant_line_direction(features, up)}) {
    bool listed = false;
    for (const Vec3& d : directions) listed = listed || std::abs(d.dot(direction)) >= kSameDirectionCosine;
    if (!listed) directions.push_back(direction);
  }
  return directions;
}

}  // namespace line_odom
