#include "validation/local_map.hpp"

#include <algorithm>

namespace line_odom {

void LocalMap::add(const std::vector<Vec3>& points, const RigidTransform& pose) {
  if (max_scans_ < 1) return;
  const std::size_t per_scan = static_cast<std::size_t>(max_points_);
  const std::size_t step = std::max<std::size_t>(1, (points.size() + per_scan - 1) / per_scan);
  std::vector<Vec3> world;
  world.reserve(points.size() / step + 1);
  for (std::size_t i = 0; i < points.size(); i += step) world.push_back(pose.apply(points[i]));
  scans_.push_back(std::move(world));
  while (static_cast<int>(scans_.size()) > max_scans_) scans_.pop_front();
  anchor(pose);
}

void LocalMap::anchor(const RigidTransform& pose) {
  merged_.clear();
  const std::size_t per_scan = static_cast<std::size_t>(std::max<std::size_t>(1, max_points_ / scans_.size()));
  for (const auto& scan : scans_) {
    const std::size_t step = std::max<std::size_t>(1, (scan.size() + per_scan - 1) / per_scan);
    for (std::size_t i = 0; i < scan.size(); i += step) merged_.push_back(scan[i]);
  }
  surface_.build(merged_, voxel_, pose.inverse());
}

void LocalMap::clear() {
  scans_.clear();
  merged_.clear();
  surface_ = SurfaceMap{};
}

}  // namespace line_odom
