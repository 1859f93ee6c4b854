// A scan as a surface for point-to-plane residuals (point_refine.hpp): its points binned in cubic voxels, each voxel
// keeping the mean and scatter of its points and, asked for lazily, the plane they lie on (as in NDT-style voxel
// maps). Built once per scan: the next frame's partners, and this frame's points (the voxel means).
#pragma once

#include <cstdint>
#include <vector>

#include "common/scan_features.hpp"
#include "common/types.hpp"

namespace line_odom {

// Voxel key -> slot, open addressing with linear probing. Written here because the map is rebuilt every scan
// (~10^5 points binned) and queried ~10^5 times a frame: std::unordered_map allocates a node per voxel and chases a
// pointer per lookup.
class VoxelTable {
 public:
  void reset(std::size_t expected);
  // The slot of `key`, inserting it with the next free slot number when absent.
  std::int32_t insert(std::uint64_t key, bool* inserted);
  std::int32_t find(std::uint64_t key) const;  // -1 when absent

 private:
  std::vector<std::uint64_t> keys_;
  std::vector<std::int32_t> slots_;
  std::uint64_t mask_ = 0;
  std::int32_t size_ = 0;
};

// The cell of coordinate `v` among cubes of `voxel` metres (clamped: a cast beyond int64 would be undefined; points
// are finite, not bounded).
std::int64_t voxel_cell(double v, double voxel);
// A cell's key for VoxelTable: 21 bits per axis, +-1 million cells (+-10 km at points.voxel's 1 cm), wrapping beyond.
std::uint64_t voxel_key(std::int64_t x, std::int64_t y, std::int64_t z);

struct VoxelPlane {
  Vec3 normal = Vec3::Zero();
  bool planar = false;  // enough points, and flat: (l1 - l0) / l2 >= min_planarity of their scatter's eigenvalues
};

// A point's residual against the plane of the voxel it falls in: r = n . (q - mean), and J, the row of r under a left
// perturbation (x y z rx ry rz) of the motion that put the point at q.
struct PlaneResidual {
  double r = 0.0;
  Vec3 normal = Vec3::Zero();
  Vec6 J = Vec6::Zero();
  int voxel = -1;
};

class SurfaceMap {
 public:
  // Every `stride`-th row and column of the image's valid points, binned in cubes of `voxel` metres.
  void build(const RangeImage& image, double voxel, int stride);
  // `points` moved by `to_map`, binned in cubes of `voxel` metres.
  void build(const std::vector<Vec3>& points, double voxel, const RigidTransform& to_map);
  bool empty() const { return means_.empty(); }
  std::size_t size() const { return means_.size(); }
  int voxel_of(const Vec3& q) const;  // the voxel holding q, -1 when empty
  const Vec3& mean(int index) const { return means_[index]; }
  int count(int index) const { return counts_[index]; }
  // The plane of the voxel's points (at least min_points of them), computed once.
  const VoxelPlane& plane(int index, int min_points, double min_planarity);
  // The residual of q against its voxel's plane; false when q's voxel is empty or not planar.
  bool residual(const Vec3& q, int min_points, double min_planarity, PlaneResidual* out);

 private:
  std::uint64_t key_of(const Vec3& p) const;
  void begin(double voxel, std::size_t expected);
  void add(const Vec3& p);
  void finish();

  double voxel_ = 0.5;
  VoxelTable table_;
  std::vector<Vec3> origins_;  // each voxel's first point: the scatter is summed about it (no cancellation far out)
  std::vector<Vec3> means_;    // while binning the summed offsets from the origin
  std::vector<Mat3> scatter_;  // while binning the summed outer products about the origin, then about the mean
  std::vector<int> counts_;
  std::vector<VoxelPlane> planes_;
  std::vector<std::uint8_t> plane_done_;
};

}  // namespace line_odom
