#include "registration/candidates.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <deque>
#include <limits>
#include <utility>

#include "common/worker_pool.hpp"
#include "common/simd.hpp"

#if defined(__SSE2__)
#include <emmintrin.h>
#endif

namespace line_odom {

namespace {

// FNV-1a over the size and the endpoint coordinates' bits of a scan's lines: which scan a cached listing belongs to.
std::uint64_t segments_fingerprint(const std::vector<LineFeature>& lines) {
  std::uint64_t h = 1469598103934665603ull ^ lines.size();
  auto mix = [&h](double v) {
    std::uint64_t bits;
    std::memcpy(&bits, &v, sizeof bits);
    h = (h ^ bits) * 1099511628211ull;
  };
  for (const LineFeature& l : lines)
    for (const Vec3* p : {&l.segment.a, &l.segment.b}) mix(p->x()), mix(p->y()), mix(p->z());
  return h;
}

double deg2rad(double deg) { return deg * kPi / 180.0; }

// Segments are bucketed in a dense voxel grid over their bounding box by points sampled along them. With
// samples every cell/3 along both segments, two segments closer than `max_distance` = 2/3 cell have samples
// in neighbouring cells. Each segment is filed under the 27-cell neighbourhood of its samples, so a query only
// reads the cells of its own samples. Cells are a CSR array: a lookup is an index, not a hash probe.
class SegmentGrid {
 public:
  // Cells of size `cell` (cell_for) over the bounds lo..hi of the segments (bounds).
  SegmentGrid(const std::vector<const LineFeature*>& lines, const Vec3& lo, const Vec3& hi, double cell) {
    const Vec3 extent = hi - lo;
    cell_ = cell;
    step_ = cell_ / 3.0;
    origin_ = lo - Vec3::Constant(2.0 * cell_);  // two cells of margin hold the neighbourhoods of the samples
    for (int k = 0; k < 3; ++k) size_[k] = static_cast<int>(extent[k] / cell_) + 5;

    inverse_cell_ = 1.0 / cell_;

    const size_t total = static_cast<size_t>(size_[0]) * size_[1] * size_[2];
    std::vector<int> filed_by(total, -1);  // last line filed under the cell
    std::vector<std::pair<int, int>> entries;  // (cell, line id)
    const int sx = size_[1] * size_[2], sy = size_[2];
    std::array<int, 27> neighbours;
    for (int x = -1, i = 0; x <= 1; ++x)
      for (int y = -1; y <= 1; ++y)
        for (int z = -1; z <= 1; ++z) neighbours[i++] = x * sx + y * sy + z;
    for (int id = 0; id < static_cast<int>(lines.size()); ++id) {
      for_each_sample_cell(lines[id]->segment, [&](int cell) {
        for (const int offset : neighbours) {
          const int c = cell + offset;
          if (filed_by[c] == id) continue;
          filed_by[c] = id;
          entries.emplace_back(c, id);
        }
      });
    }
    begin_.assign(total + 1, 0);
    for (const auto& e : entries) ++begin_[e.first + 1];
    for (size_t c = 1; c < begin_.size(); ++c) begin_[c] += begin_[c - 1];
    ids_.resize(entries.size());
    std::vector<int> fill(begin_.begin(), begin_.end() - 1);
    for (const auto& e : entries) ids_[fill[e.first]++] = e.second;
  }

  double cell() const { return cell_; }

  // Calls visit(id) for every bucketed segment with a sample in a cell next to a sample of `query`
  // (an id may be visited more than once).
  template <typename Visit>
  void for_each_near(const Segment& query, Visit&& visit) const {
    for_each_sample_cell(query, [&](int cell) {
      for (int e = begin_[cell]; e < begin_[cell + 1]; ++e) visit(ids_[e]);
    });
  }

  static bool bounds(const std::vector<const LineFeature*>& lines, Vec3* lo, Vec3* hi) {
    *lo = Vec3::Constant(std::numeric_limits<double>::infinity());
    *hi = -*lo;
    for (const LineFeature* l : lines) {
      *lo = lo->cwiseMin(l->segment.a).cwiseMin(l->segment.b);
      *hi = hi->cwiseMax(l->segment.a).cwiseMax(l->segment.b);
    }
    return !lines.empty() && lo->allFinite() && hi->allFinite();
  }
  // Coarser cells keep any grid (e.g. a frame with a far-away outlier) within a fixed size; correctness only
  // needs cell >= 1.5 max_distance.
  static double cell_for(const Vec3& extent, double max_distance, double max_cells) {
    double cell = 1.5 * std::max(max_distance, 1e-3);
    while ((extent.array() / cell + 5.0).prod() > max_cells) cell *= 2.0;
    return cell;
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
    // Sample i sits at (start + i * delta) cells from the origin.
    const Vec3 start = (s.a - origin_) * inverse_cell_, delta = (s.b - s.a) * (inverse_cell_ / n);
    const double hx = size_[0] - 2, hy = size_[1] - 2, hz = size_[2] - 2;
    int previous = -1;
    for (int i = 0; i <= n; ++i) {
      const double x = std::floor(start[0] + delta[0] * i), y = std::floor(start[1] + delta[1] * i),
                   z = std::floor(start[2] + delta[2] * i);
      if (!(x >= 1.0 && x <= hx && y >= 1.0 && y <= hy && z >= 1.0 && z <= hz)) continue;
      const int cell = (static_cast<int>(x) * size_[1] + static_cast<int>(y)) * size_[2] + static_cast<int>(z);
      if (cell == previous) continue;
      previous = cell;
      f(cell);
    }
  }

  static constexpr double kMaxSamples = 4096.0;
  double cell_ = 1.0, step_ = 1.0, inverse_cell_ = 1.0;
  Vec3 origin_ = Vec3::Zero();
  std::array<int, 3> size_{};
  std::vector<int> begin_, ids_;
};

// Up to this many line pairs, match without the grid: a box scan (listed for the later passes) costs less than the
// grids up to full-resolution KITTI frames registering ~3000 lines.
constexpr double kBruteForcePairs = 2e6;
constexpr double kMaxCells = 1 << 21;  // grid size bound: coarser cells beyond (any frame costs a bounded grid)
// The search for a line's closest partners (max_pairs_per_line > 0) looks within this share of the pass distance
// first.
constexpr double kNearFraction = 0.25;
// The lines near a line of b are listed within the pass distance and this share of it beyond: a later pass whose guess
// moved the segment less than that re-tests the listed lines instead of searching them again.
constexpr double kListMargin = 0.1;
// A grid with cells up to this many times coarser than a pass asks for serves it: on full KITTI frames the 0.5 m pass
// visiting more partners in the 1 m pass's grid (1.5 m cells) costs less than building a grid of 0.75 m cells.
constexpr double kGridReuse = 2.0;

// A segment as segment_distance reads it: start, start-to-end vector and its squared length (kept per line of
// frame a and per moved line of b, so that a distance computes only what depends on both).
struct SegmentSpan {
  Vec3 start, d;
  double d2;
  static SegmentSpan of(const Segment& s) {
    const Vec3 d = s.b - s.a;
    return {s.a, d, d.squaredNorm()};
  }
};

// segment_distance of the spans.
double span_distance(const SegmentSpan& s1, const SegmentSpan& s2) {
  // Closest points p1 + s d1 and p2 + t d2, s, t in [0, 1] (clamped least squares).
  const Vec3 &d1 = s1.d, &d2 = s2.d, r = s1.start - s2.start;
  const double a = s1.d2, e = s2.d2, f = d2.dot(r);
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
  return ((s1.start + d1 * s) - (s2.start + d2 * t)).norm();
}

using FloatLanes = simd::F4f;
using FloatLaneMask = simd::I4f;

// Whether lanes x, y and z of a compare hold true.
inline bool all_of_xyz(FloatLaneMask m) {
#if defined(__SSE2__)
  return (_mm_movemask_ps(reinterpret_cast<__m128>(m)) & 7) == 7;
#else
  return (m[0] & m[1] & m[2]) != 0;
#endif
}

// A float box (rounded outwards) of a line of frame a: lo x y z and hi x y z, each padded to 4 lanes.
struct FloatBox {
  FloatLanes lo, hi;
};

// A partner that passed the filters, with the squared gap between the bounding boxes (a lower bound of the
// squared segment distance).
struct Nearby {
  int ia;
  double box_gap2;
};

struct LinePair {
  const LineFeature* a;
  const LineFeature* b;
  double distance;
};

// What the filters read of the lines of frame a, one column per value so that a kernel tests four partners at once.
// A line without a known normal has normal 0 and normal_norm 0: its normal test divides 0 by 0 and never rejects.
struct PartnerColumns {
  std::array<std::vector<double>, 3> box_lo, box_hi;  // segment bounding box: a gap above the distance rules out
  std::array<std::vector<double>, 3> d;                // line direction
  std::array<std::vector<double>, 3> normal;           // surface normal (0 if unknown)
  std::vector<double> normal_norm;
};

// One line of frame b moved into frame a, as the filters read it.
struct PartnerQuery {
  std::array<double, 3> box_lo, box_hi, d, normal;
  double normal_norm;
  bool normal_known;
  double box_gap;          // the distance with its rounding margin
  double max_cos_lines;    // |cos| of the smallest angle between the lines
  double min_cos_normals;  // |cos| of the largest angle between known normals
};

// (The helpers are always inlined: no vector crosses a call, whose ABI differs between the clones.)
using Lanes = simd::F4;
using LaneMask = simd::I4;

inline __attribute__((always_inline)) Lanes lanes_at(const std::vector<double>& column, const int* ids) {
  const double* p = column.data();
  return Lanes{p[ids[0]], p[ids[1]], p[ids[2]], p[ids[3]]};
}
inline __attribute__((always_inline)) Lanes absolute(const Lanes& v) { return v < 0.0 ? -v : v; }
inline __attribute__((always_inline)) Lanes larger(const Lanes& x, const Lanes& y) { return x > y ? x : y; }
inline __attribute__((always_inline)) Lanes clamp01(const Lanes& v) {
  const Lanes zero = {0.0, 0.0, 0.0, 0.0}, one = {1.0, 1.0, 1.0, 1.0};
  return v < zero ? zero : (one < v ? one : v);  // std::clamp(v, 0.0, 1.0)
}

// The lines `ids` (count of them, readable up to a whole multiple of 4) of frame a that pass the filters of `q`,
// written to `out` with their squared box gaps; returns how many. The same sums in the same order as the scalar
// Eigen expressions: |n_a . n_b| / (|n_a| |n_b|) < min_cos_normals (both normals known), |d_a . d_b| >
// max_cos_lines and a box gap above box_gap reject; the squared gap is ((x^2 + y^2) + z^2).
LINE_ODOM_VECTOR_CLONES
size_t filter_partners(const PartnerColumns& c, const int* ids, size_t count, const PartnerQuery& q, Nearby* out) {
  size_t kept = 0;
  const Lanes zero = {0.0, 0.0, 0.0, 0.0};
  for (size_t i = 0; i < count; i += 4) {
    const int* const group = ids + i;
    const Lanes lo_x = lanes_at(c.box_lo[0], group) - q.box_hi[0], lo_y = lanes_at(c.box_lo[1], group) - q.box_hi[1],
                lo_z = lanes_at(c.box_lo[2], group) - q.box_hi[2];
    const Lanes hi_x = q.box_lo[0] - lanes_at(c.box_hi[0], group), hi_y = q.box_lo[1] - lanes_at(c.box_hi[1], group),
                hi_z = q.box_lo[2] - lanes_at(c.box_hi[2], group);
    LaneMask reject = (lo_x > q.box_gap) | (lo_y > q.box_gap) | (lo_z > q.box_gap) | (hi_x > q.box_gap) |
                      (hi_y > q.box_gap) | (hi_z > q.box_gap);
    const Lanes d_dot =
        (lanes_at(c.d[0], group) * q.d[0] + lanes_at(c.d[1], group) * q.d[1]) + lanes_at(c.d[2], group) * q.d[2];
    reject |= absolute(d_dot) > q.max_cos_lines;
    if (q.normal_known) {
      const Lanes n_dot =
          (lanes_at(c.normal[0], group) * q.normal[0] + lanes_at(c.normal[1], group) * q.normal[1]) +
          lanes_at(c.normal[2], group) * q.normal[2];
      reject |= absolute(n_dot) / (lanes_at(c.normal_norm, group) * q.normal_norm) < q.min_cos_normals;
    }
    const Lanes gap_x = larger(larger(lo_x, hi_x), zero), gap_y = larger(larger(lo_y, hi_y), zero),
                gap_z = larger(larger(lo_z, hi_z), zero);
    const Lanes gap2 = (gap_x * gap_x + gap_y * gap_y) + gap_z * gap_z;
    const int lanes = static_cast<int>(std::min<size_t>(4, count - i));
    for (int l = 0; l < lanes; ++l) {
      out[kept] = {ids[i + l], gap2[l]};
      kept += reject[l] == 0;
    }
  }
  return kept;
}

// span_distance of the spans `ids[0..3]` of frame a to `b`, into distances[0..3]: lane by lane the same operations
// in the same order, the branches as selects. Requires b.d2 > 1e-18 (span_distance otherwise).
LINE_ODOM_VECTOR_CLONES
void span_distances(const SegmentSpan* spans, const int* ids, const SegmentSpan& b, double* distances) {
  const SegmentSpan &s0 = spans[ids[0]], &s1 = spans[ids[1]], &s2 = spans[ids[2]], &s3 = spans[ids[3]];
  const Lanes zero = {0.0, 0.0, 0.0, 0.0}, one = {1.0, 1.0, 1.0, 1.0};
  Lanes start[3], d[3];
  for (int k = 0; k < 3; ++k) {
    start[k] = Lanes{s0.start[k], s1.start[k], s2.start[k], s3.start[k]};
    d[k] = Lanes{s0.d[k], s1.d[k], s2.d[k], s3.d[k]};
  }
  const Lanes a = {s0.d2, s1.d2, s2.d2, s3.d2};
  const double e = b.d2;
  const Lanes r_x = start[0] - b.start[0], r_y = start[1] - b.start[1], r_z = start[2] - b.start[2];
  const Lanes f = (b.d[0] * r_x + b.d[1] * r_y) + b.d[2] * r_z;
  const Lanes c = (d[0] * r_x + d[1] * r_y) + d[2] * r_z;
  const Lanes bd = (d[0] * b.d[0] + d[1] * b.d[1]) + d[2] * b.d[2];
  const Lanes denom = a * e - bd * bd;
  const Lanes s_free = denom > 1e-18 * a * e ? clamp01((bd * f - c * e) / denom) : zero;
  const Lanes t_free = (bd * s_free + f) / e;
  const Lanes s_general = t_free < zero ? clamp01(-c / a) : (t_free > one ? clamp01((bd - c) / a) : s_free);
  const Lanes t_general = t_free < zero ? zero : (t_free > one ? one : t_free);
  const auto point_a = a <= 1e-18;  // a point: the closest point of b to it
  const Lanes s = point_a ? zero : s_general;
  const Lanes t = point_a ? clamp01(f / e) : t_general;
  const Lanes p_x = (start[0] + d[0] * s) - (b.start[0] + b.d[0] * t);
  const Lanes p_y = (start[1] + d[1] * s) - (b.start[1] + b.d[1] * t);
  const Lanes p_z = (start[2] + d[2] * s) - (b.start[2] + b.d[2] * t);
  const Lanes norm2 = (p_x * p_x + p_y * p_y) + p_z * p_z;
  for (int l = 0; l < 4; ++l) distances[l] = std::sqrt(norm2[l]);
}

}  // namespace

// The usable lines of one kind (H or V) of frame a with what the filters and distances read, their grids and the work
// buffers of a match.
struct CandidateIndex::Lines {
  std::vector<const LineFeature*> lines;
  const LineFeature* all_begin;  // the lines they were taken from
  std::size_t all_count;
  PartnerColumns columns;
  std::vector<SegmentSpan> spans;     // the segments, for their distances
  double magnitude = 0.0;  // largest |coordinate| of the segments (bounds the rounding of their distances)
  // The boxes as float columns (lo x y z, hi x y z), rounded outwards: a vectorizable prefilter.
  std::array<std::vector<float>, 6> box_columns;
  std::vector<FloatBox> float_boxes;  // the same boxes by line (the re-test of listed lines reads one at a time)
  bool have_bounds = false;  // bounds of the segments, for the grids
  Vec3 lo, hi;
  // Grids built on first use (small frames are matched without), kept for any later pass that needs their cells.
  std::deque<SegmentGrid> grids;
  // Work buffers of match_lines, sized for the lines.
  std::vector<int> last_seen;
  int stamp = -1;
  std::vector<std::uint8_t> overlap;
  std::vector<Nearby> nearby;
  std::vector<int> partner_ids;  // lines of frame a whose boxes come near the line of b, before the filters
  std::vector<std::pair<double, int>> best;
  // The lines listed near the lines of lines_b (match_lines): per line of b its moved segment when listed, the
  // distance listed within and the range of its listed lines (-1, -1 before a listing).
  const std::vector<LineFeature>* listed_b = nullptr;
  std::uint64_t listed_fingerprint = 0;  // of listed_b's segments: another scan at the same address is not it
  std::vector<Segment> listed_at;
  std::vector<double> listed_within;
  std::vector<std::pair<int, int>> listed_range;  // [begin, end) in listed_ids
  std::vector<int> listed_ids;

  // How many of the usable lines come from the first n of `all` (usable keeps their order).
  int usable_before(std::size_t n) const {
    if (n >= all_count) return static_cast<int>(lines.size());
    return static_cast<int>(std::lower_bound(lines.begin(), lines.end(), all_begin + n) - lines.begin());
  }

  explicit Lines(const std::vector<LineFeature>& all)
      : lines(usable(all)), all_begin(all.data()), all_count(all.size()) {
    spans.resize(lines.size());
    for (auto& c : box_columns) c.resize(lines.size());
    float_boxes.resize(lines.size());
    for (int k = 0; k < 3; ++k)
      for (auto* column : {&columns.box_lo[k], &columns.box_hi[k], &columns.d[k], &columns.normal[k]})
        column->resize(lines.size());
    columns.normal_norm.resize(lines.size());
    for (size_t i = 0; i < lines.size(); ++i) {
      const LineFeature& l = *lines[i];
      const Vec3 box_lo = l.segment.a.cwiseMin(l.segment.b), box_hi = l.segment.a.cwiseMax(l.segment.b);
      const bool normal_known = l.normal.squaredNorm() > 0.25;
      spans[i] = SegmentSpan::of(l.segment);
      for (int k = 0; k < 3; ++k) {
        columns.box_lo[k][i] = box_lo[k];
        columns.box_hi[k][i] = box_hi[k];
        columns.d[k][i] = l.line.d[k];
        columns.normal[k][i] = normal_known ? l.normal[k] : 0.0;
        box_columns[k][i] = round_down(box_lo[k]);
        box_columns[3 + k][i] = round_up(box_hi[k]);
      }
      columns.normal_norm[i] = normal_known ? l.normal.norm() : 0.0;
      float_boxes[i].lo = FloatLanes{box_columns[0][i], box_columns[1][i], box_columns[2][i], 0.0f};
      float_boxes[i].hi = FloatLanes{box_columns[3][i], box_columns[4][i], box_columns[5][i], 0.0f};
      magnitude = std::max({magnitude, box_lo.cwiseAbs().maxCoeff(), box_hi.cwiseAbs().maxCoeff()});
    }
    have_bounds = SegmentGrid::bounds(lines, &lo, &hi);
    last_seen.assign(lines.size(), -1);
    overlap.resize(lines.size() + 32);  // padded to whole 32-byte blocks (the padding stays 0)
    nearby.resize(lines.size());       // a line of frame a at most once per search
    partner_ids.resize(lines.size() + 3);  // the same, padded to whole groups of 4 for filter_partners
  }

  // A grid for segments within max_distance with at most about max_cells cells: one built before whose cells are
  // at least as large and at most kGridReuse times larger, else a new one. Requires have_bounds.
  const SegmentGrid& grid(double max_distance, double max_cells) {
    const double cell = SegmentGrid::cell_for(hi - lo, max_distance, max_cells);
    for (const SegmentGrid& g : grids)
      if (g.cell() >= cell && g.cell() <= kGridReuse * cell) return g;
    return grids.emplace_back(lines, lo, hi, cell);
  }

  // Outward rounding to float: v itself when exact, else the float next to it on the outer side.
  static float round_down(double v) {
    const float f = static_cast<float>(v);
    return static_cast<double>(f) <= v ? f : next_float(f, false);
  }
  static float round_up(double v) {
    const float f = static_cast<float>(v);
    return static_cast<double>(f) >= v ? f : next_float(f, true);
  }
  // std::nextafter(f, +-infinity), inline for finite nonzero f (one step of the bit pattern).
  static float next_float(float f, bool up) {
    if (f == 0.0f || !std::isfinite(f))
      return std::nextafter(f, up ? std::numeric_limits<float>::infinity() : -std::numeric_limits<float>::infinity());
    std::uint32_t bits;
    std::memcpy(&bits, &f, sizeof bits);
    bits = (f > 0.0f) == up ? bits + 1 : bits - 1;  // away from zero: larger magnitude
    std::memcpy(&f, &bits, sizeof f);
    return f;
  }

  static std::vector<const LineFeature*> usable(const std::vector<LineFeature>& all) {
    std::vector<const LineFeature*> out;
    out.reserve(all.size());
    for (const auto& l : all)
      if (l.segment.a.allFinite() && l.segment.b.allFinite() && l.line.d.allFinite()) out.push_back(&l);
    return out;
  }
};

namespace {

using IndexedLines = CandidateIndex::Lines;

// The distances of sb to the segments of `count` (1 to 4) lines `ids` of frame a.
void measure_group(const IndexedLines& indexed, const int* ids, int count, const SegmentSpan& sb, double* distances) {
  if (sb.d2 > 1e-18) {
    const int last = count - 1;
    const int lanes[4] = {ids[0], ids[std::min(1, last)], ids[std::min(2, last)], ids[std::min(3, last)]};
    span_distances(indexed.spans.data(), lanes, sb, distances);
  } else {
    for (int l = 0; l < count; ++l) distances[l] = span_distance(indexed.spans[ids[l]], sb);
  }
}

// overlap[i] = 1 where box i (float columns lo x y z, hi x y z) reaches into `reach` (hi x y z, lo x y z).
LINE_ODOM_VECTOR_CLONES
void mark_box_overlaps(const std::array<std::vector<float>, 6>& columns, const std::array<float, 6>& reach,
                       std::uint8_t* __restrict overlap) {
  const float* __restrict lx = columns[0].data();
  const float* __restrict ly = columns[1].data();
  const float* __restrict lz = columns[2].data();
  const float* __restrict hx = columns[3].data();
  const float* __restrict hy = columns[4].data();
  const float* __restrict hz = columns[5].data();
  const float rx = reach[0], ry = reach[1], rz = reach[2], qx = reach[3], qy = reach[4], qz = reach[5];
  const int n = static_cast<int>(columns[0].size());
  for (int i = 0; i < n; ++i)
    overlap[i] = (lx[i] <= rx) & (ly[i] <= ry) & (lz[i] <= rz) & (hx[i] >= qx) & (hy[i] >= qy) & (hz[i] >= qz);
}

// The k partners closest by (distance, line of frame a) among `nearby`, those within max_distance; the same
// choice as computing every distance and keeping the k smallest (the order of the measurements does not matter).
// A partner whose box gap exceeds the k-th distance found so far (with a margin far above rounding) cannot be among
// them and is not measured.
void closest_partners(Nearby* nearby, size_t n, const IndexedLines& indexed, const SegmentSpan& sb,
                      double sb_magnitude, double max_distance, int k, std::vector<std::pair<double, int>>* best) {
  best->clear();
  if (k <= 0) return;
  auto before = [](const std::pair<double, int>& x, const std::pair<double, int>& y) {
    return x.first < y.first || (x.first == y.first && x.second < y.second);
  };
  const double margin = 1e-9 + 1e-12 * (sb_magnitude + indexed.magnitude);
  double bound2 = std::numeric_limits<double>::infinity();  // squared k-th distance + margin (all until k found)
  auto take = [&](double dist, int ia) {
    if (!(dist <= max_distance)) return;
    const std::pair<double, int> p{dist, ia};
    if (static_cast<int>(best->size()) < k) {
      best->push_back(p);
    } else if (before(p, best->back())) {
      best->back() = p;
    } else {
      return;
    }
    for (size_t j = best->size() - 1; j > 0 && before((*best)[j], (*best)[j - 1]); --j)
      std::swap((*best)[j], (*best)[j - 1]);
    if (static_cast<int>(best->size()) == k) {
      const double bound = best->back().first + margin;
      bound2 = bound * bound;
    }
  };
  // Measured four at a time (a bound a few measurements old only measures more).
  int group[4];
  int grouped = 0;
  auto flush = [&]() {
    if (grouped == 0) return;
    double distances[4];
    measure_group(indexed, group, grouped, sb, distances);
    for (int l = 0; l < grouped; ++l) take(distances[l], group[l]);
    grouped = 0;
  };
  auto measure = [&](int ia) {
    group[grouped++] = ia;
    if (grouped == 4) flush();
  };
  const size_t first = std::min(n, static_cast<size_t>(k));
  if (n > first) {
    // Measure the k smallest box gaps first: their distances bound the k-th distance from the start. Kept sorted
    // in the first k places; a later gap enters only when below the largest of them.
    for (size_t i = 1; i < first; ++i)
      for (size_t j = i; j > 0 && nearby[j].box_gap2 < nearby[j - 1].box_gap2; --j) std::swap(nearby[j], nearby[j - 1]);
    for (size_t i = first; i < n; ++i) {
      if (!(nearby[i].box_gap2 < nearby[first - 1].box_gap2)) continue;
      std::swap(nearby[i], nearby[first - 1]);
      for (size_t j = first - 1; j > 0 && nearby[j].box_gap2 < nearby[j - 1].box_gap2; --j)
        std::swap(nearby[j], nearby[j - 1]);
    }
  }
  for (size_t i = 0; i < first; ++i) measure(nearby[i].ia);
  flush();
  for (size_t i = first; i < n; ++i) {
    const Nearby& c = nearby[i];
    if (c.box_gap2 > bound2) continue;
    measure(c.ia);
  }
  flush();
}

// Pairs of lines of frame a (indexed) with lines_b (frame b, moved into a by T) that pass the filters.
// Only the first `taken` usable lines of frame a are partners.
void match_lines(IndexedLines& indexed, const std::vector<LineFeature>& lines_b, const RigidTransform& T,
                 const CandidateOptions& opt, int taken, std::vector<LinePair>* out) {
  const std::vector<const LineFeature*>& usable_a = indexed.lines;
  if (usable_a.empty()) return;
  const double max_cos_lines = std::cos(deg2rad(opt.min_line_angle_deg));
  const double min_cos_normals = std::cos(deg2rad(opt.max_normal_angle_deg));
  const int k = opt.max_pairs_per_line;

  // (Usable lines are finite: they always have bounds.)
  const bool brute_force =
      static_cast<double>(usable_a.size()) * lines_b.size() <= kBruteForcePairs || !indexed.have_bounds;
  // The listings of lines_b's lines (below) belong to lines_b: another scan starts them afresh.
  const double list_distance = opt.max_distance * (1.0 + kListMargin);
  const double list_gap = list_distance * (1.0 + 1e-9) + 1e-9;
  const std::uint64_t fingerprint = segments_fingerprint(lines_b);
  if (indexed.listed_b != &lines_b || indexed.listed_fingerprint != fingerprint) {
    indexed.listed_b = &lines_b;
    indexed.listed_fingerprint = fingerprint;
    indexed.listed_at.assign(lines_b.size(), {});
    indexed.listed_within.assign(lines_b.size(), 0.0);
    indexed.listed_range.assign(lines_b.size(), {-1, -1});
    indexed.listed_ids.clear();
  }
  std::vector<int>& last_seen = indexed.last_seen;
  int& stamp = indexed.stamp;
  std::uint8_t* const overlap = indexed.overlap.data();
  Nearby* const nearby = indexed.nearby.data();
  size_t nearby_count = 0;
  std::vector<std::pair<double, int>>& best = indexed.best;
  // Grids are built for a slightly larger distance: a partner measured within the distance is certainly found.
  const SegmentGrid* list_grid = nullptr;
  for (int ib = 0; ib < static_cast<int>(lines_b.size()); ++ib) {
    const LineFeature& lb = lines_b[ib];
    if (!lb.segment.a.allFinite() || !lb.segment.b.allFinite() || !lb.line.d.allFinite()) continue;
    const Segment sb = lb.segment.moved(T);
    const Vec3 db = T.R * lb.line.d;
    const bool nb_known = lb.normal.squaredNorm() > 0.25;
    const Vec3 nb = T.R * lb.normal;
    const double nb_norm = nb.norm();
    const Vec3 sb_lo = sb.a.cwiseMin(sb.b), sb_hi = sb.a.cwiseMax(sb.b);
    const double sb_magnitude = std::max(sb_lo.cwiseAbs().maxCoeff(), sb_hi.cwiseAbs().maxCoeff());
    const SegmentSpan sb_span = SegmentSpan::of(sb);
    // The float box of sb widened by `gap`, rounded outwards: (hi x y z, lo x y z).
    auto box_reach = [&](double gap) {
      std::array<float, 6> reach;
      for (int c = 0; c < 3; ++c) {
        reach[c] = IndexedLines::round_up(sb_hi[c] + gap + 1e-9);
        reach[3 + c] = IndexedLines::round_down(sb_lo[c] - gap - 1e-9);
      }
      return reach;
    };
    // Calls emit(ia) for the lines whose float boxes reach into sb's box widened by `gap`: a scan of the boxes where
    // pairs are few (it costs less than the grid's cell lists), else those in the grid's cells near sb.
    auto collect = [&](double gap, auto&& emit) {
      const std::array<float, 6> wide = box_reach(gap);
      if (brute_force) {
        mark_box_overlaps(indexed.box_columns, wide, overlap);
        const int na = static_cast<int>(usable_a.size());
        for (int block = 0; block < na; block += 32) {
          std::uint64_t words[4];  // overlaps are few: 32 boxes at a time, then only the set bytes
          std::memcpy(words, overlap + block, sizeof words);
          if ((words[0] | words[1] | words[2] | words[3]) == 0) continue;
          for (int w = 0; w < 4; ++w) {
            const int word = block + 8 * w;
#if defined(__GNUC__) && __BYTE_ORDER__ == __ORDER_LITTLE_ENDIAN__
            for (std::uint64_t any = words[w]; any != 0; any &= any - 1) emit(word + (__builtin_ctzll(any) >> 3));
#else
            if (words[w] != 0)
              for (int ia = word; ia < std::min(word + 8, na); ++ia)
                if (overlap[ia]) emit(ia);
#endif
          }
        }
        return;
      }
      if (!list_grid) list_grid = &indexed.grid(list_distance * (1.0 + 1e-6), kMaxCells);
      const FloatLanes wide_hi = {wide[0], wide[1], wide[2], 0.0f}, wide_lo = {wide[3], wide[4], wide[5], 0.0f};
      ++stamp;
      list_grid->for_each_near(sb, [&](int ia) {  // the grid may visit a line more than once
        if (last_seen[ia] == stamp) return;
        last_seen[ia] = stamp;
        const FloatBox& box = indexed.float_boxes[ia];
        if (all_of_xyz((box.lo <= wide_hi) & (box.hi >= wide_lo))) emit(ia);
      });
    };
    // The lines near sb: its listing by an earlier call, while sb has moved less than that listing's distance less
    // the pass distance since (a point of sb is at most that far from the point at the same place along the listed
    // segment: the segments' points are convex combinations of their endpoints). A line without a listing is listed
    // now (the passes of a frame move it little); one whose listing is out of reach (a search's guesses far apart)
    // is searched without.
    const double pass_gap = opt.max_distance * (1.0 + 1e-9) + 1e-9;
    std::pair<int, int> range = indexed.listed_range[ib];
    bool listed = false;
    if (range.first < 0) {
      const int begin = static_cast<int>(indexed.listed_ids.size());
      collect(list_gap, [&](int ia) { indexed.listed_ids.push_back(ia); });
      range = {begin, static_cast<int>(indexed.listed_ids.size())};
      indexed.listed_at[ib] = sb;
      indexed.listed_within[ib] = list_distance;
      indexed.listed_range[ib] = range;
      listed = true;
    } else {
      const Segment& at = indexed.listed_at[ib];
      listed = pass_gap + std::max((sb.a - at.a).norm(), (sb.b - at.b).norm()) <= indexed.listed_within[ib];
    }
    // Fills `nearby` with the lines of frame a that pass the filters and whose boxes come within `distance`
    // (a superset of the partners within `distance`).
    PartnerQuery query;
    for (int c = 0; c < 3; ++c) {
      query.box_lo[c] = sb_lo[c];
      query.box_hi[c] = sb_hi[c];
      query.d[c] = db[c];
      query.normal[c] = nb[c];
    }
    query.normal_norm = nb_norm;
    query.normal_known = nb_known;
    query.max_cos_lines = max_cos_lines;
    query.min_cos_normals = min_cos_normals;
    auto gather = [&](double distance) {
      const double box_gap = distance * (1.0 + 1e-9) + 1e-9;
      query.box_gap = box_gap;
      int* const ids = indexed.partner_ids.data();
      size_t id_count = 0;
      if (listed) {
        // The listed lines whose float boxes reach into sb's box widened by box_gap.
        const std::array<float, 6> reach = box_reach(box_gap);
        const FloatLanes reach_hi = {reach[0], reach[1], reach[2], 0.0f};
        const FloatLanes reach_lo = {reach[3], reach[4], reach[5], 0.0f};
        for (int e = range.first; e < range.second; ++e) {
          const int ia = indexed.listed_ids[e];
          const FloatBox& box = indexed.float_boxes[ia];
          ids[id_count] = ia;
          id_count += (ia < taken) & all_of_xyz((box.lo <= reach_hi) & (box.hi >= reach_lo));
        }
      } else {
        collect(box_gap, [&](int ia) {
          if (ia < taken) ids[id_count++] = ia;
        });
      }
      for (size_t pad = id_count; pad < id_count + 3; ++pad) ids[pad] = 0;
      nearby_count = filter_partners(indexed.columns, ids, id_count, query, nearby);
    };
    best.clear();
    if (k > 0) {
      // Most lines have their k closest partners much nearer than the pass distance: on a listing, look there first.
      // When k partners lie within near_distance, no partner farther away can displace them.
      const double near_distance = opt.max_distance * kNearFraction;
      if (listed) {
        gather(near_distance);
        closest_partners(nearby, nearby_count, indexed, sb_span, sb_magnitude, near_distance, k, &best);
      }
      if (static_cast<int>(best.size()) < k) {
        gather(opt.max_distance);
        closest_partners(nearby, nearby_count, indexed, sb_span, sb_magnitude, opt.max_distance, k, &best);
      }
    } else {
      gather(opt.max_distance);
      for (size_t i = 0; i < nearby_count; i += 4) {
        const int count = static_cast<int>(std::min<size_t>(4, nearby_count - i));
        int ids[4];
        double distances[4];
        for (int l = 0; l < count; ++l) ids[l] = nearby[i + l].ia;
        measure_group(indexed, ids, count, sb_span, distances);
        for (int l = 0; l < count; ++l)
          if (distances[l] <= opt.max_distance) best.emplace_back(distances[l], ids[l]);
      }
    }
    // Deterministic order regardless of grid traversal: by line of frame a.
    std::sort(best.begin(), best.end(), [](const auto& x, const auto& y) { return x.second < y.second; });
    for (const auto& p : best) out->push_back({usable_a[p.second], &lb, p.first});
  }
}

}  // namespace

double segment_distance(const Segment& s1, const Segment& s2) {
  return span_distance(SegmentSpan::of(s1), SegmentSpan::of(s2));
}

CandidateIndex::CandidateIndex(const ScanFeatures& a)
    : a_(&a), h_(std::make_unique<Lines>(a.h_lines)), v_(std::make_unique<Lines>(a.v_lines)) {}

CandidateIndex::~CandidateIndex() = default;

void build_candidates(CandidateIndex& index, const ScanFeatures& b, const RigidTransform& T_ab_guess,
                      const CandidateOptions& options, Correspondences* out, CandidateStats* stats, WorkerPool* pool,
                      const CandidateSubset& subset) {
  *out = Correspondences{};
  const ScanFeatures& a = *index.a_;
  std::vector<LinePair> pairs;
  if (options.max_pairs_per_line > 0)  // at most k per line of b
    pairs.reserve(static_cast<size_t>(options.max_pairs_per_line) * (b.v_lines.size() + b.h_lines.size()));
  const int h_taken = index.h_->usable_before(subset.h_lines), v_taken = index.v_->usable_before(subset.v_lines);
  constexpr size_t kMinSharedLines = 1000;  // fewer lines of b: waking a worker costs about what it saves
  if (has_workers(pool) && b.h_lines.size() + b.v_lines.size() >= kMinSharedLines) {
    std::vector<LinePair> v_pairs;  // each search touches only its own index
    pool->run(2, [&](int task) {
      if (task == 0) match_lines(*index.h_, b.v_lines, T_ab_guess, options, h_taken, &pairs);  // H_a x V_b
      else match_lines(*index.v_, b.h_lines, T_ab_guess, options, v_taken, &v_pairs);       // V_a x H_b
    });
    pairs.insert(pairs.end(), v_pairs.begin(), v_pairs.end());
  } else {
    match_lines(*index.h_, b.v_lines, T_ab_guess, options, h_taken, &pairs);  // H_a x V_b
    match_lines(*index.v_, b.h_lines, T_ab_guess, options, v_taken, &pairs);  // V_a x H_b
  }

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
  // Inverse normal-cluster size (paper §6.3), scaled so that the weights average to 1 over all pairs. Pairs without a
  // normal form no cluster: each weighs 1 (as a group of their own, a handful of them could carry a third of the
  // weight and decide the motion, e.g. floor-wall seams in a corridor).
  const double clustered = static_cast<double>(n - counts[3]);
  std::array<double, 4> group_weight{1.0, 1.0, 1.0, 1.0};
  for (int g = 0; g < 3; ++g)
    if (counts[g] > 0) group_weight[g] = clustered / (clusters * counts[g]);
  out->lines_a.resize(n);
  out->lines_b.resize(n);
  out->segments_a.resize(n);
  out->segments_b.resize(n);
  out->weights.resize(n);
  out->clusters.resize(n);
  out->lines_b_index.resize(n);
  for (size_t i = 0; i < n; ++i) {
    const LineFeature* lb = pairs[i].b;
    const bool vertical = !b.v_lines.empty() && lb >= b.v_lines.data() && lb < b.v_lines.data() + b.v_lines.size();
    out->lines_b_index[i] = vertical ? static_cast<int>(lb - b.v_lines.data())
                                     : static_cast<int>(b.v_lines.size() + (lb - b.h_lines.data()));
    out->lines_a[i] = pairs[i].a->line;
    out->lines_b[i] = pairs[i].b->line;
    out->segments_a[i] = pairs[i].a->segment;
    out->segments_b[i] = pairs[i].b->segment;
    out->weights[i] = group_weight[group[i]];
    out->clusters[i] = group[i] == 3 ? -1 : group[i];
  }

  const double min_cos_planes = std::cos(deg2rad(options.plane_max_angle_deg));
  for (std::size_t i = 0; i < std::min(a.planes.size(), subset.planes); ++i) {
    const PlaneFeature& pa = a.planes[i];
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
