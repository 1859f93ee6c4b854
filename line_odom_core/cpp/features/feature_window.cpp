#include "features/feature_window.hpp"

#include <algorithm>
#include <cmath>

namespace line_odom {

namespace {

int nearest_cluster(const Vec3& normal, const std::array<Vec3, 3>& directions) {
  if (normal.isZero()) return -1;
  int best = -1;
  double best_cos = std::cos(45.0 * kPi / 180.0);
  for (int k = 0; k < 3; ++k) {
    const double c = std::abs(normal.dot(directions[k]));
    if (c > best_cos) best_cos = c, best = k;
  }
  return best;
}

void append_moved(const std::vector<LineFeature>& lines, const RigidTransform& T, int plane_offset,
                  const std::array<Vec3, 3>& directions, std::vector<LineFeature>* out) {
  for (const LineFeature& line : lines) {
    LineFeature moved = line;
    moved.segment = line.segment.moved(T);
    moved.line = line.line.moved(T);
    moved.normal = T.R * line.normal;
    moved.cluster = line.cluster < 0 ? -1 : nearest_cluster(moved.normal, directions);
    moved.plane = line.plane < 0 ? -1 : line.plane + plane_offset;
    out->push_back(moved);
  }
}

}  // namespace

void FeatureWindow::push(const ScanFeatures& next, const RigidTransform& delta, bool measured) {
  if (!measured) entries_.clear();
  const RigidTransform next_from_newest = delta.inverse();
  for (Entry& e : entries_) e.T_newest = next_from_newest * e.T_newest;
  entries_.push_front({next, RigidTransform::identity()});
  while (entries_.size() > static_cast<std::size_t>(scans_)) entries_.pop_back();
}

std::size_t FeatureWindow::scans_within(int max_lines) const {
  std::size_t scans = 0, lines = 0;
  for (const Entry& e : entries_) {
    if (scans > 0 && max_lines > 0 && lines >= static_cast<std::size_t>(max_lines)) break;
    lines += e.features.h_lines.size() + e.features.v_lines.size();
    ++scans;
  }
  return scans;
}

ScanFeatures FeatureWindow::merged(std::size_t scans) const {
  if (entries_.empty()) return {};
  ScanFeatures out = entries_.front().features;
  for (std::size_t i = 1; i < std::min(scans, entries_.size()); ++i) {
    const Entry& e = entries_[i];
    const int plane_offset = static_cast<int>(out.planes.size());
    for (const PlaneFeature& p : e.features.planes)
      out.planes.push_back({p.plane.moved(e.T_newest), e.T_newest.apply(p.centroid), p.support, p.rms});
    append_moved(e.features.h_lines, e.T_newest, plane_offset, out.cluster_directions, &out.h_lines);
    append_moved(e.features.v_lines, e.T_newest, plane_offset, out.cluster_directions, &out.v_lines);
  }
  return out;
}

}  // namespace line_odom
