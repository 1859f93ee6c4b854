#include "registration/surface_map.hpp"

#include <Eigen/Eigenvalues>
#include <algorithm>
#include <cmath>
#include <limits>

#include "common/splitmix64.hpp"

namespace line_odom {

namespace {
constexpr std::uint64_t kEmpty = std::numeric_limits<std::uint64_t>::max();
constexpr std::int64_t kBias = 1 << 20;  // 21 bits per axis
}  // namespace

std::int64_t voxel_cell(double v, double voxel) {
  constexpr double kFarthest = 1e15;
  return static_cast<std::int64_t>(std::clamp(std::floor(v / voxel), -kFarthest, kFarthest));
}

std::uint64_t voxel_key(std::int64_t x, std::int64_t y, std::int64_t z) {
  const auto field = [](std::int64_t c) { return static_cast<std::uint64_t>((c + kBias) & ((std::int64_t{1} << 21) - 1)); };
  return field(x) << 42 | field(y) << 21 | field(z);
}

void VoxelTable::reset(std::size_t expected) {
  std::size_t capacity = 16;
  while (capacity < 2 * expected) capacity <<= 1;
  keys_.assign(capacity, kEmpty);
  slots_.assign(capacity, -1);
  mask_ = capacity - 1;
  size_ = 0;
}

std::int32_t VoxelTable::insert(std::uint64_t key, bool* inserted) {
  if (static_cast<std::size_t>(size_ + 1) * 2 > keys_.size()) {  // grow: keep the load under a half
    std::vector<std::uint64_t> keys = std::move(keys_);
    std::vector<std::int32_t> slots = std::move(slots_);
    const std::int32_t size = size_;
    reset(keys.size());
    for (std::size_t i = 0; i < keys.size(); ++i) {
      if (keys[i] == kEmpty) continue;
      std::uint64_t h = splitmix64_mix(keys[i]) & mask_;
      while (keys_[h] != kEmpty) h = (h + 1) & mask_;
      keys_[h] = keys[i];
      slots_[h] = slots[i];
    }
    size_ = size;
  }
  std::uint64_t h = splitmix64_mix(key) & mask_;
  while (keys_[h] != kEmpty) {
    if (keys_[h] == key) {
      *inserted = false;
      return slots_[h];
    }
    h = (h + 1) & mask_;
  }
  keys_[h] = key;
  slots_[h] = size_++;
  *inserted = true;
  return slots_[h];
}

std::int32_t VoxelTable::find(std::uint64_t key) const {
  if (keys_.empty()) return -1;
  std::uint64_t h = splitmix64_mix(key) & mask_;
  while (keys_[h] != kEmpty) {
    if (keys_[h] == key) return slots_[h];
    h = (h + 1) & mask_;
  }
  return -1;
}

std::uint64_t SurfaceMap::key_of(const Vec3& p) const {
  return voxel_key(voxel_cell(p.x(), voxel_), voxel_cell(p.y(), voxel_), voxel_cell(p.z(), voxel_));
}

void SurfaceMap::begin(double voxel, std::size_t expected) {
  voxel_ = voxel;
  table_.reset(expected);
  origins_.clear();
  means_.clear();
  scatter_.clear();
  counts_.clear();
}

void SurfaceMap::add(const Vec3& p) {
  bool inserted = false;
  const std::int32_t slot = table_.insert(key_of(p), &inserted);
  if (inserted) {
    origins_.push_back(p);
    means_.push_back(Vec3::Zero());
    scatter_.push_back(Mat3::Zero());
    counts_.push_back(1);
    return;
  }
  const Vec3 d = p - origins_[slot];
  means_[slot] += d;
  scatter_[slot].noalias() += d * d.transpose();
  ++counts_[slot];
}

void SurfaceMap::finish() {
  for (std::size_t i = 0; i < means_.size(); ++i) {
    const Vec3 offset = means_[i] / counts_[i];  // of the mean from the origin
    scatter_[i] = scatter_[i] / counts_[i] - offset * offset.transpose();  // the scatter about the mean
    means_[i] = origins_[i] + offset;
  }
  planes_.assign(means_.size(), VoxelPlane{});
  plane_done_.assign(means_.size(), 0);
}

void SurfaceMap::build(const RangeImage& image, double voxel, int stride) {
  stride = std::max(1, stride);
  begin(voxel, image.points.size() / (8 * stride * stride) + 16);
  for (int r = 0; r < image.rows; r += stride)
    for (int c = 0; c < image.cols; c += stride)
      if (image.is_valid(r, c)) add(image.at(r, c));
  finish();
}

void SurfaceMap::build(const std::vector<Vec3>& points, double voxel, const RigidTransform& to_map) {
  begin(voxel, points.size() / 8 + 16);
  for (const Vec3& p : points) add(to_map.apply(p));
  finish();
}

int SurfaceMap::voxel_of(const Vec3& q) const { return table_.find(key_of(q)); }

const VoxelPlane& SurfaceMap::plane(int index, int min_points, double min_planarity) {
  if (plane_done_[index]) return planes_[index];
  plane_done_[index] = 1;
  VoxelPlane& out = planes_[index];
  if (counts_[index] < std::max(3, min_points)) return out;
  Eigen::SelfAdjointEigenSolver<Mat3> es;
  es.computeDirect(scatter_[index]);
  const Vec3 l = es.eigenvalues();
  if (!(l(2) > 0.0) || (l(1) - l(0)) / l(2) < min_planarity) return out;
  out.normal = es.eigenvectors().col(0).normalized();
  out.planar = out.normal.allFinite();
  return out;
}

bool SurfaceMap::residual(const Vec3& q, int min_points, double min_planarity, PlaneResidual* out) {
  const int voxel = voxel_of(q);
  if (voxel < 0) return false;
  const VoxelPlane& p = plane(voxel, min_points, min_planarity);
  if (!p.planar) return false;
  out->voxel = voxel;
  out->normal = p.normal;
  out->r = p.normal.dot(q - means_[voxel]);
  out->J << p.normal, q.cross(p.normal);
  return true;
}

}  // namespace line_odom
