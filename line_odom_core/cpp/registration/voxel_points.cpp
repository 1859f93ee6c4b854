#include "registration/voxel_points.hpp"

#include <Eigen/Eigenvalues>

#include <algorithm>
#include <cmath>
#include <limits>

namespace line_odom {

void VoxelPointMap::clear() {
  table_ = VoxelTable{};
  voxels_.clear();
  points_.clear();
  point_scans_.clear();
  points_on_ground_.clear();
  points_resampled_.clear();
  scan_places_.clear();
}

void VoxelPointMap::renumber_scans() {
  std::vector<int> kept;
  for (const Voxel& v : voxels_)
    kept.insert(kept.end(), point_scans_.begin() + v.first, point_scans_.begin() + v.first + v.count);
  std::sort(kept.begin(), kept.end());
  kept.erase(std::unique(kept.begin(), kept.end()), kept.end());
  for (const Voxel& v : voxels_)
    for (int k = v.first; k < v.first + v.count; ++k)
      point_scans_[k] = static_cast<int>(std::lower_bound(kept.begin(), kept.end(), point_scans_[k]) - kept.begin());
  std::vector<Vec3> places(kept.size());
  for (std::size_t i = 0; i < kept.size(); ++i) places[i] = scan_places_[kept[i]];
  scan_places_ = std::move(places);
}

void VoxelPointMap::rebuild_table() {
  table_.reset(voxels_.size());
  for (std::size_t i = 0; i < voxels_.size(); ++i) {
    bool inserted = false;
    table_.insert(voxel_key(voxels_[i].x, voxels_[i].y, voxels_[i].z), &inserted);
  }
}

void VoxelPointMap::add(const std::vector<Vec3>& points, const RigidTransform& pose, double max_distance,
                        const Plane* ground) {
  if (voxels_.empty()) table_.reset(points.size());
  const Plane ground_here = ground != nullptr ? ground->normalized().moved(pose) : Plane{};
  if (scan_places_.size() > std::max<std::size_t>(kMinRenumbered, voxels_.size())) renumber_scans();
  const int scan = static_cast<int>(scan_places_.size());
  scan_places_.push_back(pose.t);
  // Whether a scan in voxel v other than this one stood within same_place_ of this one (the point in slot `skip` aside).
  auto sampled_from_here = [&](const Voxel& v, int skip) {
    for (int k = 0; k < v.count; ++k) {
      const int other = point_scans_[v.first + k];
      if (k != skip && other != scan && (scan_places_[other] - pose.t).norm() < same_place_) return true;
    }
    return false;
  };
  for (const Vec3& p : points) {
    const Vec3 q = pose.apply(p);
    if (!q.allFinite()) continue;
    const std::int64_t x = voxel_cell(q.x(), voxel_), y = voxel_cell(q.y(), voxel_), z = voxel_cell(q.z(), voxel_);
    bool inserted = false;
    const std::int32_t slot = table_.insert(voxel_key(x, y, z), &inserted);
    if (inserted) {
      voxels_.push_back(Voxel{x, y, z, static_cast<int>(points_.size()), 0});
      const std::size_t slots = points_.size() + per_voxel_;
      points_.resize(slots);
      point_scans_.resize(slots);
      points_on_ground_.resize(slots);
      points_resampled_.resize(slots);
    }
    Voxel& v = voxels_[slot];
    // The slot the point takes: the next free one, else the oldest point from a place sampled before.
    int at = v.count;
    if (v.count == per_voxel_) {
      if (v.resampled == 0) continue;
      for (int k = 0, oldest = scan + 1; k < v.count; ++k)
        if (points_resampled_[v.first + k] && point_scans_[v.first + k] < oldest)
          oldest = point_scans_[v.first + k], at = k;
      --v.resampled;
    } else {
      ++v.count;
    }
    const bool on_ground = ground != nullptr && std::abs(ground_here.signed_distance(q)) <= voxel_;
    if (on_ground) v.ground_normal = ground_here.n;
    const bool resampled = same_place_ >= 0.0 && sampled_from_here(v, at);
    v.resampled += resampled;
    ++v.changes;  // (its plane is computed again)
    points_[v.first + at] = q;
    point_scans_[v.first + at] = scan;
    points_on_ground_[v.first + at] = on_ground;
    points_resampled_[v.first + at] = resampled;
    if (at == v.count - 1) {
      v.on_ground = (at == 0 || v.on_ground) && on_ground;
    } else {
      v.on_ground = true;
      for (int k = 0; k < v.count; ++k) v.on_ground = v.on_ground && points_on_ground_[v.first + k];
    }
  }
  // Drop the voxels out of the sensor's reach once they are a quarter of the map (they are never near a scan's points;
  // dropping compacts the points and builds the table again).
  const double reach2 = max_distance * max_distance;
  std::size_t far = 0;
  for (const Voxel& v : voxels_) far += (points_[v.first] - pose.t).squaredNorm() > reach2;
  if (4 * far < voxels_.size()) return;
  std::size_t kept = 0;
  for (std::size_t i = 0; i < voxels_.size(); ++i) {
    const Voxel& v = voxels_[i];
    if ((points_[v.first] - pose.t).squaredNorm() > reach2) continue;
    if (kept != i) {
      Voxel moved = v;
      moved.first = static_cast<int>(kept) * per_voxel_;
      auto move_slots = [&](auto& column) {
        std::copy(column.begin() + v.first, column.begin() + v.first + v.count, column.begin() + moved.first);
      };
      move_slots(points_);
      move_slots(point_scans_);
      move_slots(points_on_ground_);
      move_slots(points_resampled_);
      voxels_[kept] = moved;
    }
    ++kept;
  }
  voxels_.resize(kept);
  points_.resize(kept * per_voxel_);
  point_scans_.resize(points_.size());
  points_on_ground_.resize(points_.size());
  points_resampled_.resize(points_.size());
  rebuild_table();
}

bool VoxelPointMap::nearest(const Vec3& q, double max_distance, Vec3* nearest_point, int* voxel) const {
  if (voxels_.empty()) return false;
  // Within a voxel, the 2 x 2 x 2 voxels around the voxel corner nearest q (exact within half a voxel of q, the nearest
  // of them farther); farther (an alignment's first steps from a poor guess), the 3 x 3 x 3 around q's voxel.
  const bool near = max_distance <= voxel_;
  // Per axis the cells looked in, q's own first (the nearest point is most often there, and the cubes no nearer to q
  // than it are then skipped).
  const Vec3 cell = q / voxel_;
  std::int64_t cells[3][3];
  for (int k = 0; k < 3; ++k) {
    const std::int64_t own = voxel_cell(q[k], voxel_);
    cells[k][0] = own;
    cells[k][1] = near ? own + (cell[k] - std::floor(cell[k]) < 0.5 ? -1 : 1) : own - 1;
    cells[k][2] = own + 1;
  }
  const int count = near ? 2 : 3;
  double best = max_distance * max_distance;
  bool found = false;
  // A cube no nearer to q than the nearest point so far holds no nearer one: not looked up.
  auto gap = [&](int axis, std::int64_t c) {
    constexpr double kRounding = 1e-9;  // m: the cube's edges computed apart from voxel_cell's floor
    const double below = static_cast<double>(c) * voxel_ - q[axis], above = q[axis] - static_cast<double>(c + 1) * voxel_;
    return std::max(0.0, std::max(below, above) - kRounding);
  };
  for (int ix = 0; ix < count; ++ix) {
    const double gx = gap(0, cells[0][ix]);
    for (int iy = 0; iy < count; ++iy) {
      const double gy = gap(1, cells[1][iy]);
      for (int iz = 0; iz < count; ++iz) {
        const double gz = gap(2, cells[2][iz]);
        if (gx * gx + gy * gy + gz * gz >= best) continue;
        const std::int32_t slot = table_.find(voxel_key(cells[0][ix], cells[1][iy], cells[2][iz]));
        if (slot < 0) continue;
        const Voxel& v = voxels_[slot];
        for (int k = 0; k < v.count; ++k) {
          const double d2 = (points_[v.first + k] - q).squaredNorm();
          if (d2 < best) {
            best = d2;
            *nearest_point = points_[v.first + k];
            if (voxel != nullptr) *voxel = slot;
            found = true;
          }
        }
      }
    }
  }
  return found;
}

bool VoxelPointMap::plane(int index, Vec3* mean, Vec3* normal, bool ground) const {
  // As SurfaceMap's voxel planes: at least kMinPlanePoints points whose scatter's eigenvalues l0 <= l1 <= l2 spread
  // over two directions, (l1 - l0) / l2 >= kMinPlanarity. Else on the ground, a single point or points along one
  // direction (l1 < kMinPlanarity l2) within 30 degrees of it: a ring's arc.
  constexpr int kMinPlanePoints = 5;
  constexpr double kMinPlanarity = 0.1;
  constexpr double kGroundArcSine = 0.5;
  const Voxel& v = voxels_[index];
  if (v.plane_count != v.changes) {
    v.plane_count = v.changes;
    v.planar = v.ground_arc = false;
    if (v.count >= kMinPlanePoints || v.on_ground) {
      Vec3 m = Vec3::Zero();
      for (int k = 0; k < v.count; ++k) m += points_[v.first + k];
      m /= v.count;
      Mat3 scatter = Mat3::Zero();
      for (int k = 0; k < v.count; ++k) {
        const Vec3 d = points_[v.first + k] - m;
        scatter += d * d.transpose();
      }
      const Eigen::SelfAdjointEigenSolver<Mat3> es(scatter);
      const Vec3 l = es.eigenvalues();
      v.mean = m;
      v.normal = es.eigenvectors().col(0);
      v.planar = v.count >= kMinPlanePoints && l(2) > 0.0 && (l(1) - l(0)) / l(2) >= kMinPlanarity;
      const bool along_ground =
          !(l(2) > 0.0) ||
          (l(1) < kMinPlanarity * l(2) && std::abs(es.eigenvectors().col(2).dot(v.ground_normal)) < kGroundArcSine);
      v.ground_arc = !v.planar && v.on_ground && along_ground;
    }
  }
  *mean = v.mean;
  if (v.planar) {
    *normal = v.normal;
    return true;
  }
  const bool on_ground_plane = ground && v.ground_arc;
  *normal = on_ground_plane ? v.ground_normal : v.normal;
  return on_ground_plane;
}

std::vector<Vec3> voxel_downsample(const std::vector<Vec3>& points, double voxel) {
  VoxelTable table;
  table.reset(points.size());
  std::vector<Vec3> out;
  out.reserve(points.size());
  for (const Vec3& p : points) {
    if (!p.allFinite()) continue;
    bool inserted = false;
    table.insert(voxel_key(voxel_cell(p.x(), voxel), voxel_cell(p.y(), voxel), voxel_cell(p.z(), voxel)), &inserted);
    if (inserted) out.push_back(p);
  }
  return out;
}

}  // namespace line_odom
