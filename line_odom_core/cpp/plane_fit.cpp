#include "plane_fit.hpp"

#include <Eigen/Eigenvalues>
#include <algorithm>
#include <cmath>
#include <numeric>
#include <stdexcept>
#include <string>

namespace line_odom {

namespace {

constexpr double kDeg = 3.14159265358979323846 / 180.0;

struct PlaneEstimate {
  Vec3 n = Vec3::UnitZ();
  double delta = 0.0;
  double lambda_min = 0.0, lambda_mid = 0.0;
};

PlaneEstimate pca_plane(const PointMoments& m) {
  PlaneEstimate p;
  Eigen::SelfAdjointEigenSolver<Mat3> eig;
  eig.computeDirect(m.covariance());
  p.n = eig.eigenvectors().col(0).normalized();
  p.lambda_min = std::max(0.0, eig.eigenvalues()(0));
  p.lambda_mid = std::max(0.0, eig.eigenvalues()(1));
  p.delta = -p.n.dot(m.mean());
  return p;
}

}  // namespace

void PlaneFitConfig::validate() const {
  auto fail = [](const std::string& field, const std::string& what) {
    throw std::invalid_argument("planes." + field + ": " + what);
  };
  if (!(max_distance > 0.0)) fail("max_distance", "expected > 0");
  if (!(max_normal_angle_deg > 0.0 && max_normal_angle_deg < 90.0))
    fail("max_normal_angle_deg", "expected in (0, 90)");
  if (min_points < 3) fail("min_points", "expected >= 3");
  if (min_lines < 2) fail("min_lines", "expected >= 2");
  if (!(min_extent >= 0.0)) fail("min_extent", "expected >= 0");
  if (!(max_rms > 0.0)) fail("max_rms", "expected > 0");
  if (max_planes < 0) fail("max_planes", "expected >= 0");
}

std::vector<PlaneFeature> fit_planes(const RangeImage& image, const std::vector<LineCrossing>& crossings,
                                     const PlaneFitConfig& config, const LineFitConfig& line_config,
                                     ScanLines* lines) {
  config.validate();
  auto& H = lines->h_lines;
  auto& V = lines->v_lines;
  for (auto& f : H) f.plane = -1;
  for (auto& f : V) f.plane = -1;
  std::vector<PlaneFeature> planes;
  if (!config.enabled || config.max_planes == 0) return planes;

  // One index space over all lines: H-lines first, then V-lines.
  const int nh = static_cast<int>(H.size()), nl = nh + static_cast<int>(V.size());
  auto line = [&](int i) -> LineFeature& { return i < nh ? H[i] : V[i - nh]; };
  auto known = [&](int i) { return line(i).normal.squaredNorm() > 0.25; };

  // Per-line moments (a crossing cell counts for both of its lines while growing).
  std::vector<PointMoments> moments(nl);
  const int cells = image.rows * image.cols;
  for (int c = 0; c < cells; ++c) {
    if (lines->h_label[c] >= 0) moments[lines->h_label[c]].add(image.points[c]);
    if (lines->v_label[c] >= 0) moments[nh + lines->v_label[c]].add(image.points[c]);
  }

  // Crossing graph between lines whose normals agree.
  const double cos_normal = std::cos(config.max_normal_angle_deg * kDeg);
  const double sin_normal = std::sin(config.max_normal_angle_deg * kDeg);
  std::vector<int> offset(nl + 1, 0), adj;
  std::vector<std::pair<int, int>> edges;
  edges.reserve(crossings.size());
  for (const auto& x : crossings) {
    const int a = x.h, b = nh + x.v;
    if (!known(a) || !known(b)) continue;
    if (std::abs(line(a).normal.dot(line(b).normal)) < cos_normal) continue;
    edges.emplace_back(a, b);
    ++offset[a + 1];
    ++offset[b + 1];
  }
  for (int i = 0; i < nl; ++i) offset[i + 1] += offset[i];
  adj.resize(offset[nl]);
  {
    std::vector<int> fill(offset.begin(), offset.end() - 1);
    for (const auto& [a, b] : edges) {
      adj[fill[a]++] = b;
      adj[fill[b]++] = a;
    }
  }

  std::vector<int> order;
  for (int i = 0; i < nl; ++i)
    if (known(i) && offset[i + 1] > offset[i]) order.push_back(i);
  std::stable_sort(order.begin(), order.end(), [&](int a, int b) { return line(a).support > line(b).support; });

  std::vector<int> region(nl, -1);
  std::vector<int> queue, members;
  struct Region {
    std::vector<int> lines;
  };
  std::vector<Region> regions;
  for (int seed : order) {
    if (region[seed] >= 0) continue;
    const int rid = static_cast<int>(regions.size());
    regions.emplace_back();
    members.clear();
    queue.assign(1, seed);
    region[seed] = rid;
    PointMoments acc = moments[seed];
    Vec3 normal_sum = line(seed).normal;
    PlaneEstimate plane;
    plane.n = line(seed).normal;
    plane.delta = -plane.n.dot(acc.mean());
    int fitted_at = acc.count;
    for (size_t qi = 0; qi < queue.size(); ++qi) {
      const int cur = queue[qi];
      members.push_back(cur);
      for (int k = offset[cur]; k < offset[cur + 1]; ++k) {
        const int nb = adj[k];
        if (region[nb] >= 0) continue;
        const LineFeature& f = line(nb);
        if (std::abs(f.normal.dot(plane.n)) < cos_normal) continue;
        if (std::abs(f.line.d.dot(plane.n)) > sin_normal) continue;
        const double da = std::abs(plane.n.dot(f.segment.a) + plane.delta);
        const double db = std::abs(plane.n.dot(f.segment.b) + plane.delta);
        if (da > config.max_distance * line_config.threshold_scale(f.segment.a.norm()) ||
            db > config.max_distance * line_config.threshold_scale(f.segment.b.norm()))
          continue;
        region[nb] = rid;
        queue.push_back(nb);
        acc.add(moments[nb]);
        normal_sum += f.normal.dot(normal_sum) >= 0.0 ? f.normal : Vec3(-f.normal);
        if (acc.count >= fitted_at + fitted_at / 5 + 1) {
          const PlaneEstimate p = pca_plane(acc);
          // Least squares once the region spans two directions; the mean line normal before that.
          if (p.lambda_mid > 1e-2 && p.lambda_mid > 25.0 * p.lambda_min) {
            plane = p;
          } else {
            plane.n = normal_sum.normalized();
            plane.delta = -plane.n.dot(acc.mean());
          }
          fitted_at = acc.count;
        }
      }
    }
    regions[rid].lines = members;
  }

  // Final fit of every region on its points, each cell counted once.
  const int nr = static_cast<int>(regions.size());
  std::vector<PointMoments> region_moments(nr);
  for (int c = 0; c < cells; ++c) {
    const int h = lines->h_label[c], v = lines->v_label[c];
    int r = h >= 0 ? region[h] : -1;
    if (r < 0 && v >= 0) r = region[nh + v];
    if (r >= 0) region_moments[r].add(image.points[c]);
  }
  // Regions on one plane that the crossing graph did not connect (split by an occluder, a gap or the sensor's
  // blind spot) are merged when their planes agree and the union still fits.
  std::vector<int> parent(nr);
  std::iota(parent.begin(), parent.end(), 0);
  {
    std::vector<int> big;
    for (int r = 0; r < nr; ++r)
      if (region_moments[r].count >= 3 && regions[r].lines.size() >= 2) big.push_back(r);
    std::stable_sort(big.begin(), big.end(),
                     [&](int a, int b) { return region_moments[a].count > region_moments[b].count; });
    std::vector<PlaneEstimate> est(nr);
    for (int r : big) est[r] = pca_plane(region_moments[r]);
    auto within = [&](const PlaneEstimate& p, const Vec3& x) {
      return std::abs(p.n.dot(x) + p.delta) <= config.max_distance * line_config.threshold_scale(x.norm());
    };
    for (size_t i = 0; i < big.size(); ++i) {
      const int a = big[i];
      if (parent[a] != a) continue;
      for (size_t j = i + 1; j < big.size(); ++j) {
        const int b = big[j];
        if (parent[b] != b) continue;
        const PlaneEstimate& pa = est[a];
        const PlaneEstimate& pb = est[b];
        if (std::abs(pa.n.dot(pb.n)) < cos_normal) continue;
        if (!within(pa, region_moments[b].mean()) || !within(pb, region_moments[a].mean())) continue;
        PointMoments u = region_moments[a];
        u.add(region_moments[b]);
        const PlaneEstimate pu = pca_plane(u);
        // the union must fit about as well as its parts (not two parallel surfaces a step apart)
        const double parts_rms = std::sqrt(std::max(pa.lambda_min, pb.lambda_min));
        if (!(std::sqrt(pu.lambda_min) <= std::min(config.max_rms, 1.25 * parts_rms + 0.005))) continue;
        region_moments[a] = u;
        est[a] = pu;
        regions[a].lines.insert(regions[a].lines.end(), regions[b].lines.begin(), regions[b].lines.end());
        parent[b] = a;
      }
    }
    for (int i = 0; i < nl; ++i)
      if (region[i] >= 0) region[i] = parent[region[i]];
  }

  std::vector<std::pair<PlaneFeature, int>> accepted;
  for (int r = 0; r < nr; ++r) {
    if (parent[r] != r) continue;
    const PointMoments& m = region_moments[r];
    if (static_cast<int>(regions[r].lines.size()) < config.min_lines || m.count < config.min_points) continue;
    const PlaneEstimate p = pca_plane(m);
    const double rms = std::sqrt(p.lambda_min);
    const double extent = std::sqrt(12.0 * p.lambda_mid);
    if (!(rms <= config.max_rms) || extent < config.min_extent) continue;
    PlaneFeature f;
    f.centroid = m.mean();
    Vec3 n = p.n;
    if (n.dot(f.centroid) > 0.0) n = -n;
    f.plane = Plane{n, -n.dot(f.centroid)};
    f.support = m.count;
    f.rms = rms;
    accepted.emplace_back(f, r);
  }
  std::stable_sort(accepted.begin(), accepted.end(),
                   [](const auto& a, const auto& b) { return a.first.support > b.first.support; });
  if (static_cast<int>(accepted.size()) > config.max_planes) accepted.resize(config.max_planes);
  std::vector<int> plane_of_region(nr, -1);
  for (size_t i = 0; i < accepted.size(); ++i) {
    planes.push_back(accepted[i].first);
    plane_of_region[accepted[i].second] = static_cast<int>(i);
  }
  for (int i = 0; i < nl; ++i)
    if (region[i] >= 0) line(i).plane = plane_of_region[region[i]];
  return planes;
}

}  // namespace line_odom
