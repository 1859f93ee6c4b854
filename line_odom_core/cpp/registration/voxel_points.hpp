// A local map of the last scans' points in the odometry frame (beyond the paper): cubic voxels holding at most a few
// points each, the voxels farther than the sensor's range from its last position dropped. The map the scan's points
// are aligned to where the line intersections do not pin the motion down (point_alignment.hpp), as in KISS-ICP
// (Vizzo et al., RA-L 2023).
#pragma once

#include <cstdint>
#include <vector>

#include "common/types.hpp"
#include "registration/surface_map.hpp"

namespace line_odom {

class VoxelPointMap {
 public:
  VoxelPointMap() = default;
  // `same_place` (m; negative: never): a full voxel's points that a scan added within this of where another scan in the
  // voxel stood give way to new points, the oldest first; the other points stay (the first points, as KISS-ICP's map).
  VoxelPointMap(double voxel, int max_points_per_voxel, double same_place = -1.0)
      : voxel_(voxel), per_voxel_(max_points_per_voxel), same_place_(same_place) {}

  // Adds `points` (sensor frame) at `pose` (T_world_sensor), up to the voxel's capacity (or in place of its points
  // from a place sampled before, same_place), then drops the voxels farther than `max_distance` from the pose's
  // position. `ground` (nullable, sensor frame): the ground plane the points were measured over (ground_plane of their
  // scan's features).
  void add(const std::vector<Vec3>& points, const RigidTransform& pose, double max_distance,
           const Plane* ground = nullptr);
  void clear();
  bool empty() const { return voxels_.empty(); }
  std::size_t voxels() const { return voxels_.size(); }
  double voxel() const { return voxel_; }

  // The map point nearest to q within `max_distance`: up to a voxel away, among the 8 voxels around the voxel corner
  // nearest q (exact within half a voxel); farther, among the 27 around q's voxel. False when there is none.
  // `voxel` (nullable): the index of the voxel holding it.
  bool nearest(const Vec3& q, double max_distance, Vec3* nearest_point, int* voxel = nullptr) const;
  // The plane of a voxel's points (mean and unit normal), computed once per change of the voxel: false when they are
  // too few or do not spread over a plane (a single ring's arc, a pole). With `ground`, points on the ground (within a
  // voxel of the ground plane of the scans that added them) that are one point or run along it (a ring's arc) are the
  // ground's plane there: where along the ground a ring sits is where the sensor put it, not where the world is
  // (matched point to point, a sparse scan's rings would hold it at the last scan's place).
  bool plane(int voxel, Vec3* mean, Vec3* normal, bool ground) const;

 private:
  struct Voxel {
    std::int64_t x, y, z;
    int first;  // into points_: per_voxel_ slots from here
    int count;
    int changes = 0;               // points added
    int resampled = 0;             // points from a place another scan in the voxel stood at (same_place)
    bool on_ground = false;        // every point within a voxel of its scan's ground plane
    Vec3 ground_normal = Vec3::Zero();
    mutable int plane_count = -1;  // the changes its plane was computed at
    mutable bool planar = false;      // its points spread over a plane
    mutable bool ground_arc = false;  // ... or lie on the ground as one point or a ring's arc along it
    mutable Vec3 mean = Vec3::Zero(), normal = Vec3::Zero();
  };
  void rebuild_table();
  // The scans' numbers made consecutive over those whose points the map still holds (in their order): the places of
  // scans it no longer holds are forgotten, so a sensor standing for hours does not grow the map.
  void renumber_scans();
  static constexpr std::size_t kMinRenumbered = 1024;  // scans remembered before the first renumbering

  double voxel_ = 1.0;
  int per_voxel_ = 20;
  double same_place_ = -1.0;
  VoxelTable table_;
  std::vector<Voxel> voxels_;
  // Per point (per_voxel_ slots per voxel): where it is, the scan that added it (into scan_places_), whether it lay
  // within a voxel of that scan's ground plane, and whether another scan in its voxel stood within same_place_.
  std::vector<Vec3> points_;
  std::vector<int> point_scans_;
  std::vector<unsigned char> points_on_ground_, points_resampled_;
  std::vector<Vec3> scan_places_;  // the sensor's position of each add() (renumber_scans)
};

// The points one per cube of `voxel` metres (the first of each), in input order: a scan thinned evenly in space.
std::vector<Vec3> voxel_downsample(const std::vector<Vec3>& points, double voxel);

}  // namespace line_odom
