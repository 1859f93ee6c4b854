#include "features/plane_fit.hpp"

#include <Eigen/Eigenvalues>
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <numeric>
#include <stdexcept>
#include <string>

#include "common/lent_workspace.hpp"
#include "common/simd.hpp"

namespace line_odom {

namespace {

constexpr double kDeg = kPi / 180.0;

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

// The sums of PointMoments with the 6 distinct entries of sum p p^T: the full outer sum is symmetric bit for
// bit (p_i p_j == p_j p_i, added in the same order), so moments() rebuilds PointMoments exactly.
struct MomentSums {
  int count = 0;
  double sx = 0.0, sy = 0.0, sz = 0.0, xx = 0.0, xy = 0.0, xz = 0.0, yy = 0.0, yz = 0.0, zz = 0.0;

  void add(const Vec3& p) {
    const double x = p.x(), y = p.y(), z = p.z();
    ++count;
    sx += x, sy += y, sz += z;
    xx += x * x, xy += x * y, xz += x * z, yy += y * y, yz += y * z, zz += z * z;
  }
  void add(const MomentSums& o) {
    count += o.count;
    sx += o.sx, sy += o.sy, sz += o.sz;
    xx += o.xx, xy += o.xy, xz += o.xz, yy += o.yy, yz += o.yz, zz += o.zz;
  }
  PointMoments moments() const {
    PointMoments m;
    m.count = count;
    m.sum = Vec3(sx, sy, sz);
    m.outer << xx, xy, xz, xy, yy, yz, xz, yz, zz;
    return m;
  }
  Vec3 mean() const { return moments().mean(); }
};

PlaneEstimate pca_plane(const MomentSums& m) { return pca_plane(m.moments()); }

// MomentSums while points are added, its sums in pairs of lanes ((sx, sy), (xx, xy), (xz, yz), (yy, zz); sz alone):
// each sum takes the same products in the same order as MomentSums::add, with three multiplications and four
// additions of pairs instead of six and nine scalar ones (GCC vector types: element-wise IEEE operations).
class MomentLanes {
 public:
  using Pair = simd::F2;

  explicit MomentLanes(const MomentSums& m)
      : count_(m.count), sz_(m.sz), s_xy_{m.sx, m.sy}, xx_xy_{m.xx, m.xy}, xz_yz_{m.xz, m.yz}, yy_zz_{m.yy, m.zz} {}

  void add(const Vec3& p) {
    const double* q = p.data();
    Pair xy, yz;
    std::memcpy(&xy, q, sizeof(Pair));
    std::memcpy(&yz, q + 1, sizeof(Pair));
    const Pair xx = {q[0], q[0]}, zz = {q[2], q[2]};
    ++count_;
    s_xy_ += xy;
    sz_ += q[2];
    xx_xy_ += xx * xy;
    xz_yz_ += xy * zz;
    yy_zz_ += yz * yz;
  }
  int count() const { return count_; }
  MomentSums sums() const {
    MomentSums m;
    m.count = count_;
    m.sx = s_xy_[0], m.sy = s_xy_[1], m.sz = sz_;
    m.xx = xx_xy_[0], m.xy = xx_xy_[1], m.xz = xz_yz_[0], m.yz = xz_yz_[1], m.yy = yy_zz_[0], m.zz = yy_zz_[1];
    return m;
  }

 private:
  int count_;
  double sz_;
  Pair s_xy_, xx_xy_, xz_yz_, yy_zz_;
};

// Labels >= 0 of n.
LINE_ODOM_VECTOR_CLONES int count_labelled(const std::int32_t* label, int n) {
  int labelled = 0;
  for (int c = 0; c < n; ++c) labelled += label[c] >= 0;
  return labelled;
}

// Moments of the cells of each line, in ascending cell order (as a row-major scan of the labels adds them):
// each line scans only its own span [first, last] of its row (H) or column (V). Returns false, leaving `out`
// unspecified, when some labelled cell lies outside its line's span (the caller then scans all cells).
bool line_moments_by_span(const RangeImage& image, const std::vector<LineFeature>& lines,
                          const std::vector<std::int32_t>& labels, bool horizontal, MomentSums* out) {
  const int rows = image.rows, cols = image.cols;
  const int cells = rows * cols;
  const std::int32_t* label = labels.data();
  const int labelled = count_labelled(label, cells);
  int found = 0;
  const int scans = horizontal ? rows : cols, along = horizontal ? cols : rows;
  const int step = horizontal ? 1 : cols;
  for (size_t i = 0; i < lines.size(); ++i) {
    const LineFeature& f = lines[i];
    if (f.scan_index < 0 || f.scan_index >= scans || f.first < 0 || f.last >= along || f.first > f.last)
      return false;
    MomentLanes m{MomentSums{}};
    const int id = static_cast<int>(i);
    int cell = horizontal ? f.scan_index * cols + f.first : f.first * cols + f.scan_index;
    for (int k = f.first; k <= f.last; ++k, cell += step)
      if (label[cell] == id) m.add(image.points[cell]);
    found += m.count();
    out[i] = m.sums();
  }
  return found == labelled;
}

// The first j in [from, count) with alive[j] and |a . n_j| not below cos_limit (n_j = (nx, ny, nz)[j]; the
// products summed in Eigen's order for a 3-vector dot), else count. Blocks of 16 are tested without branches.
LINE_ODOM_VECTOR_CLONES size_t next_parallel(const double* nx, const double* ny, const double* nz,
                                             const std::uint8_t* alive, size_t from, size_t count, double ax,
                                             double ay, double az, double cos_limit) {
  constexpr size_t kBlock = 16;
  for (size_t j0 = from; j0 < count; j0 += kBlock) {
    const size_t m = std::min(kBlock, count - j0);
    unsigned hits = 0;
    for (size_t k = 0; k < m; ++k) {
      const size_t j = j0 + k;
      const bool near = !(std::abs(ax * nx[j] + ay * ny[j] + az * nz[j]) < cos_limit);
      hits |= static_cast<unsigned>(near & (alive[j] != 0)) << k;
    }
    if (hits) return j0 + static_cast<size_t>(__builtin_ctz(hits));
  }
  return count;
}

// The line fields region growing tests, packed (the distance limits computed once per line).
struct GrowLine {
  Vec3 d, a, b;
  double limit_a, limit_b;
};

// Work buffers of fit_planes, kept per thread (lent_workspace.hpp).
struct PlaneFitWorkspace {
  std::vector<Vec3> normal;
  std::vector<std::uint8_t> known;
  std::vector<MomentSums> moments, region_moments;
  std::vector<int> offset, fill, adj, order, sorted, support, region, queue, region_lines, parent, big, plane_of_region;
  std::vector<std::pair<int, int>> edges;
  std::vector<GrowLine> grow;
  std::vector<PlaneEstimate> est;
  std::vector<double> big_nx, big_ny, big_nz;
  std::vector<std::uint8_t> big_alive;
};

// The scan's lines in one index space: H-lines first, then V-lines.
class AllLines {
 public:
  explicit AllLines(ScanLines* lines)
      : lines_(lines), nh_(static_cast<int>(lines->h_lines.size())),
        count_(nh_ + static_cast<int>(lines->v_lines.size())) {}
  LineFeature& operator[](int i) const { return i < nh_ ? lines_->h_lines[i] : lines_->v_lines[i - nh_]; }
  int count() const { return count_; }
  int first_v() const { return nh_; }
  const ScanLines& scan() const { return *lines_; }

 private:
  ScanLines* lines_;
  int nh_, count_;
};

// Per-line normals (ws.normal, ws.known: a normal was estimated) and moments (ws.moments; a crossing cell counts for
// both of its lines while growing).
void line_normals_and_moments(const RangeImage& image, const AllLines& line, PlaneFitWorkspace& ws) {
  const int nl = line.count(), nh = line.first_v();
  ws.normal.resize(nl);
  ws.known.resize(nl);
  for (int i = 0; i < nl; ++i) {
    ws.normal[i] = line[i].normal;
    ws.known[i] = ws.normal[i].squaredNorm() > 0.25;
  }
  auto& moments = ws.moments;
  moments.resize(nl);
  const ScanLines& lines = line.scan();
  if (!line_moments_by_span(image, lines.h_lines, lines.h_label, true, moments.data()) ||
      !line_moments_by_span(image, lines.v_lines, lines.v_label, false, moments.data() + nh)) {
    std::fill(moments.begin(), moments.end(), MomentSums{});
    const int cells = image.rows * image.cols;
    for (int c = 0; c < cells; ++c) {
      if (lines.h_label[c] >= 0) moments[lines.h_label[c]].add(image.points[c]);
      if (lines.v_label[c] >= 0) moments[nh + lines.v_label[c]].add(image.points[c]);
    }
  }
}

// The crossing graph between lines whose normals agree within cos_normal, as adjacency lists (ws.offset, ws.adj).
void crossing_graph(const std::vector<LineCrossing>& crossings, const AllLines& line, double cos_normal,
                    PlaneFitWorkspace& ws) {
  const int nl = line.count(), nh = line.first_v();
  auto& offset = ws.offset;
  auto& edges = ws.edges;
  offset.assign(nl + 1, 0);
  edges.clear();
  edges.reserve(crossings.size());
  for (const auto& x : crossings) {
    const int a = x.h, b = nh + x.v;
    if (!ws.known[a] || !ws.known[b]) continue;
    if (std::abs(ws.normal[a].dot(ws.normal[b])) < cos_normal) continue;
    edges.emplace_back(a, b);
    ++offset[a + 1];
    ++offset[b + 1];
  }
  for (int i = 0; i < nl; ++i) offset[i + 1] += offset[i];
  ws.adj.resize(offset[nl]);
  auto& fill = ws.fill;
  fill.assign(offset.begin(), offset.end() - 1);
  for (const auto& [a, b] : edges) {
    ws.adj[fill[a]++] = b;
    ws.adj[fill[b]++] = a;
  }
}

bool in_graph(const PlaneFitWorkspace& ws, int i) { return ws.known[i] && ws.offset[i + 1] > ws.offset[i]; }

// The lines of the graph by support, descending, ties in index order (ws.order): the seeds of the regions.
void seeds_by_support(const AllLines& line, PlaneFitWorkspace& ws) {
  auto& order = ws.order;
  order.clear();
  for (int i = 0; i < line.count(); ++i)
    if (in_graph(ws, i)) order.push_back(i);
  // A counting sort (supports are point counts), stable.
  auto& support = ws.support;
  support.resize(order.size());
  int min_support = 0, max_support = 0;
  for (size_t k = 0; k < order.size(); ++k) {
    support[k] = line[order[k]].support;
    min_support = std::min(min_support, support[k]);
    max_support = std::max(max_support, support[k]);
  }
  if (min_support < 0 || max_support > (1 << 22)) {
    std::stable_sort(order.begin(), order.end(), [&](int a, int b) { return line[a].support > line[b].support; });
    return;
  }
  auto& start = ws.fill;
  start.assign(static_cast<size_t>(max_support) + 2, 0);
  for (int s : support) ++start[max_support - s + 1];
  for (int b = 0; b <= max_support; ++b) start[b + 1] += start[b];
  auto& sorted = ws.sorted;
  sorted.resize(order.size());
  for (size_t k = 0; k < order.size(); ++k) sorted[start[max_support - support[k]]++] = order[k];
  order.swap(sorted);
}

// Regions grown from each seed over the crossing graph (ws.region per line, ws.region_lines per region): a neighbour
// joins when its normal and direction agree with the region's plane and both its ends lie within the plane distance.
void grow_regions(const AllLines& line, const PlaneFitConfig& config, const LineFitConfig& line_config,
                  double cos_normal, double sin_normal, PlaneFitWorkspace& ws) {
  const int nl = line.count();
  auto& grow = ws.grow;
  grow.resize(nl);
  for (int i = 0; i < nl; ++i)
    if (in_graph(ws, i)) {
      const LineFeature& f = line[i];
      grow[i] = {f.line.d, f.segment.a, f.segment.b,
                 config.max_distance * line_config.threshold_scale(f.segment.a.norm()),
                 config.max_distance * line_config.threshold_scale(f.segment.b.norm())};
    }
  auto& region = ws.region;
  auto& queue = ws.queue;
  region.assign(nl, -1);
  ws.region_lines.clear();
  for (int seed : ws.order) {
    if (region[seed] >= 0) continue;
    const int rid = static_cast<int>(ws.region_lines.size());
    queue.assign(1, seed);
    region[seed] = rid;
    MomentSums acc = ws.moments[seed];
    Vec3 normal_sum = ws.normal[seed];
    PlaneEstimate plane;
    plane.n = ws.normal[seed];
    plane.delta = -plane.n.dot(acc.mean());
    int fitted_at = acc.count;
    for (size_t qi = 0; qi < queue.size(); ++qi) {
      const int cur = queue[qi];
      for (int k = ws.offset[cur]; k < ws.offset[cur + 1]; ++k) {
        const int nb = ws.adj[k];
        if (region[nb] >= 0) continue;
        const Vec3& fn = ws.normal[nb];
        if (std::abs(fn.dot(plane.n)) < cos_normal) continue;
        const GrowLine& g = grow[nb];
        if (std::abs(g.d.dot(plane.n)) > sin_normal) continue;
        const double da = std::abs(plane.n.dot(g.a) + plane.delta);
        const double db = std::abs(plane.n.dot(g.b) + plane.delta);
        if (da > g.limit_a || db > g.limit_b) continue;
        region[nb] = rid;
        queue.push_back(nb);
        acc.add(ws.moments[nb]);
        normal_sum += fn.dot(normal_sum) >= 0.0 ? fn : Vec3(-fn);
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
    ws.region_lines.push_back(static_cast<int>(queue.size()));
  }
}

// Each region's moments over its points, each cell counted once (ws.region_moments).
void region_moments(const RangeImage& image, const AllLines& line, PlaneFitWorkspace& ws) {
  const int nr = static_cast<int>(ws.region_lines.size()), nh = line.first_v();
  auto& moments = ws.region_moments;
  moments.assign(nr, MomentSums{});
  // Runs of cells of one region are summed in a local copy (the same running sums, kept in registers).
  const std::int32_t* h_label = line.scan().h_label.data();
  const std::int32_t* v_label = line.scan().v_label.data();
  const int cells = image.rows * image.cols;
  // A row without H-line cells (most rows of a sparsely fitted scan) reads only its V-labels.
  int run = -1;
  MomentLanes sums{MomentSums{}};
  for (int row_cell = 0; row_cell < cells; row_cell += image.cols) {
    const bool h_row = count_labelled(h_label + row_cell, image.cols) > 0;
    for (int c = row_cell; c < row_cell + image.cols; ++c) {
      int r = -1;
      if (h_row && h_label[c] >= 0) r = ws.region[h_label[c]];
      if (r < 0 && v_label[c] >= 0) r = ws.region[nh + v_label[c]];
      if (r < 0) continue;
      if (r != run) {
        if (run >= 0) moments[run] = sums.sums();
        run = r;
        sums = MomentLanes(moments[r]);
      }
      sums.add(image.points[c]);
    }
  }
  if (run >= 0) moments[run] = sums.sums();
}

// Regions on one plane that the crossing graph did not connect (split by an occluder, a gap or the sensor's blind
// spot) merged when their planes agree and the union still fits (ws.parent; ws.region relabelled to the roots).
void merge_regions(const PlaneFitConfig& config, const LineFitConfig& line_config, double cos_normal,
                   PlaneFitWorkspace& ws) {
  const int nr = static_cast<int>(ws.region_lines.size());
  auto& region_moments = ws.region_moments;
  auto& region_lines = ws.region_lines;
  auto& parent = ws.parent;
  parent.resize(nr);
  std::iota(parent.begin(), parent.end(), 0);
  auto& big = ws.big;
  big.clear();
  for (int r = 0; r < nr; ++r)
    if (region_moments[r].count >= 3 && region_lines[r] >= 2) big.push_back(r);
  std::stable_sort(big.begin(), big.end(),
                   [&](int a, int b) { return region_moments[a].count > region_moments[b].count; });
  auto& est = ws.est;
  est.assign(nr, PlaneEstimate{});
  for (int r : big) est[r] = pca_plane(region_moments[r]);
  auto within = [&](const PlaneEstimate& p, const Vec3& x) {
    return std::abs(p.n.dot(x) + p.delta) <= config.max_distance * line_config.threshold_scale(x.norm());
  };
  // The normals of the big regions in their order, and whether each is still a root, for the pair search.
  const size_t nb_big = big.size();
  auto& bx = ws.big_nx;
  auto& by = ws.big_ny;
  auto& bz = ws.big_nz;
  auto& alive = ws.big_alive;
  bx.resize(nb_big);
  by.resize(nb_big);
  bz.resize(nb_big);
  alive.assign(nb_big, 1);
  for (size_t j = 0; j < nb_big; ++j) {
    const Vec3& n = est[big[j]].n;
    bx[j] = n.x(), by[j] = n.y(), bz[j] = n.z();
  }
  for (size_t i = 0; i < nb_big; ++i) {
    const int a = big[i];
    if (!alive[i]) continue;
    for (size_t j = i + 1; j < nb_big; ++j) {
      const Vec3& na = est[a].n;
      j = next_parallel(bx.data(), by.data(), bz.data(), alive.data(), j, nb_big, na.x(), na.y(), na.z(), cos_normal);
      if (j >= nb_big) break;
      const int b = big[j];
      const PlaneEstimate& pa = est[a];
      const PlaneEstimate& pb = est[b];
      if (!within(pa, region_moments[b].mean()) || !within(pb, region_moments[a].mean())) continue;
      MomentSums u = region_moments[a];
      u.add(region_moments[b]);
      const PlaneEstimate pu = pca_plane(u);
      // the union must fit about as well as its parts (not two parallel surfaces a step apart)
      const double parts_rms = std::sqrt(std::max(pa.lambda_min, pb.lambda_min));
      if (!(std::sqrt(pu.lambda_min) <= std::min(config.max_rms, 1.25 * parts_rms + 0.005))) continue;
      region_moments[a] = u;
      est[a] = pu;
      region_lines[a] += region_lines[b];
      parent[b] = a;
      alive[j] = 0;
    }
  }
  for (int& r : ws.region)
    if (r >= 0) r = parent[r];
}

// The merged regions that fit a plane well enough, the best supported first, at most config.max_planes; each line
// labelled with its plane (-1: none).
std::vector<PlaneFeature> accept_planes(const PlaneFitConfig& config, const AllLines& line, PlaneFitWorkspace& ws) {
  const int nr = static_cast<int>(ws.region_lines.size());
  std::vector<std::pair<PlaneFeature, int>> accepted;
  for (int r = 0; r < nr; ++r) {
    if (ws.parent[r] != r) continue;
    const PointMoments m = ws.region_moments[r].moments();
    if (ws.region_lines[r] < config.min_lines || m.count < config.min_points) continue;
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
  std::vector<PlaneFeature> planes;
  auto& plane_of_region = ws.plane_of_region;
  plane_of_region.assign(nr, -1);
  for (size_t i = 0; i < accepted.size(); ++i) {
    planes.push_back(accepted[i].first);
    plane_of_region[accepted[i].second] = static_cast<int>(i);
  }
  for (int i = 0; i < line.count(); ++i)
    if (ws.region[i] >= 0) line[i].plane = plane_of_region[ws.region[i]];
  return planes;
}

}  // namespace

std::vector<PlaneFeature> fit_planes(const RangeImage& image, const std::vector<LineCrossing>& crossings,
                                     const PlaneFitConfig& config, const LineFitConfig& line_config,
                                     ScanLines* lines) {
  for (auto& f : lines->h_lines) f.plane = -1;
  for (auto& f : lines->v_lines) f.plane = -1;
  if (!config.enabled || config.max_planes == 0) return {};
  const AllLines line(lines);
  LentWorkspace<PlaneFitWorkspace> lent;
  PlaneFitWorkspace& ws = *lent;
  const double cos_normal = std::cos(config.max_normal_angle_deg * kDeg);
  const double sin_normal = std::sin(config.max_normal_angle_deg * kDeg);
  line_normals_and_moments(image, line, ws);
  crossing_graph(crossings, line, cos_normal, ws);
  seeds_by_support(line, ws);
  grow_regions(line, config, line_config, cos_normal, sin_normal, ws);
  region_moments(image, line, ws);
  merge_regions(config, line_config, cos_normal, ws);
  return accept_planes(config, line, ws);
}

}  // namespace line_odom
