// A small local map of the last registered scans' points (beyond the paper): the surface a scan's motion is checked
// against (point_evidence.hpp). A sparse scan's own voxels hold too few points for a plane; a few scans together do.
#pragma once

#include <cstddef>
#include <deque>
#include <vector>

#include "common/types.hpp"
#include "registration/surface_map.hpp"

namespace line_odom {

class LocalMap {
 public:
  LocalMap() = default;
  // Keeps the last `scans` scans, `points` points in all, spread evenly over them: a dense and a sparse sensor give
  // maps of the same size, and the first scans of a run a map as dense as a full one.
  LocalMap(int scans, int points, double voxel) : max_scans_(scans), max_points_(points), voxel_(voxel) {}

  // Adds a scan's points (sensor frame) at its pose T_world_sensor and rebuilds the voxels in that scan's frame.
  void add(const std::vector<Vec3>& points, const RigidTransform& pose);
  // The voxels rebuilt in the frame of `pose` (a held frame: the map stays, its anchor moves).
  void anchor(const RigidTransform& pose);
  void clear();

  bool empty() const { return scans_.empty(); }
  int scans() const { return static_cast<int>(scans_.size()); }
  SurfaceMap& surface() { return surface_; }  // in the frame of the last add / anchor

 private:
  int max_scans_ = 10;
  int max_points_ = 40000;
  double voxel_ = 1.0;
  std::deque<std::vector<Vec3>> scans_;  // world frame
  std::vector<Vec3> merged_;
  SurfaceMap surface_;
};

}  // namespace line_odom
