#include "candidates.hpp"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <utility>

namespace line_odom {

namespace {

constexpr double kPi = 3.14159265358979323846;

double deg2rad(double deg) { return deg * kPi / 180.0; }

// Segments are bucketed in a sparse voxel grid by points sampled along them. With samples every
// cell/3 along both segments, two segments closer than `max_distance` = 2/3 cell have samples in
// neighbouring cells, so a 27-cell lookup around each sample of the query finds every partner. Cells are
// found through an open-addressing hash of cell keys to runs of a sorted (key, id) array.
class SegmentGrid {
 public:
  SegmentGrid(const std::vector<const LineFeature*>& lines, double max_distance)
      : cell_(1.5 * std::max(max_distance, 1e-3)), step_(cell_ / 3.0) {
    for (int id = 0; id < static_cast<int>(lines.size()); ++id)
      for_each_sample_cell(lines[id]->segment,
                           [&](std::int64_t x, std::int64_t y, std::int64_t z) { entries_.emplace_back(pack(x, y, z), id); });
    std::sort(entries_.begin(), entries_.end());
    entries_.erase(std::unique(entries_.begin(), entries_.end()), entries_.end());
    size_t cells = 0;
    for (size_t i = 0; i < entries_.size(); ++i) cells += (i == 0 || entries_[i].first != entries_[i - 1].first);
    size_t capacity = 16;
    while (capacity < 2 * cells) capacity *= 2;
    mask_ = capacity - 1;
    slots_.assign(capacity, Slot{});
    slot_seen_.assign(capacity, 0);
    ids_.reserve(entries_.size());
    for (size_t i = 0; i < entries_.size();) {
      size_t j = i;
      while (j < entries_.size() && entries_[j].first == entries_[i].first) ids_.push_back(entries_[j++].second);
      size_t h = hash(entries_[i].first) & mask_;
      while (slots_[h].end != 0) h = (h + 1) & mask_;
      slots_[h] = {entries_[i].first, static_cast<int>(i), static_cast<int>(j)};
      i = j;
    }
  }

  // Calls visit(id) for every bucketed segment with a sample in a cell next to a sample of `query`
  // (an id may be visited more than once; each cell is visited once per query).
  template <typename Visit>
  void for_each_near(const Segment& query, Visit&& visit) {
    ++query_stamp_;
    for_each_sample_cell(query, [&](std::int64_t x, std::int64_t y, std::int64_t z) {
      for (int dx = -1; dx <= 1; ++dx)
        for (int dy = -1; dy <= 1; ++dy)
          for (int dz = -1; dz <= 1; ++dz) {
            const std::int64_t k = pack(x + dx, y + dy, z + dz);
            for (size_t h = hash(k) & mask_; slots_[h].end != 0; h = (h + 1) & mask_) {
              if (slots_[h].key != k) continue;
              if (slot_seen_[h] == query_stamp_) break;
              slot_seen_[h] = query_stamp_;
              for (int e = slots_[h].begin; e < slots_[h].end; ++e) visit(ids_[e]);
              break;
            }
          }
    });
  }

 private:
  struct Slot {
    std::int64_t key = 0;
    int begin = 0, end = 0;  // end == 0: empty slot
  };

  // Cell coordinates wrap at 2^21 per axis (thousands of km at any sensible cell size); aliased cells only add
  // visits that the distance test rejects.
  static std::int64_t pack(std::int64_t x, std::int64_t y, std::int64_t z) {
    constexpr std::int64_t kOffset = 1 << 20, kMask = (1 << 21) - 1;
    return ((x + kOffset) & kMask) | (((y + kOffset) & kMask) << 21) | (((z + kOffset) & kMask) << 42);
  }
  static size_t hash(std::int64_t k) {
    std::uint64_t z = static_cast<std::uint64_t>(k) * 0x9e3779b97f4a7c15ULL;
    return static_cast<size_t>(z ^ (z >> 29));
  }

  // Calls f(x, y, z) for each cell holding a sample of s (consecutive repeats skipped).
  template <typename F>
  void for_each_sample_cell(const Segment& s, F&& f) const {
    const double len = s.length();
    // A segment longer than kMaxSamples steps (kilometres at LiDAR settings: only corrupted input, e.g. absurd
    // intrinsics) is not bucketed, so one bad frame cannot allocate without bound.
    if (!std::isfinite(len) || len > kMaxSamples * step_) return;
    const int n = 1 + static_cast<int>(std::ceil(len / step_));
    std::int64_t previous = 0;
    for (int i = 0; i <= n; ++i) {
      const Vec3 p = s.a + (s.b - s.a) * (static_cast<double>(i) / n);
      const std::int64_t cx = static_cast<std::int64_t>(std::floor(p.x() / cell_));
      const std::int64_t cy = static_cast<std::int64_t>(std::floor(p.y() / cell_));
      const std::int64_t cz = static_cast<std::int64_t>(std::floor(p.z() / cell_));
      const std::int64_t k = pack(cx, cy, cz);
      if (i > 0 && k == previous) continue;
      previous = k;
      f(cx, cy, cz);
    }
  }

  static constexpr double kMaxSamples = 4096.0;
  double cell_, step_;
  std::vector<std::pair<std::int64_t, int>> entries_;
  std::vector<int> ids_;
  std::vector<Slot> slots_;
  std::vector<std::uint32_t> slot_seen_;  // query stamp of the last query that visited the slot
  std::uint32_t query_stamp_ = 0;
  size_t mask_ = 0;
};

struct LinePair {
  const LineFeature* a;
  const LineFeature* b;
  double distance;
};

// Pairs of lines_a (frame a) with lines_b (frame b, moved into a by T) that pass the filters.
void match_lines(const std::vector<LineFeature>& lines_a, const std::vector<LineFeature>& lines_b,
                 const RigidTransform& T, const CandidateOptions& opt, std::vector<LinePair>* out) {
  std::vector<const LineFeature*> usable_a;
  usable_a.reserve(lines_a.size());
  for (const auto& l : lines_a)
    if (l.segment.a.allFinite() && l.segment.b.allFinite() && l.line.d.allFinite()) usable_a.push_back(&l);
  if (usable_a.empty()) return;
  SegmentGrid grid(usable_a, opt.max_distance);
  // Per line of a: bounding box of its segment (a box gap above max_distance rules the pair out before the exact
  // distance) and the norm of its normal.
  std::vector<Vec3> box_lo(usable_a.size()), box_hi(usable_a.size());
  std::vector<double> normal_norm(usable_a.size());
  for (size_t i = 0; i < usable_a.size(); ++i) {
    const Segment& s = usable_a[i]->segment;
    box_lo[i] = s.a.cwiseMin(s.b);
    box_hi[i] = s.a.cwiseMax(s.b);
    normal_norm[i] = usable_a[i]->normal.norm();
  }
  const double box_gap = opt.max_distance * (1.0 + 1e-9) + 1e-9;
  const double max_cos_lines = std::cos(deg2rad(opt.min_line_angle_deg));
  const double min_cos_normals = std::cos(deg2rad(opt.max_normal_angle_deg));

  std::vector<int> last_seen(usable_a.size(), -1);
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
    grid.for_each_near(sb, [&](int ia) {
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
    });
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
  std::vector<LinePair> pairs;
  match_lines(a.h_lines, b.v_lines, T_ab_guess, options, &pairs);  // H_a x V_b
  match_lines(a.v_lines, b.h_lines, T_ab_guess, options, &pairs);  // V_a x H_b

  // Cluster of the pair: the previous frame's normal cluster (paper §6.3), else the current frame's.
  std::array<int, 4> counts{};
  std::vector<int> group(pairs.size());
  for (size_t i = 0; i < pairs.size(); ++i) {
    int c = pairs[i].a->cluster;
    if (c < 0 || c > 2) c = pairs[i].b->cluster;
    group[i] = (c >= 0 && c <= 2) ? c : 3;
    ++counts[group[i]];
  }
  const int groups = static_cast<int>(std::count_if(counts.begin(), counts.end(), [](int n) { return n > 0; }));

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
    // Inverse cluster size, scaled so that the weights average to 1 over all pairs.
    out->weights.push_back(static_cast<double>(n) / (groups * counts[group[i]]));
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

double score_motion(const Correspondences& candidates, const RigidTransform& T_ab, double threshold,
                    double min_sine, int* inliers) {
  const size_t n = std::min(candidates.lines_a.size(), candidates.lines_b.size());
  const bool weighted = candidates.weights.size() == n;
  const double th2 = threshold * threshold, min_s2 = min_sine * min_sine;
  double score = 0.0;
  int count = 0;
  for (size_t i = 0; i < n; ++i) {
    const PluckerLine& a = candidates.lines_a[i];
    const PluckerLine b = candidates.lines_b[i].moved(T_ab);
    const double f = reciprocal_product(a, b);
    const double s2 = a.d.cross(b.d).squaredNorm();
    if (s2 >= min_s2 && f * f < th2 * s2) {
      score += weighted ? candidates.weights[i] : 1.0;
      ++count;
    }
  }
  if (inliers) *inliers = count;
  return score;
}

}  // namespace line_odom
