#include "candidates.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <limits>
#include <optional>
#include <utility>

namespace line_odom {

namespace {

constexpr double kPi = 3.14159265358979323846;

double deg2rad(double deg) { return deg * kPi / 180.0; }

// Segments are bucketed in a dense voxel grid over their bounding box by points sampled along them. With
// samples every cell/3 along both segments, two segments closer than `max_distance` = 2/3 cell have samples
// in neighbouring cells. Each segment is filed under the 27-cell neighbourhood of its samples, so a query only
// reads the cells of its own samples. Cells are a CSR array: a lookup is an index, not a hash probe.
class SegmentGrid {
 public:
  SegmentGrid(const std::vector<const LineFeature*>& lines, double max_distance)
      : cell_(1.5 * std::max(max_distance, 1e-3)) {
    Vec3 lo = Vec3::Constant(std::numeric_limits<double>::infinity()), hi = -lo;
    for (const LineFeature* l : lines) {
      lo = lo.cwiseMin(l->segment.a).cwiseMin(l->segment.b);
      hi = hi.cwiseMax(l->segment.a).cwiseMax(l->segment.b);
    }
    if (lines.empty() || !lo.allFinite() || !hi.allFinite()) return;
    const Vec3 extent = hi - lo;
    // Coarser cells keep any grid (e.g. a frame with a far-away outlier) within a fixed size; correctness only
    // needs cell >= 1.5 max_distance.
    auto cells = [&]() { return (extent.array() / cell_ + 5.0).prod(); };
    while (cells() > kMaxCells) cell_ *= 2.0;
    step_ = cell_ / 3.0;
    origin_ = lo - Vec3::Constant(2.0 * cell_);  // two cells of margin hold the neighbourhoods of the samples
    for (int k = 0; k < 3; ++k) size_[k] = static_cast<int>(extent[k] / cell_) + 5;

    const size_t total = static_cast<size_t>(size_[0]) * size_[1] * size_[2];
    std::vector<int> filed_by(total, -1);  // last line filed under the cell
    std::vector<std::pair<int, int>> entries;  // (cell, line id)
    const int sx = size_[1] * size_[2], sy = size_[2];
    for (int id = 0; id < static_cast<int>(lines.size()); ++id)
      for_each_sample_cell(lines[id]->segment, [&](int cell) {
        const int cx = cell / sx, cy = (cell / sy) % size_[1], cz = cell % sy;
        for (int x = cx - 1; x <= cx + 1; ++x)
          for (int y = cy - 1; y <= cy + 1; ++y)
            for (int z = cz - 1; z <= cz + 1; ++z) {
              const int c = x * sx + y * sy + z;
              if (filed_by[c] == id) continue;
              filed_by[c] = id;
              entries.emplace_back(c, id);
            }
      });
    begin_.assign(total + 1, 0);
    for (const auto& e : entries) ++begin_[e.first + 1];
    for (size_t c = 1; c < begin_.size(); ++c) begin_[c] += begin_[c - 1];
    ids_.resize(entries.size());
    std::vector<int> fill(begin_.begin(), begin_.end() - 1);
    for (const auto& e : entries) ids_[fill[e.first]++] = e.second;
  }

  // Calls visit(id) for every bucketed segment with a sample in a cell next to a sample of `query`
  // (an id may be visited more than once).
  template <typename Visit>
  void for_each_near(const Segment& query, Visit&& visit) const {
    if (begin_.empty()) return;
    for_each_sample_cell(query, [&](int cell) {
      for (int e = begin_[cell]; e < begin_[cell + 1]; ++e) visit(ids_[e]);
    });
  }

 private:
  // Calls f(cell) for each cell of the grid holding a sample of s (consecutive repeats skipped: a straight
  // segment crosses a cell in one run of samples; samples outside the grid are near no bucketed segment).
  template <typename F>
  void for_each_sample_cell(const Segment& s, F&& f) const {
    const double len = s.length();
    // A segment longer than kMaxSamples steps (kilometres at LiDAR settings: only corrupted input, e.g. absurd
    // intrinsics) is not bucketed, so one bad frame cannot cost without bound.
    if (!std::isfinite(len) || len > kMaxSamples * step_) return;
    const int n = 1 + static_cast<int>(std::ceil(len / step_));
    int previous = -1;
    for (int i = 0; i <= n; ++i) {
      const Vec3 p = s.a + (s.b - s.a) * (static_cast<double>(i) / n);
      int cell = 0;
      bool inside = true;
      for (int k = 0; k < 3 && inside; ++k) {
        const double c = std::floor((p[k] - origin_[k]) / cell_);
        inside = c >= 1.0 && c <= size_[k] - 2;
        cell = cell * size_[k] + static_cast<int>(c);
      }
      if (!inside || cell == previous) continue;
      previous = cell;
      f(cell);
    }
  }

  static constexpr double kMaxSamples = 4096.0;
  static constexpr double kMaxCells = 1 << 21;
  double cell_, step_ = 1.0;
  Vec3 origin_ = Vec3::Zero();
  std::array<int, 3> size_{};
  std::vector<int> begin_, ids_;
};

constexpr double kBruteForcePairs = 3e5;  // up to this many line pairs, match without the grid

struct LinePair {
  const LineFeature* a;
  const LineFeature* b;
  double distance;
};

// The usable lines of one kind (H or V) of frame a with their grid, segment bounding boxes (a box gap above the
// pass distance rules a pair out before the exact distance) and normal norms.
struct IndexedLines {
  std::vector<const LineFeature*> lines;
  std::vector<Vec3> box_lo, box_hi;
  // The same boxes as float columns (lo x y z, hi x y z), rounded outwards: a vectorizable prefilter.
  std::array<std::vector<float>, 6> box_columns;
  std::vector<double> normal_norm;
  double max_distance;
  std::optional<SegmentGrid> grid;  // built on first use: small frames are matched without it

  IndexedLines(const std::vector<LineFeature>& all, double max_distance)
      : lines(usable(all)), max_distance(max_distance) {
    box_lo.resize(lines.size());
    box_hi.resize(lines.size());
    normal_norm.resize(lines.size());
    for (size_t i = 0; i < lines.size(); ++i) {
      const Segment& s = lines[i]->segment;
      box_lo[i] = s.a.cwiseMin(s.b);
      box_hi[i] = s.a.cwiseMax(s.b);
      for (int k = 0; k < 3; ++k) {
        box_columns[k].push_back(round_down(box_lo[i][k]));
        box_columns[3 + k].push_back(round_up(box_hi[i][k]));
      }
      normal_norm[i] = lines[i]->normal.norm();
    }
  }

  static float round_down(double v) {
    const float f = static_cast<float>(v);
    return static_cast<double>(f) <= v ? f : std::nextafter(f, -std::numeric_limits<float>::infinity());
  }
  static float round_up(double v) {
    const float f = static_cast<float>(v);
    return static_cast<double>(f) >= v ? f : std::nextafter(f, std::numeric_limits<float>::infinity());
  }

  static std::vector<const LineFeature*> usable(const std::vector<LineFeature>& all) {
    std::vector<const LineFeature*> out;
    out.reserve(all.size());
    for (const auto& l : all)
      if (l.segment.a.allFinite() && l.segment.b.allFinite() && l.line.d.allFinite()) out.push_back(&l);
    return out;
  }
};

// Pairs of lines of frame a (indexed) with lines_b (frame b, moved into a by T) that pass the filters.
void match_lines(IndexedLines& indexed, const std::vector<LineFeature>& lines_b, const RigidTransform& T,
                 const CandidateOptions& opt, std::vector<LinePair>* out) {
  const std::vector<const LineFeature*>& usable_a = indexed.lines;
  if (usable_a.empty()) return;
  const std::vector<Vec3>& box_lo = indexed.box_lo;
  const std::vector<Vec3>& box_hi = indexed.box_hi;
  const std::vector<double>& normal_norm = indexed.normal_norm;
  const double box_gap = opt.max_distance * (1.0 + 1e-9) + 1e-9;
  const double max_cos_lines = std::cos(deg2rad(opt.min_line_angle_deg));
  const double min_cos_normals = std::cos(deg2rad(opt.max_normal_angle_deg));

  const bool brute_force = static_cast<double>(usable_a.size()) * lines_b.size() <= kBruteForcePairs;
  std::vector<int> last_seen(usable_a.size(), -1);
  std::vector<std::uint8_t> overlap(brute_force ? usable_a.size() : 0);
  std::vector<LinePair> partners;
  for (int ib = 0; ib < static_cast<int>(lines_b.size()); ++ib) {
    const LineFeature& lb = lines_b[ib];
    if (!lb.segment.a.allFinite() || !lb.segment.b.allFinite() || !lb.line.d.allFinite()) continue;
    const Segment sb = lb.segment.moved(T);
    const Vec3 db = T.R * lb.line.d;
    const bool nb_known = lb.normal.squaredNorm() > 0.25;
    const Vec3 nb = T.R * lb.normal;
    const double nb_norm = nb.norm();
    const Vec3 sb_lo = sb.a.cwiseMin(sb.b), sb_hi = sb.a.cwiseMax(sb.b);
    partners.clear();
    auto consider = [&](int ia) {
      if (last_seen[ia] == ib) return;
      last_seen[ia] = ib;
      const LineFeature& la = *usable_a[ia];
      if (std::abs(la.line.d.dot(db)) > max_cos_lines) return;
      if (nb_known && la.normal.squaredNorm() > 0.25 &&
          std::abs(la.normal.dot(nb)) / (normal_norm[ia] * nb_norm) < min_cos_normals)
        return;
      if ((box_lo[ia] - sb_hi).maxCoeff() > box_gap || (sb_lo - box_hi[ia]).maxCoeff() > box_gap) return;
      const double dist = segment_distance(la.segment, sb);
      if (dist <= opt.max_distance) partners.push_back({&la, &lb, dist});
    };
    if (brute_force) {
      // Few pairs: a scan of the boxes costs less than the grid's cell lists.
      std::array<float, 6> reach;
      for (int k = 0; k < 3; ++k) {
        reach[k] = IndexedLines::round_up(sb_hi[k] + box_gap + 1e-9);
        reach[3 + k] = IndexedLines::round_down(sb_lo[k] - box_gap - 1e-9);
      }
      const auto& c = indexed.box_columns;
      const int na = static_cast<int>(usable_a.size());
      for (int ia = 0; ia < na; ++ia)
        overlap[ia] = (c[0][ia] <= reach[0]) & (c[1][ia] <= reach[1]) & (c[2][ia] <= reach[2]) &
                      (c[3][ia] >= reach[3]) & (c[4][ia] >= reach[4]) & (c[5][ia] >= reach[5]);
      for (int ia = 0; ia < na; ++ia)
        if (overlap[ia]) consider(ia);
    } else {
      if (!indexed.grid) indexed.grid.emplace(usable_a, indexed.max_distance);
      indexed.grid->for_each_near(sb, consider);
    }
    if (opt.max_pairs_per_line > 0 && static_cast<int>(partners.size()) > opt.max_pairs_per_line) {
      // Closest k; ties broken by line, so the choice does not depend on the grid's traversal order.
      std::nth_element(partners.begin(), partners.begin() + opt.max_pairs_per_line, partners.end(),
                       [](const LinePair& x, const LinePair& y) {
                         return x.distance < y.distance || (x.distance == y.distance && x.a < y.a);
                       });
      partners.resize(opt.max_pairs_per_line);
    }
    // Deterministic order regardless of grid traversal.
    std::sort(partners.begin(), partners.end(), [](const LinePair& x, const LinePair& y) { return x.a < y.a; });
    out->insert(out->end(), partners.begin(), partners.end());
  }
}

}  // namespace

double segment_distance(const Segment& s1, const Segment& s2) {
  // Closest points p1 + s d1 and p2 + t d2, s, t in [0, 1] (clamped least squares).
  const Vec3 d1 = s1.b - s1.a, d2 = s2.b - s2.a, r = s1.a - s2.a;
  const double a = d1.squaredNorm(), e = d2.squaredNorm(), f = d2.dot(r);
  double s = 0.0, t = 0.0;
  if (a <= 1e-18 && e <= 1e-18) return r.norm();
  if (a <= 1e-18) {
    t = std::clamp(f / e, 0.0, 1.0);
  } else {
    const double c = d1.dot(r);
    if (e <= 1e-18) {
      s = std::clamp(-c / a, 0.0, 1.0);
    } else {
      const double b = d1.dot(d2), denom = a * e - b * b;
      s = denom > 1e-18 * a * e ? std::clamp((b * f - c * e) / denom, 0.0, 1.0) : 0.0;
      t = (b * s + f) / e;
      if (t < 0.0) {
        t = 0.0;
        s = std::clamp(-c / a, 0.0, 1.0);
      } else if (t > 1.0) {
        t = 1.0;
        s = std::clamp((b - c) / a, 0.0, 1.0);
      }
    }
  }
  return ((s1.a + d1 * s) - (s2.a + d2 * t)).norm();
}

void build_candidates(const ScanFeatures& a, const ScanFeatures& b, const RigidTransform& T_ab_guess,
                      const CandidateOptions& options, Correspondences* out, CandidateStats* stats) {
  *out = Correspondences{};
  IndexedLines h_a(a.h_lines, options.max_distance), v_a(a.v_lines, options.max_distance);
  std::vector<LinePair> pairs;
  match_lines(h_a, b.v_lines, T_ab_guess, options, &pairs);  // H_a x V_b
  match_lines(v_a, b.h_lines, T_ab_guess, options, &pairs);  // V_a x H_b

  // Cluster of the pair: the previous frame's normal cluster (paper §6.3), else the current frame's.
  std::array<int, 4> counts{};
  std::vector<int> group(pairs.size());
  for (size_t i = 0; i < pairs.size(); ++i) {
    int c = pairs[i].a->cluster;
    if (c < 0 || c > 2) c = pairs[i].b->cluster;
    group[i] = (c >= 0 && c <= 2) ? c : 3;
    ++counts[group[i]];
  }
  const int clusters = static_cast<int>((counts[0] > 0) + (counts[1] > 0) + (counts[2] > 0));

  const size_t n = pairs.size();
  out->lines_a.reserve(n);
  out->lines_b.reserve(n);
  out->segments_a.reserve(n);
  out->segments_b.reserve(n);
  out->weights.reserve(n);
  out->clusters.reserve(n);
  for (size_t i = 0; i < n; ++i) {
    out->lines_a.push_back(pairs[i].a->line);
    out->lines_b.push_back(pairs[i].b->line);
    out->segments_a.push_back(pairs[i].a->segment);
    out->segments_b.push_back(pairs[i].b->segment);
    // Inverse normal-cluster size (paper §6.3), scaled so that the weights average to 1 over all pairs. Pairs
    // without a normal form no cluster: each weighs 1 (as a group of their own, a handful of them could carry a
    // third of the weight and decide the motion, e.g. floor-wall seams in a corridor).
    const double clustered = static_cast<double>(n - counts[3]);
    out->weights.push_back(group[i] == 3 ? 1.0 : clustered / (clusters * counts[group[i]]));
    out->clusters.push_back(group[i] == 3 ? -1 : group[i]);
  }

  const double min_cos_planes = std::cos(deg2rad(options.plane_max_angle_deg));
  for (const PlaneFeature& pa : a.planes) {
    if (!pa.plane.n.allFinite() || !std::isfinite(pa.plane.delta)) continue;
    const Plane plane_a = pa.plane.normalized();
    for (const PlaneFeature& pb : b.planes) {
      if (!pb.plane.n.allFinite() || !std::isfinite(pb.plane.delta)) continue;
      Plane plane_b = pb.plane.normalized();
      Plane moved = plane_b.moved(T_ab_guess);
      double cos_angle = plane_a.n.dot(moved.n);
      if (cos_angle < 0.0) {  // fitted normals carry no orientation: use the matching sign
        plane_b = {-plane_b.n, -plane_b.delta};
        moved = {-moved.n, -moved.delta};
        cos_angle = -cos_angle;
      }
      if (cos_angle < min_cos_planes) continue;
      if (std::abs(plane_a.signed_distance(T_ab_guess.apply(pb.centroid))) > options.plane_max_distance) continue;
      if (std::abs(moved.signed_distance(pa.centroid)) > options.plane_max_distance) continue;
      out->planes_a.push_back(plane_a);
      out->planes_b.push_back(plane_b);
    }
  }

  if (stats) {
    stats->line_pairs = static_cast<int>(n);
    stats->plane_pairs = static_cast<int>(out->planes_a.size());
    stats->cluster_pairs = counts;
  }
}

}  // namespace line_odom
