#include "features/line_fit.hpp"

#include <algorithm>
#include <cmath>
#include <cstddef>
#include <cstring>
#include <limits>
#include <memory>
#include <stdexcept>
#include <string>

#include "common/simd.hpp"
#include "common/worker_pool.hpp"

namespace line_odom {

namespace {

constexpr double kDeg = kPi / 180.0;

// PointMoments with only the 6 distinct entries of the symmetric sum of outer products (the same sums,
// entry by entry, in less memory and work: the prefix sums below hold one per point of a scan line).
struct Moments {
  int count = 0;
  Vec3 sum = Vec3::Zero();
  double xx = 0.0, xy = 0.0, xz = 0.0, yy = 0.0, yz = 0.0, zz = 0.0;

  void add(const Moments& o) {
    count += o.count;
    sum += o.sum;
    xx += o.xx, xy += o.xy, xz += o.xz, yy += o.yy, yz += o.yz, zz += o.zz;
  }
  void remove(const Vec3& p) {
    --count;
    sum -= p;
    xx -= p.x() * p.x(), xy -= p.x() * p.y(), xz -= p.x() * p.z();
    yy -= p.y() * p.y(), yz -= p.y() * p.z(), zz -= p.z() * p.z();
  }
};

// Hot (inlined into every caller); its rare retry refit_from_axis stays out of line.
inline __attribute__((always_inline)) LineLeastSquares fit_upper(int count, const Vec3& sum, double oxx, double oxy,
                                                                 double oxz, double oyy, double oyz, double ozz,
                                                                 const Vec3& seed, int iterations);
LineLeastSquares refit_from_axis(int count, const Vec3& sum, double oxx, double oxy, double oxz, double oyy,
                                 double oyz, double ozz, int axis, int iterations);

inline __attribute__((always_inline)) LineLeastSquares fit_line(const Moments& m, const Vec3& seed) {
  return fit_upper(m.count, m.sum, m.xx, m.xy, m.xz, m.yy, m.yz, m.zz, seed, 3);
}

// fit_upper in two halves, for callers that decide on the direction before its normalization (the square root
// and divisions) and finish the fit only when they keep it: the same operations, so the same fit.
struct LinePrefit {
  Vec3 centroid = Vec3::Zero();
  double xx = 0.0, xy = 0.0, xz = 0.0, yy = 0.0, yz = 0.0, zz = 0.0;  // covariance
  Vec3 u = Vec3::Zero();  // C^3 seed
  double norm2 = 0.0;     // |u|^2
  bool usable() const { return norm2 > 1e-300 && norm2 < 1e300; }  // the normalized path, scale far from overflow
};
inline __attribute__((always_inline)) LinePrefit prefit_line(const Moments& m, const Vec3& seed);
inline __attribute__((always_inline)) LineLeastSquares finish_line(const LinePrefit& p, const Moments& m,
                                                                   const Vec3& seed);

// Points of one scan line in scan order, with their positions along it, their split thresholds and the
// prefix sums of their moments (the moments of any stretch in O(1)).
struct ScanBuffer {
  int cell0 = 0, cell_step = 1;         // range-image cell of position k along the scan line: cell0 + k cell_step
  std::vector<int> pos;
  std::vector<double> x, y, z;        // the points, as structure of arrays
  std::vector<double> tau;
  std::vector<double> inv_tau2;       // 1 / tau^2
  struct PrefixSums {
    double sx, sy, sz, xx, xy, xz, yy, yz, zz;  // (fill_buffer stores the first and second four as vectors)
  };
  static_assert(offsetof(PrefixSums, xy) == 4 * sizeof(double) && offsetof(PrefixSums, zz) == 8 * sizeof(double),
                "PrefixSums is packed: two vectors of four sums and zz");
  std::vector<PrefixSums> prefix;     // prefix[k] = moment sums of points [0, k)

  int count = 0;                      // points in this scan line (the arrays keep their largest size)

  int size() const { return count; }
  Vec3 p(int k) const { return Vec3(x[k], y[k], z[k]); }
  Moments stretch(int a, int b) const {  // points [a, b]
    const PrefixSums& hi = prefix[b + 1];
    const PrefixSums& lo = prefix[a];
    Moments m;
    m.count = b + 1 - a;
    m.sum = Vec3(hi.sx - lo.sx, hi.sy - lo.sy, hi.sz - lo.sz);
    m.xx = hi.xx - lo.xx, m.xy = hi.xy - lo.xy, m.xz = hi.xz - lo.xz;
    m.yy = hi.yy - lo.yy, m.yz = hi.yz - lo.yz, m.zz = hi.zz - lo.zz;
    return m;
  }
};

// A line is a stretch [first, last] of the scan line minus the stray points skipped while merging.
struct CandidateLine {
  int first = 0, last = 0;
  int skipped_begin = 0, skipped_end = 0;  // range in ScanLineFitter::skipped_
  Moments moments;
  LineLeastSquares fit;
  bool accepted = false;
};

// Scalar forms of |v|^2 and |(p - c) x d|^2 with the same operations, in the same order, as Eigen's
// squaredNorm() and cross() on Vec3 (which pack a temporary through memory, a store-forwarding stall).
inline double squared_norm(double x, double y, double z) { return x * x + y * y + z * z; }
inline double squared_norm(const Vec3& v) { return squared_norm(v.x(), v.y(), v.z()); }
inline double cross_squared_norm(double rx, double ry, double rz, const Vec3& d) {
  return squared_norm(ry * d.z() - rz * d.y(), rz * d.x() - rx * d.z(), rx * d.y() - ry * d.x());
}
inline double distance2(const Vec3& p, const Vec3& c, const Vec3& d) {  // |(p - c) x d|^2
  return cross_squared_norm(p.x() - c.x(), p.y() - c.y(), p.z() - c.z(), d);
}

double residual(const LineLeastSquares& f, const Vec3& p) { return std::sqrt(distance2(p, f.centroid, f.direction)); }

// Squared distance to the line over the squared threshold: > 1 means outside.
inline __attribute__((always_inline)) double excess2(const LineLeastSquares& f, const ScanBuffer& buf, int k) {
  return distance2(buf.p(k), f.centroid, f.direction) * buf.inv_tau2[k];
}

void remove_point(Moments* m, const Vec3& p) { m->remove(p); }

// Four lanes of doubles / 64-bit integers (GCC vector extensions: AVX2 registers in the AVX2 clones, SSE2 pairs
// in the baseline; the same IEEE operations lane by lane as the scalar expressions they replace).
// (Always inlined: these helpers never pass vectors across a call, whose ABI would differ between the clones.)
#pragma GCC diagnostic ignored "-Wpsabi"
typedef double F4 __attribute__((vector_size(32)));
typedef std::int64_t I4 __attribute__((vector_size(32)));
constexpr int kLanes = 4;
constexpr int kPad = kLanes;  // elements readable past the end of a scan buffer's arrays (lanes past n are masked)

inline __attribute__((always_inline)) F4 load4(const double* p) {
  F4 v;
  std::memcpy(&v, p, sizeof v);
  return v;
}

inline __attribute__((always_inline)) bool any(const I4& m) { return (m[0] | m[1] | m[2] | m[3]) != 0; }

// rows[i] = (a[i], b[i], c[i], d[i])
inline __attribute__((always_inline)) void transpose4(const F4& a, const F4& b, const F4& c, const F4& d, F4* rows) {
  const F4 ab_even = __builtin_shuffle(a, b, I4{0, 4, 2, 6}), ab_odd = __builtin_shuffle(a, b, I4{1, 5, 3, 7});
  const F4 cd_even = __builtin_shuffle(c, d, I4{0, 4, 2, 6}), cd_odd = __builtin_shuffle(c, d, I4{1, 5, 3, 7});
  rows[0] = __builtin_shuffle(ab_even, cd_even, I4{0, 1, 4, 5});
  rows[1] = __builtin_shuffle(ab_odd, cd_odd, I4{0, 1, 4, 5});
  rows[2] = __builtin_shuffle(ab_even, cd_even, I4{2, 3, 6, 7});
  rows[3] = __builtin_shuffle(ab_odd, cd_odd, I4{2, 3, 6, 7});
}

// Index (1..n) of the largest ratio above 1 of the squared distances of points 1..n of X/Y/Z to the chord from
// point 0 to point n+1 over their squared thresholds (times W), -1 if none; ties: the first. The ratios are >= +0
// (squares times positive factors; a NaN from absurd scales counts by its bits), so they order as their bit
// patterns do: each lane keeps its largest bits and their first index. Reads up to kPad - 1 elements past
// X0[n+1] / W[n-1] (masked out).
inline __attribute__((always_inline)) int farthest_from_chord(const double* __restrict X0,
                                                              const double* __restrict Y0,
                                                              const double* __restrict Z0,
                                                              const double* __restrict W, int n) {
  const double ax = X0[0], ay = Y0[0], az = Z0[0];
  const double cx = X0[n + 1] - ax, cy = Y0[n + 1] - ay, cz = Z0[n + 1] - az;
  const double len2 = cx * cx + cy * cy + cz * cz;
  const double* __restrict X = X0 + 1;
  const double* __restrict Y = Y0 + 1;
  const double* __restrict Z = Z0 + 1;
  std::int64_t top = 0;
  int at = 0;
  if (!(len2 > 1e-24)) {  // degenerate chord: distances to its first point
    for (int i = 0; i < n; ++i) {
      const double rx = X[i] - ax, ry = Y[i] - ay, rz = Z[i] - az;
      const double r = (rx * rx + ry * ry + rz * rz) * W[i];
      std::int64_t b;
      std::memcpy(&b, &r, sizeof b);
      if (b > top) top = b, at = i;
    }
  } else {
    const double inv_len2 = 1.0 / len2;
    I4 best = {0, 0, 0, 0}, best_at = {0, 0, 0, 0}, index = {0, 1, 2, 3};
    const I4 count = {n, n, n, n};
    // whole groups of four, then the last partial group with its lanes past n masked to 0
    auto step = [&](int i, bool partial) __attribute__((always_inline)) {
      const F4 rx = load4(X + i) - ax, ry = load4(Y + i) - ay, rz = load4(Z + i) - az;
      const F4 ux = ry * cz - rz * cy, uy = rz * cx - rx * cz, uz = rx * cy - ry * cx;
      const F4 r = (ux * ux + uy * uy + uz * uz) * (inv_len2 * load4(W + i));
      I4 bits;
      std::memcpy(&bits, &r, sizeof bits);
      if (partial) bits &= index < count;
      const I4 more = bits > best;
      best = more ? bits : best;
      best_at = more ? index : best_at;
      index += kLanes;
    };
    const int whole = n - n % kLanes;
    for (int i = 0; i < whole; i += kLanes) step(i, false);
    if (whole < n) step(whole, true);
    std::int64_t one;
    const double one_value = 1.0;
    std::memcpy(&one, &one_value, sizeof one);
    if (!any(best > one)) return -1;  // no ratio above 1: no split (most calls)
    // across the lanes, without branches: the largest bits, at the smallest index among the lanes holding them
    for (const int stride : {2, 1}) {  // lanes exchanged with the lane `stride` away: (2 3 0 1), then (1 0 3 2)
      const I4 other = {best[stride], best[1 ^ stride], best[2 ^ stride], best[3 ^ stride]};
      const I4 other_at = {best_at[stride], best_at[1 ^ stride], best_at[2 ^ stride], best_at[3 ^ stride]};
      const I4 take = (other > best) | ((other == best) & (other_at < best_at));
      best = take ? other : best;
      best_at = take ? other_at : best_at;
    }
    top = best[0];
    at = static_cast<int>(best_at[0]);
  }
  double worst;
  std::memcpy(&worst, &top, sizeof worst);
  return worst > 1.0 ? 1 + at : -1;
}

constexpr double kMargin = 1e-9;  // relative margin of the squared decision tests (see breaks_between)

// The clear cases of try_merge's test of points k..k+len-1 (len <= 4) against the prefit line (centroid c,
// unnormalized direction u): e = |(p - c) x u|^2 / tau^2 against |u|^2 (1 +- kMargin), the same IEEE operations as
// distance2 and excess2 lane by lane. 1: a point is clearly outside; 2: a point is close to the margin (the caller
// decides exactly); 0: all clearly inside.
inline __attribute__((always_inline)) int prefit_verdict(const ScanBuffer& buf, int k, int len, const LinePrefit& pre) {
  const double cx = pre.centroid.x(), cy = pre.centroid.y(), cz = pre.centroid.z();
  const double ux = pre.u.x(), uy = pre.u.y(), uz = pre.u.z();
  const F4 rx = load4(buf.x.data() + k) - cx, ry = load4(buf.y.data() + k) - cy, rz = load4(buf.z.data() + k) - cz;
  const F4 vx = ry * uz - rz * uy, vy = rz * ux - rx * uz, vz = rx * uy - ry * ux;
  const F4 e = (vx * vx + vy * vy + vz * vz) * load4(buf.inv_tau2.data() + k);
  const I4 lane = {0, 1, 2, 3};
  const I4 valid = lane < len;
  const I4 out = e > pre.norm2 * (1.0 + kMargin);
  const I4 in = e < pre.norm2 * (1.0 - kMargin);
  if (any(out & valid)) return 1;
  return any(~(out | in) & valid) ? 2 : 0;
}

// The clear cases of ScanLineFitter::breaks_between for every pair of neighbouring points (j - 1, j), j = 1..n-1,
// in one vectorizable pass (the same IEEE operations): code[j] 1 = break, 0 = none, 2 = close to a margin (the
// caller decides it exactly).
void break_codes(const double* __restrict X, const double* __restrict Y, const double* __restrict Z,
                 const double* __restrict T, const int* __restrict P, int n, int max_gap, double sin2,
                 std::int32_t* __restrict code) {
  for (int j = 1; j < n; ++j) {
    const double sx = X[j] - X[j - 1], sy = Y[j] - Y[j - 1], sz = Z[j] - Z[j - 1];
    const double len2 = sx * sx + sy * sy + sz * sz;
    const double tau = T[j - 1] < T[j] ? T[j] : T[j - 1];
    const double tau2 = tau * tau;
    const double wx = X[j - 1] + X[j], wy = Y[j - 1] + Y[j], wz = Z[j - 1] + Z[j];
    const double cx = sy * wz - sz * wy, cy = sz * wx - sx * wz, cz = sx * wy - sy * wx;
    const double lhs = cx * cx + cy * cy + cz * cz;
    const double rhs = sin2 * len2 * (wx * wx + wy * wy + wz * wz);
    // gap ? 1 : quiet ? 0 : near_tau ? 2 : jump ? 1 : smooth ? 0 : 2, without branches
    const int gap = P[j] - P[j - 1] - 1 > max_gap;
    const int quiet = len2 < tau2 * (1.0 - kMargin);
    const int near_tau = len2 <= tau2 * (1.0 + kMargin);
    const int jump = lhs < rhs * (1.0 - kMargin);
    const int smooth = lhs > rhs * (1.0 + kMargin);
    const int far = jump | ((1 - jump) & (1 - smooth)) << 1;
    const int loud = near_tau << 1 | (1 - near_tau) * far;
    code[j] = gap | (1 - gap) * (1 - quiet) * loud;
  }
}

// sqrt(n / (n - 2)), the factor of the unbiased rms of a line fitted to n points, from a table for small n (the same
// expression, evaluated once at load time): no division and square root on the path of every line's end test.
struct UnbiasedFactors {
  static constexpr int kSize = 256;
  double value[kSize];
  UnbiasedFactors() : value() {
    for (int n = 3; n < kSize; ++n) value[n] = std::sqrt(n / (n - 2.0));
  }
};
const UnbiasedFactors kUnbiased;

inline double unbiased_factor(int n) {
  return n >= 3 && n < UnbiasedFactors::kSize ? kUnbiased.value[n] : std::sqrt(n / (n - 2.0));
}

class ScanLineFitter {
  static constexpr int kEndChecks = 4;

 public:
  // (re)configures the fitter; its work buffers keep their largest size
  void configure(const LineFitConfig& cfg) {
    cfg_ = cfg;
    sin_min_incidence_ = std::sin(cfg.min_incidence_deg * kDeg);
    sin2_min_incidence_ = sin_min_incidence_ * sin_min_incidence_;
    const double floor_per_tau = 0.5 * cfg.max_rms / cfg.split_distance;
    floor_bound_ = floor_per_tau * floor_per_tau * (1.0 - kMargin);
    trim2_ = cfg.trim_sigmas * cfg.trim_sigmas;
  }

  // Fits the lines of the buffered scan line and appends them to `out`, labelling their cells.
  void fit(const ScanBuffer& buf, int min_points, int scan_index, std::vector<LineFeature>* out,
           std::vector<std::int32_t>* labels) {
    candidates_.clear();
    skipped_.clear();
    const int n = buf.size();
    count_ = n;
    if (static_cast<int>(is_skipped_.size()) < n) is_skipped_.resize(n);
    std::fill(is_skipped_.begin(), is_skipped_.begin() + n, 0);
    if (static_cast<int>(break_code_.size()) < n) break_code_.resize(n);
    break_codes(buf.x.data(), buf.y.data(), buf.z.data(), buf.tau.data(), buf.pos.data(), n, cfg_.max_gap,
                sin2_min_incidence_, break_code_.data());
    // Runs end at the breaks; most codes are 0, skipped eight at a time.
    const std::int32_t* code = break_code_.data();
    int run_start = 0;
    for (int j = 1; j < n; ++j) {
      if (j + 8 <= n) {
        I4 word;
        std::memcpy(&word, code + j, sizeof word);
        if ((word[0] | word[1] | word[2] | word[3]) == 0) {
          j += 7;
          continue;
        }
      }
      if (code[j] == 0) continue;
      if (code[j] == 1 || breaks_between(buf, j - 1, j)) {
        fit_run(buf, run_start, j - 1, min_points);
        run_start = j;
      }
    }
    if (n > 0) fit_run(buf, run_start, n - 1, min_points);
    for (auto& c : candidates_) c.accepted = acceptable(buf, c, min_points);
    resolve_shared_points(buf, min_points);
    for (const auto& c : candidates_) {
      if (!c.accepted) continue;
      emit(buf, c, scan_index, out, labels);
    }
  }

 private:
  // A hole longer than max_gap, or a step longer than the noise that runs along the viewing ray.
  // The tests are decided on squared quantities without sqrt/division when they are clear by a relative
  // margin of 1e-9 (far beyond the few-ulp rounding of either form); the rare close cases take the exact
  // original expressions, so the decisions are the same bit for bit.
  bool breaks_between(const ScanBuffer& buf, int i, int j) const {
    if (buf.pos[j] - buf.pos[i] - 1 > cfg_.max_gap) return true;
    const Vec3 step = buf.p(j) - buf.p(i);
    const double len2 = step.squaredNorm();
    const double tau = std::max(buf.tau[i], buf.tau[j]);
    const double tau2 = tau * tau;
    if (len2 < tau2 * (1.0 - kMargin)) return false;  // within noise: never a jump
    if (len2 <= tau2 * (1.0 + kMargin) && std::sqrt(len2) <= tau) return false;
    const Vec3 w = buf.p(i) + buf.p(j);
    // |step x ray| < sin * len  <=>  |step x w|^2 < sin^2 len^2 |w|^2
    const double lhs = step.cross(w).squaredNorm();
    const double rhs = sin2_min_incidence_ * len2 * w.squaredNorm();
    if (lhs < rhs * (1.0 - kMargin)) return true;
    if (lhs > rhs * (1.0 + kMargin)) return false;
    const double len = std::sqrt(len2);
    const Vec3 ray = w.normalized();
    return step.cross(ray).norm() < sin_min_incidence_ * len;
  }

  // Douglas-Peucker split of run [s, e] into pieces sharing their end points, then greedy merging.
  void fit_run(const ScanBuffer& buf, int s, int e, int min_points) {
    if (e - s + 1 < std::max(2, min_points)) return;
    pieces_.clear();
    stack_.clear();
    stack_.emplace_back(s, e);
    while (!stack_.empty()) {
      const auto [a, b] = stack_.back();
      stack_.pop_back();
      int split = -1;
      if (b - a >= 2) {
        split = farthest_beyond_threshold(buf, a, b);
      }
      if (split < 0) {
        pieces_.emplace_back(a, b);
      } else {
        stack_.emplace_back(split, b);
        stack_.emplace_back(a, split);
      }
    }

    const int np = static_cast<int>(pieces_.size());
    int i = 0;
    CandidateLine cur;
    start_line(buf, &cur, pieces_[0].first, pieces_[0].second);
    while (true) {
      bool merged = false;
      for (int j = i + 1; j < np; ++j) {
        const int first_new = std::max(pieces_[j].first, cur.last + 1);
        if (first_new - cur.last - 1 > cfg_.max_outliers) break;
        if (merge_must_fail(buf, cur, pieces_[j].second)) continue;
        if (try_merge(buf, &cur, first_new, pieces_[j].second)) {
          i = j;
          merged = true;
          break;
        }
      }
      if (merged) continue;
      // A line with too few points, or too short, is certain to be rejected by acceptable(): it is neither fitted
      // nor kept (only accepted lines are resolved and emitted).
      if (cur.moments.count >= min_points && !certainly_short(buf, cur.first, cur.last)) {
        if (!fitted_)
          cur.fit = fit_line(cur.moments, chord_direction(buf, cur.first, cur.last));
        else
          settle_fit(&cur);
        candidates_.push_back(cur);
      }
      if (++i >= np) break;
      start_line(buf, &cur, pieces_[i].first, pieces_[i].second);
    }
  }

  // True when try_merge(line, ., b) is certain to return false, decided without the refit: try_merge checks the
  // line's first and last points and b against the refit, and no line keeps three points within T = their
  // largest threshold when their triangle is wider than 2 T (its smallest altitude; a strip of half-width T
  // around any line, projected into the triangle's plane, would hold it). Margin 1e-6: far beyond the rounding.
  bool merge_must_fail(const ScanBuffer& buf, const CandidateLine& line, int b) const {
    const Vec3 p0 = buf.p(line.first);
    const Vec3 p1 = buf.p(line.last);
    const Vec3 p2 = buf.p(b);
    const Vec3 v = p2 - p0;
    const double area2 = distance2(p1, p0, v);  // |(p1 - p0) x (p2 - p0)|^2 = (2 area)^2
    const double side01 = squared_norm(p1.x() - p0.x(), p1.y() - p0.y(), p1.z() - p0.z());
    const double side12 = squared_norm(p2.x() - p1.x(), p2.y() - p1.y(), p2.z() - p1.z());
    const double side2 = std::max(squared_norm(v), std::max(side01, side12));
    const double t = std::max(buf.tau[line.first], std::max(buf.tau[line.last], buf.tau[b]));
    return area2 > 4.0 * (t * t) * side2 * (1.0 + 1e-6);
  }

  // True when every line acceptable() can make of stretch [a, b] is shorter than min_length: its length is the
  // distance of two of these points along a unit direction, at most the diagonal of their bounding box (up to a
  // few ulps; margin 1e-6). Most lines are decided by the distance of their end points, a lower bound of it.
  bool certainly_short(const ScanBuffer& buf, int a, int b) const {
    const double limit2 = cfg_.min_length * cfg_.min_length * (1.0 - 1e-6);
    const double ex = buf.x[b] - buf.x[a], ey = buf.y[b] - buf.y[a], ez = buf.z[b] - buf.z[a];
    if (!(squared_norm(ex, ey, ez) < limit2)) return false;
    const double x0 = buf.x[a], y0 = buf.y[a], z0 = buf.z[a];
    F4 lo_x = {x0, x0, x0, x0}, lo_y = {y0, y0, y0, y0}, lo_z = {z0, z0, z0, z0};
    F4 hi_x = lo_x, hi_y = lo_y, hi_z = lo_z;
    const I4 lane = {0, 1, 2, 3};
    for (int k = a; k <= b; k += kLanes) {
      const I4 in = lane < b + 1 - k;  // lanes past b take the current minima, which move neither bound
      const F4 x = in ? load4(buf.x.data() + k) : lo_x, y = in ? load4(buf.y.data() + k) : lo_y;
      const F4 z = in ? load4(buf.z.data() + k) : lo_z;
      lo_x = x < lo_x ? x : lo_x, lo_y = y < lo_y ? y : lo_y, lo_z = z < lo_z ? z : lo_z;
      hi_x = x > hi_x ? x : hi_x, hi_y = y > hi_y ? y : hi_y, hi_z = z > hi_z ? z : hi_z;
    }
    double span2 = 0.0;
    for (const auto& [lo, hi] : {std::pair<F4, F4>{lo_x, hi_x}, {lo_y, hi_y}, {lo_z, hi_z}}) {
      const double extent = std::max(std::max(hi[0], hi[1]), std::max(hi[2], hi[3])) -
                            std::min(std::min(lo[0], lo[1]), std::min(lo[2], lo[3]));
      span2 += extent * extent;
    }
    return span2 < limit2;
  }

  // The fit of a new line is only needed once it is long enough for the cheap rejection in try_merge.
  void start_line(const ScanBuffer& buf, CandidateLine* line, int a, int b) {
    line->first = a;
    line->last = b;
    line->skipped_begin = line->skipped_end = static_cast<int>(skipped_.size());
    line->moments = buf.stretch(a, b);
    line->accepted = false;
    fitted_ = false;
    pending_ = false;
  }

  // Finishes the fit of the last successful merge when it was left pending (see try_merge).
  void settle_fit(CandidateLine* line) {
    if (!pending_) return;
    line->fit = finish_line(pending_pre_, line->moments, pending_seed_);
    pending_ = false;
  }

  // Index in (a, b) of the point farthest from the chord a-b relative to its threshold, -1 if all are within.
  int farthest_beyond_threshold(const ScanBuffer& buf, int a, int b) {
    const int k = farthest_from_chord(buf.x.data() + a, buf.y.data() + a, buf.z.data() + a,
                                      buf.inv_tau2.data() + a + 1, b - a - 1);
    return k < 0 ? -1 : a + k;
  }

  Vec3 chord_direction(const ScanBuffer& buf, int a, int b) const {
    const Vec3 d = buf.p(b) - buf.p(a);
    const double n = std::sqrt(squared_norm(d));
    if (!(n > 1e-12)) return Vec3::UnitX();
    const F4 unit = F4{d.x(), d.y(), d.z(), n} / n;  // the three quotients in one vector division
    return Vec3(unit[0], unit[1], unit[2]);
  }

  // Adds points [a, b] (skipping the stray points between the line and a) when the least-squares line of the
  // union keeps every point within its threshold. The refit moves the line by an amount affine along it, so
  // among the old inliers (all within the threshold of the old line) only those near the two ends are checked.
  bool try_merge(const ScanBuffer& buf, CandidateLine* line, int a, int b) {
    const int count = line->moments.count;
    // Cheap rejection against the current line when it is long enough to extrapolate.
    if (count >= 2 * (b - a + 1) && count >= 8) {
      if (!fitted_) {
        line->fit = fit_line(line->moments, chord_direction(buf, line->first, line->last));
        fitted_ = true;
      } else {
        settle_fit(line);
      }
      for (int k = a; k <= b; ++k)
        if (excess2(line->fit, buf, k) > 4.0) return false;
    }
    Moments m = line->moments;
    m.add(buf.stretch(a, b));
    // The checks are decided on the direction before its normalization when clear by kMargin (far beyond the
    // rounding of either form; the close cases finish the fit and take excess2 itself): the same decisions, and a
    // rejected merge never pays for the square roots and divisions.
    const Vec3 seed = chord_direction(buf, line->first, b);
    const LinePrefit pre = prefit_line(m, seed);
    LineLeastSquares f;
    bool finished = false;
    // The clear cases four points at a time (a line without skipped points: its end checks are its first and last
    // four points); a point close to the margin takes the exact test below, point by point.
    bool decided = false;
    if (pre.usable() && line->skipped_begin == line->skipped_end) {
      int verdict = 0;
      for (int k = a; k <= b && verdict == 0; k += kLanes) verdict = prefit_verdict(buf, k, b + 1 - k, pre);
      const int span = line->last + 1 - line->first;
      if (verdict == 0) verdict = prefit_verdict(buf, line->first, span, pre);
      if (verdict == 0 && span > kLanes) verdict = prefit_verdict(buf, line->last + 1 - kLanes, kLanes, pre);
      if (verdict == 1) return false;
      decided = verdict == 0;
    }
    auto outside = [&](int k) {
      if (pre.usable()) {
        const double e = distance2(buf.p(k), pre.centroid, pre.u) * buf.inv_tau2[k];
        if (e > pre.norm2 * (1.0 + kMargin)) return true;
        if (e < pre.norm2 * (1.0 - kMargin)) return false;
      }
      if (!finished) {
        f = finish_line(pre, m, seed);
        finished = true;
      }
      return excess2(f, buf, k) > 1.0;
    };
    if (!decided) {
      for (int k = a; k <= b; ++k)
        if (outside(k)) return false;
      int checked = 0;
      for (int k = line->first; k <= line->last && checked < kEndChecks; ++k)
        if (!is_skipped_[k]) {
          if (outside(k)) return false;
          ++checked;
        }
      checked = 0;
      for (int k = line->last; k >= line->first && checked < kEndChecks; --k)
        if (!is_skipped_[k]) {
          if (outside(k)) return false;
          ++checked;
        }
    }
    for (int k = line->last + 1; k < a; ++k) {
      skipped_.push_back(k);
      is_skipped_[k] = 1;
    }
    line->skipped_end = static_cast<int>(skipped_.size());
    line->last = b;
    line->moments = m;
    // The fit is finished when first read (the next merge's cheap rejection or the end of the line): a line merged
    // again before that never pays for it.
    if (finished) {
      line->fit = f;
      pending_ = false;
    } else {
      pending_pre_ = pre;
      pending_seed_ = seed;
      pending_ = true;
    }
    fitted_ = true;
    return true;
  }

  // Moments of the current stretch minus its skipped points, and the refit from them.
  void refit(const ScanBuffer& buf, CandidateLine* c) const {
    Moments m = buf.stretch(c->first, c->last);
    for (int i = c->skipped_begin; i < c->skipped_end; ++i) {
      const int k = skipped_[i];
      if (k >= c->first && k <= c->last) remove_point(&m, buf.p(k));
    }
    c->moments = m;
    c->fit = fit_line(m, c->fit.direction);
  }

  int next_inlier(int k, int step) const {
    k += step;
    while (k >= 0 && k < count_ && is_skipped_[k]) k += step;
    return k;
  }

  // True when the short-line test in acceptable() (the point is off when beyond the split threshold of the line f
  // through the other n points, or beyond both trim_sigmas x its unbiased rms and the floor) is certain to keep
  // point k, decided on the direction before its normalization: with u = C^3 seed, |u|^2 r^2 = |(p - c) x u|^2 and
  // |u|^2 rms^2 = trace |u|^2 - u.C u. Margins: 1e-9 relative (the rounding of either form is a few ulps) and
  // 1e-10 trace |u|^2 absolute on the rms (its cancellation); the floor is floor_per_tau_ x the split threshold up
  // to a few ulps. Undecided cases take the finished fit, so the decisions are the same.
  bool clearly_kept(const ScanBuffer& buf, int k, const LinePrefit& pre, int n) const {
    const double d2 = distance2(buf.p(k), pre.centroid, pre.u);
    const double e = d2 * buf.inv_tau2[k];
    if (!(e < pre.norm2 * (1.0 - kMargin))) return false;        // maybe beyond the split threshold
    if (e < pre.norm2 * floor_bound_) return true;                // within the floor
    const double ux = pre.u.x(), uy = pre.u.y(), uz = pre.u.z();
    const double cx = pre.xx * ux + pre.xy * uy + pre.xz * uz;
    const double cy = pre.xy * ux + pre.yy * uy + pre.yz * uz;
    const double cz = pre.xz * ux + pre.yz * uy + pre.zz * uz;
    const double trace = pre.xx + pre.yy + pre.zz;
    const double spread = trace * pre.norm2 * (1.0 - 1e-10) - (ux * cx + uy * cy + uz * cz);  // <= |u|^2 rms^2
    return spread > 0.0 && d2 * (n - 2.0) < trim2_ * n * spread * (1.0 - kMargin);
  }

  // Trims end points beyond the threshold, then applies the support / rms / length tests.
  bool acceptable(const ScanBuffer& buf, CandidateLine& c, int min_points) const {
    if (c.moments.count < min_points) return false;
    // Ends: points of the neighbouring surface near a corner stay within the split threshold but pull the fit
    // towards them. The middle half of the line is clean, so its least-squares line and rms judge the ends:
    // end points farther than trim_sigmas x that rms (floor: half of max_rms) or than the split threshold are
    // trimmed, then the line is refitted. Lines under 12 points judge each end by the line through the others.
    for (int round = 0; round < 2; ++round) {
      LineLeastSquares judge = c.fit;
      double limit_rms = std::numeric_limits<double>::infinity();  // short lines: the split threshold only
      if (c.moments.count >= 12) {
        const int a = c.first + (c.last - c.first) / 4, b = c.last - (c.last - c.first) / 4;
        Moments core = buf.stretch(a, b);
        for (int i = c.skipped_begin; i < c.skipped_end; ++i)
          if (skipped_[i] >= a && skipped_[i] <= b) remove_point(&core, buf.p(skipped_[i]));
        judge = fit_line(core, c.fit.direction);
        // a fit to n points absorbs 4 of their 2n residual components: unbiased rms
        limit_rms = judge.rms * unbiased_factor(core.count);
      }
      const bool short_line = c.moments.count < 12;
      // residual > max(limit, floor), the floor (a sqrt) computed only when the residual exceeds the limit
      // (the square root of the squared distance d2 taken only when the point is not clearly within the limit: the
      // squares decide by kMargin, far beyond the rounding of either form)
      auto beyond = [&](double d2, double limit, int k) {
        if (d2 < limit * limit * (1.0 - kMargin)) return false;
        const double r = std::sqrt(d2);
        return r > limit && r > 0.5 * cfg_.max_rms * cfg_.threshold_scale(std::sqrt(squared_norm(buf.p(k))));
      };
      auto off = [&](int k) {
        if (short_line && c.moments.count >= 5) {  // judged by the line through the other points
          Moments rest = c.moments;
          remove_point(&rest, buf.p(k));
          const LinePrefit pre = prefit_line(rest, c.fit.direction);
          if (pre.usable() && clearly_kept(buf, k, pre, rest.count)) return false;
          const LineLeastSquares f = finish_line(pre, rest, c.fit.direction);
          const double rms = f.rms * unbiased_factor(rest.count);
          return excess2(f, buf, k) > 1.0 || beyond(distance2(buf.p(k), f.centroid, f.direction), cfg_.trim_sigmas * rms, k);
        }
        if (excess2(judge, buf, k) > 1.0) return true;
        return beyond(distance2(buf.p(k), judge.centroid, judge.direction), cfg_.trim_sigmas * limit_rms, k);
      };
      int lo = c.first, hi = c.last;
      while (hi > lo && off(lo)) lo = next_inlier(lo, 1);
      while (hi > lo && off(hi)) hi = next_inlier(hi, -1);
      if (lo == c.first && hi == c.last) break;
      if (hi <= lo) return false;
      c.first = lo;
      c.last = hi;
      refit(buf, &c);
      if (c.moments.count < min_points) return false;
    }
    const double range = c.fit.centroid.norm();
    if (!(c.fit.rms <= cfg_.max_rms * cfg_.threshold_scale(range))) return false;
    const Vec3& d = c.fit.direction;
    const double t0 = (buf.p(c.first) - c.fit.centroid).dot(d);
    const double t1 = (buf.p(c.last) - c.fit.centroid).dot(d);
    return std::abs(t1 - t0) >= cfg_.min_length;
  }

  // A corner point kept by two neighbouring lines goes to the one it fits better.
  void resolve_shared_points(const ScanBuffer& buf, int min_points) {
    int prev = -1;
    for (int i = 0; i < static_cast<int>(candidates_.size()); ++i) {
      if (!candidates_[i].accepted) continue;
      if (prev >= 0) {
        CandidateLine& a = candidates_[prev];
        CandidateLine& b = candidates_[i];
        if (a.last == b.first) {
          const int k = b.first;
          const double ra = residual(a.fit, buf.p(k)), rb = residual(b.fit, buf.p(k));
          CandidateLine& loser = ra <= rb ? b : a;
          if (&loser == &b) {
            b.first = next_inlier(b.first, 1);
          } else {
            a.last = next_inlier(a.last, -1);
          }
          if (loser.first < loser.last) {
            refit(buf, &loser);
            loser.accepted = acceptable(buf, loser, min_points);
          } else {
            loser.accepted = false;
          }
        }
      }
      if (candidates_[i].accepted) prev = i;
    }
  }

  void emit(const ScanBuffer& buf, const CandidateLine& c, int scan_index, std::vector<LineFeature>* out,
            std::vector<std::int32_t>* labels) const {
    const Vec3& d = c.fit.direction;
    const Vec3& o = c.fit.centroid;
    const Vec3 p0 = buf.p(c.first);
    const Vec3 p1 = buf.p(c.last);
    // Direction from the first to the last inlier along the scan line.
    const Vec3 dir = (p1 - p0).dot(d) >= 0.0 ? d : Vec3(-d);
    LineFeature f;
    f.segment.a = o + dir * (p0 - o).dot(dir);
    f.segment.b = o + dir * (p1 - o).dot(dir);
    f.line.d = dir;
    f.line.m = o.cross(dir);
    f.rms = c.fit.rms;
    f.support = c.moments.count;
    f.scan_index = scan_index;
    f.first = buf.pos[c.first];
    f.last = buf.pos[c.last];
    const auto id = static_cast<std::int32_t>(out->size());
    // (everything the loop reads held in locals: the byte flags may alias anything, so the stores would otherwise
    // reload the vectors' data pointers on every point)
    std::int32_t* __restrict cells = labels->data() + buf.cell0;
    const int* __restrict pos = buf.pos.data();
    const std::uint8_t* __restrict skipped = is_skipped_.data();
    const std::ptrdiff_t step = buf.cell_step;
    for (int k = c.first; k <= c.last; ++k)
      if (!skipped[k]) cells[pos[k] * step] = id;
    out->push_back(f);
  }

  LineFitConfig cfg_;
  double sin_min_incidence_ = 0.0;
  double sin2_min_incidence_ = 0.0;
  double floor_bound_ = 0.0;  // (floor / split threshold)^2, less the margin
  double trim2_ = 0.0;        // trim_sigmas^2
  std::vector<std::pair<int, int>> stack_, pieces_;
  std::vector<CandidateLine> candidates_;
  std::vector<int> skipped_;
  std::vector<std::uint8_t> is_skipped_;
  std::vector<std::int32_t> break_code_;
  bool fitted_ = false;   // the current line's fit is known (finished, or pending below)
  bool pending_ = false;  // its fit is the unfinished pending_pre_ from seed pending_seed_
  LinePrefit pending_pre_;
  Vec3 pending_seed_ = Vec3::UnitX();
  int count_ = 0;  // points of the current scan line
};

// Per-cell split thresholds, computed once for both passes (holes: 1).
struct CellThresholds {
  std::vector<double> tau;    // per cell: tau, 1 / tau^2 interleaved (one memory stream for the column pass)
};

// A branch-free loop over the cells (vectorized; the same IEEE operations as Vec3::norm and threshold_scale).
LINE_ODOM_VECTOR_CLONES void cell_thresholds(const RangeImage& img, const LineFitConfig& cfg, CellThresholds& t) {
  static_assert(sizeof(Vec3) == 3 * sizeof(double), "Vec3 arrays are read as packed x, y, z");
  const size_t n = img.points.size();
  if (t.tau.size() < 2 * n) t.tau.resize(2 * n);
  const double* __restrict xyz = img.points.empty() ? nullptr : img.points[0].data();
  const std::uint8_t* __restrict valid = img.valid.data();
  double* __restrict pair_out = t.tau.data();
  const double split = cfg.split_distance, a = cfg.threshold_per_m, b = cfg.threshold_per_m2;
  // one pass (-fno-math-errno, setup.py, lets the square root vectorize)
  for (size_t i = 0; i < n; ++i) {
    const double x = xyz[3 * i], y = xyz[3 * i + 1], z = xyz[3 * i + 2];
    const double r = std::sqrt(x * x + y * y + z * z);
    const double scaled = split * (1.0 + a * r + b * r * r);
    // valid ? scaled : 1, as a bit select (a branch would keep the loop from vectorizing)
    const std::uint64_t keep = 0 - static_cast<std::uint64_t>(valid[i] != 0);
    std::uint64_t bits_scaled, bits_one;
    const double one = 1.0;
    std::memcpy(&bits_scaled, &scaled, sizeof scaled);
    std::memcpy(&bits_one, &one, sizeof one);
    const std::uint64_t bits = (bits_scaled & keep) | (bits_one & ~keep);
    double tau;
    std::memcpy(&tau, &bits, sizeof tau);
    pair_out[2 * i] = tau;
    pair_out[2 * i + 1] = 1.0 / (tau * tau);
  }
}

// Its own clones, called once per scan line: inlined into fit_pass it shares the registers of the whole fitter.
__attribute__((noinline)) LINE_ODOM_VECTOR_CLONES void fill_buffer(const RangeImage& img, const CellThresholds& th,
                                                                  bool horizontal, int index, ScanBuffer* buf) {
  const int n = horizontal ? img.cols : img.rows;
  if (static_cast<int>(buf->pos.size()) < n) {  // grow once; sizes stay at the maximum, `count` is the length
    buf->pos.resize(n);
    buf->x.resize(n + kPad);
    buf->y.resize(n + kPad);
    buf->z.resize(n + kPad);
    buf->tau.resize(n);
    buf->inv_tau2.resize(n + kPad);
    buf->prefix.resize(n + 1);
  }
  const int cell0 = horizontal ? index * img.cols : index;
  const int step = horizontal ? 1 : img.cols;
  buf->cell0 = cell0;
  buf->cell_step = step;
  // The valid points, compacted; then their prefix sums (two loops: one holding every output stream would keep more
  // pointers live than there are registers).
  const std::uint8_t* __restrict valid = img.valid.data();
  const double* __restrict points = img.points.empty() ? nullptr : img.points[0].data();
  const double* __restrict cell_tau = th.tau.data();
  int* __restrict out_pos = buf->pos.data();
  double* __restrict out_x = buf->x.data();
  double* __restrict out_y = buf->y.data();
  double* __restrict out_z = buf->z.data();
  double* __restrict out_tau = buf->tau.data();
  double* __restrict out_inv_tau2 = buf->inv_tau2.data();
  // (pointers stepped along the scan line, by a constant along rows: no index arithmetic in the loops)
  const std::uint8_t* __restrict v = valid + cell0;
  const double* __restrict q = points + 3 * static_cast<std::ptrdiff_t>(cell0);
  const double* __restrict t = cell_tau + 2 * static_cast<std::ptrdiff_t>(cell0);
  int m = 0;
  auto copy = [&](int k) __attribute__((always_inline)) {
    out_pos[m] = k;
    out_x[m] = q[0];
    out_y[m] = q[1];
    out_z[m] = q[2];
    out_tau[m] = t[0];
    out_inv_tau2[m] = t[1];
    ++m;
  };
  if (horizontal) {
    for (int k = 0; k < n; ++k, ++v, q += 3, t += 2)
      if (*v) copy(k);
  } else {
    // A column's cells are `cols` cells apart, a stride the hardware prefetchers do not follow: the points and
    // thresholds kPrefetchCells cells to the right are requested into L2 while this column is read.
    constexpr int kPrefetchCells = 16;
    const std::ptrdiff_t stride = step;
    for (int k = 0; k < n; ++k, v += stride, q += 3 * stride, t += 2 * stride) {
      __builtin_prefetch(q + 3 * kPrefetchCells, 0, 2);
      __builtin_prefetch(t + 2 * kPrefetchCells, 0, 2);
      if (*v) copy(k);
    }
  }
  buf->count = m;
  // Running sums in registers (the same additions, in the same order, as prev + p p^T). Four points at a time: their
  // products as vectors, transposed into one (x, y, z, xx) and one (xy, xz, yy, yz) vector per point.
  ScanBuffer::PrefixSums* __restrict next = buf->prefix.data();
  *next++ = {0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0};
  F4 low = {0.0, 0.0, 0.0, 0.0}, high = {0.0, 0.0, 0.0, 0.0};  // (sx, sy, sz, xx), (xy, xz, yy, yz): PrefixSums order
  double zz = 0.0;
  auto add = [&](const F4& point_low, const F4& point_high, double point_zz) __attribute__((always_inline)) {
    low += point_low;
    high += point_high;
    zz += point_zz;
    std::memcpy(&next->sx, &low, sizeof low);
    std::memcpy(&next->xy, &high, sizeof high);
    next->zz = zz;
    ++next;
  };
  int k = 0;
  for (; k + kLanes <= m; k += kLanes) {
    const F4 x = load4(out_x + k), y = load4(out_y + k), z = load4(out_z + k);
    F4 lows[kLanes], highs[kLanes];
    transpose4(x, y, z, x * x, lows);
    transpose4(x * y, x * z, y * y, y * z, highs);
    const F4 zzs = z * z;
    for (int i = 0; i < kLanes; ++i) add(lows[i], highs[i], zzs[i]);
  }
  for (; k < m; ++k) {
    const double x = out_x[k], y = out_y[k], z = out_z[k];
    add(F4{x, y, z, x * x}, F4{x, x, y, y} * F4{y, z, y, z}, z * z);
  }
}

// The lines of rows (horizontal) or columns [begin, end); all it calls but fill_buffer is inlined into its two clones.
LINE_ODOM_VECTOR_CLONES_FLATTEN void fit_pass(
    const RangeImage& image, const CellThresholds& thresholds, bool horizontal, int min_points,
    ScanLineFitter& fitter, ScanBuffer& buf, std::vector<LineFeature>* out, std::vector<std::int32_t>* labels,
    int scan_step, int begin, int end) {
  for (int i = begin; i < end; i += scan_step) {
    fill_buffer(image, thresholds, horizontal, i, &buf);
    fitter.fit(buf, min_points, i, out, labels);
  }
}

}  // namespace

Mat3 PointMoments::covariance() const {
  if (count == 0) return Mat3::Zero();
  const Vec3 c = mean();
  return outer / count - c * c.transpose();
}

LineLeastSquares fit_line(const PointMoments& moments, const Vec3& seed, int iterations) {
  const Mat3& o = moments.outer;
  return fit_upper(moments.count, moments.sum, o(0, 0), o(0, 1), o(0, 2), o(1, 1), o(1, 2), o(2, 2), seed,
                   iterations);
}

namespace {

// fit_line from the count, sum and upper triangle of the sum of outer products.
// 1 / n for small n from a table (the same correctly rounded quotients): no division latency at the head of
// every fit.
struct Reciprocals {
  static constexpr int kSize = 256;
  double value[kSize];
  constexpr Reciprocals() : value() {
    for (int n = 1; n < kSize; ++n) value[n] = 1.0 / n;
  }
};
constexpr Reciprocals kReciprocals;

inline double reciprocal(int n) { return n < Reciprocals::kSize ? kReciprocals.value[n] : 1.0 / n; }

// Centroid, covariance (from its upper triangle) and the unnormalized power iterations (the scale grows like
// lambda_max^k, harmless in double). Scalar code: the same operations, in the same order, as the Eigen expressions
// C d, |d|^2, d / |d|, d.C d.
inline __attribute__((always_inline)) LinePrefit prefit_upper(int count, const Vec3& sum, double oxx, double oxy,
                                                              double oxz, double oyy, double oyz, double ozz,
                                                              const Vec3& seed, int iterations) {
  LinePrefit p;
  if (count == 0) return p;
  const double inv_n = reciprocal(count);
  p.centroid = sum * inv_n;
  if (count == 1) return p;
  const Vec3& c = p.centroid;
  const double xx = oxx * inv_n - c.x() * c.x(), xy = oxy * inv_n - c.x() * c.y();
  const double xz = oxz * inv_n - c.x() * c.z(), yy = oyy * inv_n - c.y() * c.y();
  const double yz = oyz * inv_n - c.y() * c.z(), zz = ozz * inv_n - c.z() * c.z();
  double dx = seed.x(), dy = seed.y(), dz = seed.z();
  for (int it = 0; it < iterations; ++it) {
    const double nx = xx * dx + xy * dy + xz * dz;
    const double ny = xy * dx + yy * dy + yz * dz;
    const double nz = xz * dx + yz * dy + zz * dz;
    dx = nx, dy = ny, dz = nz;
  }
  p.xx = xx, p.xy = xy, p.xz = xz, p.yy = yy, p.yz = yz, p.zz = zz;
  p.u = Vec3(dx, dy, dz);
  p.norm2 = dx * dx + dy * dy + dz * dz;
  return p;
}

// The normalization, the rms, and the retry from the largest axis when the seed was orthogonal to the spread.
inline __attribute__((always_inline)) LineLeastSquares finish_upper(const LinePrefit& p, int count, const Vec3& sum,
                                                                    double oxx, double oxy, double oxz, double oyy,
                                                                    double oyz, double ozz, const Vec3& seed,
                                                                    int iterations) {
  LineLeastSquares f;
  f.count = count;
  if (count == 0) return f;
  f.centroid = p.centroid;
  if (count == 1) return f;
  const double xx = p.xx, xy = p.xy, xz = p.xz, yy = p.yy, yz = p.yz, zz = p.zz;
  double dx = p.u.x(), dy = p.u.y(), dz = p.u.z();
  const double norm2 = p.norm2;
  const double trace = xx + yy + zz;
  if (!(norm2 > 1e-300) || !std::isfinite(norm2)) {
    if (iterations > 0 && seed.squaredNorm() > 0.0 && trace > 0.0) {  // seed orthogonal to the spread
      const int k = xx >= yy ? (xx >= zz ? 0 : 2) : (yy >= zz ? 1 : 2);
      // one retry: when the axis fails too (overflow or underflow at absurd scales) stop, no endless recursion
      if (seed != Vec3::Unit(k)) return refit_from_axis(count, sum, oxx, oxy, oxz, oyy, oyz, ozz, k, iterations);
    }
    return f;  // all points equal
  }
  const double norm = std::sqrt(norm2);
  const F4 unit = F4{dx, dy, dz, norm} / norm;  // the three quotients in one vector division
  dx = unit[0], dy = unit[1], dz = unit[2];
  f.direction = Vec3(dx, dy, dz);
  const double cx = xx * dx + xy * dy + xz * dz;
  const double cy = xy * dx + yy * dy + yz * dz;
  const double cz = xz * dx + yz * dy + zz * dz;
  f.rms = std::sqrt(std::max(0.0, trace - (dx * cx + dy * cy + dz * cz)));
  return f;
}

inline LineLeastSquares fit_upper(int count, const Vec3& sum, double oxx, double oxy, double oxz, double oyy,
                                  double oyz, double ozz, const Vec3& seed, int iterations) {
  return finish_upper(prefit_upper(count, sum, oxx, oxy, oxz, oyy, oyz, ozz, seed, iterations), count, sum, oxx,
                      oxy, oxz, oyy, oyz, ozz, seed, iterations);
}

inline LinePrefit prefit_line(const Moments& m, const Vec3& seed) {
  return prefit_upper(m.count, m.sum, m.xx, m.xy, m.xz, m.yy, m.yz, m.zz, seed, 3);
}

inline LineLeastSquares finish_line(const LinePrefit& p, const Moments& m, const Vec3& seed) {
  return finish_upper(p, m.count, m.sum, m.xx, m.xy, m.xz, m.yy, m.yz, m.zz, seed, 3);
}

// The rare retry of fit_upper out of line, so that the hot fit_upper stays inlinable.
__attribute__((noinline, cold)) LineLeastSquares refit_from_axis(int count, const Vec3& sum, double oxx, double oxy,
                                                                 double oxz, double oyy, double oyz, double ozz,
                                                                 int axis, int iterations) {
  return fit_upper(count, sum, oxx, oxy, oxz, oyy, oyz, ozz, Vec3::Unit(axis), iterations);
}

}  // namespace

LineLeastSquares fit_line(const PointMoments& moments) {
  const Mat3 C = moments.covariance();
  int k = 0;
  C.diagonal().maxCoeff(&k);
  return fit_line(moments, C.col(k), 6);
}

namespace {

// Rows (horizontal) or columns [begin, end), every scan_step-th one; begin is a multiple of scan_step.
struct ScanBlock {
  bool horizontal = true;
  int begin = 0, end = 0;
  bool first = true;                   // the pass's first block writes the frame's list itself; the others ...
  std::vector<LineFeature> own_lines;  // ... their own, labelled from 0 in their cells
  size_t offset = 0;                   // of own_lines[0] in the frame's list
};

// Fits one block with the calling thread's work buffers, kept at their largest size: a full frame needs a few MB,
// which the allocator would otherwise map and the kernel fault in and zero again on every call.
void fit_block(const RangeImage& image, const LineFitConfig& config, const CellThresholds& thresholds, int scan_step,
               ScanBlock* block, std::vector<LineFeature>* frame_lines, std::vector<std::int32_t>* labels) {
  thread_local ScanBuffer buf;
  thread_local ScanLineFitter fitter;
  fitter.configure(config);
  const int min_points = block->horizontal ? config.min_points_h : config.min_points_v;
  std::vector<LineFeature>* lines = block->first ? frame_lines : &block->own_lines;
  fit_pass(image, thresholds, block->horizontal, min_points, fitter, buf, lines, labels, scan_step, block->begin,
           block->end);
}

// A pass split into `parts` blocks of whole scans, aligned to scan_step.
void add_blocks(bool horizontal, int scans, int scan_step, int parts, std::vector<ScanBlock>* blocks) {
  const int fitted = (scans + scan_step - 1) / scan_step;
  parts = std::max(1, std::min(parts, fitted));
  for (int p = 0; p < parts; ++p) {
    ScanBlock b;
    b.horizontal = horizontal;
    b.begin = static_cast<int>(static_cast<long long>(fitted) * p / parts) * scan_step;
    b.end = std::min(scans, static_cast<int>(static_cast<long long>(fitted) * (p + 1) / parts) * scan_step);
    b.first = p == 0;
    blocks->push_back(std::move(b));
  }
}

// Copies a later block's lines into the frame's list (sized already) at its offset and shifts its cells' labels.
void gather_block(const RangeImage& image, const ScanBlock& block, std::vector<LineFeature>* frame_lines,
                  std::vector<std::int32_t>* labels) {
  if (block.first) return;
  std::copy(block.own_lines.begin(), block.own_lines.end(), frame_lines->begin() + block.offset);
  if (block.offset == 0 || block.own_lines.empty()) return;
  const auto shift = static_cast<std::int32_t>(block.offset);
  std::int32_t* cells = labels->data();
  for (int r = block.horizontal ? block.begin : 0; r < (block.horizontal ? block.end : image.rows); ++r) {
    std::int32_t* row = cells + static_cast<std::ptrdiff_t>(r) * image.cols;
    const int c0 = block.horizontal ? 0 : block.begin, c1 = block.horizontal ? image.cols : block.end;
    for (int c = c0; c < c1; ++c)
      if (row[c] >= 0) row[c] += shift;
  }
}

}  // namespace

ScanLines fit_scan_lines(const RangeImage& image, const LineFitConfig& config, int scan_step, WorkerPool* pool) {
  if (scan_step < 1) throw std::invalid_argument("scan_step: expected >= 1");
  const size_t cells = static_cast<size_t>(image.rows) * image.cols;
  if (image.rows < 0 || image.cols < 0 || image.points.size() != cells || image.valid.size() != cells)
    throw std::invalid_argument("range image: points/valid sizes do not match rows x cols");
  ScanLines out;
  // the line lists grow to about the sizes of this thread's previous call (no reallocation copies)
  thread_local size_t previous_h = 0, previous_v = 0;
  out.h_lines.reserve(previous_h + previous_h / 8);
  out.v_lines.reserve(previous_v + previous_v / 8);
  out.h_label.assign(cells, -1);
  out.v_label.assign(cells, -1);
  thread_local CellThresholds kept_thresholds;
  cell_thresholds(image, config, kept_thresholds);
  const CellThresholds& thresholds = kept_thresholds;  // the caller's, read by every block (a lambda naming a
                                                       // thread_local would read its own thread's)
  // Blocks: with workers, each pass in about twice as many blocks as threads (the row pass carries ~40 % of the
  // work), taken in order; alone, or for an image too small to repay waking the workers, one block per pass.
  constexpr size_t kMinSharedPoints = 1 << 15;  // ~0.5 ms of fitting (a full KITTI frame: 262k, every 4th: 66k)
  const size_t fitted_points = static_cast<size_t>((image.rows + scan_step - 1) / scan_step) * image.cols +
                               static_cast<size_t>((image.cols + scan_step - 1) / scan_step) * image.rows;
  const bool shared = has_workers(pool) && fitted_points >= kMinSharedPoints;
  const int parts = shared ? 2 * pool->threads() : 1;
  std::vector<ScanBlock> blocks;
  add_blocks(true, image.rows, scan_step, parts, &blocks);
  add_blocks(false, image.cols, scan_step, parts, &blocks);
  auto lines_of = [&](const ScanBlock& b) { return b.horizontal ? &out.h_lines : &out.v_lines; };
  auto labels_of = [&](const ScanBlock& b) { return b.horizontal ? &out.h_label : &out.v_label; };
  auto fit = [&](int b) { fit_block(image, config, thresholds, scan_step, &blocks[b], lines_of(blocks[b]),
                                    labels_of(blocks[b])); };
  if (parts == 1) {
    for (int b = 0; b < static_cast<int>(blocks.size()); ++b) fit(b);
  } else {
    pool->run(static_cast<int>(blocks.size()), fit);
    for (auto* list : {&out.h_lines, &out.v_lines}) {
      size_t size = list->size();
      for (auto& b : blocks)
        if (!b.first && lines_of(b) == list) {
          b.offset = size;
          size += b.own_lines.size();
        }
      list->resize(size);
    }
    pool->run(static_cast<int>(blocks.size()),
              [&](int b) { gather_block(image, blocks[b], lines_of(blocks[b]), labels_of(blocks[b])); });
  }
  previous_h = out.h_lines.size();
  previous_v = out.v_lines.size();
  return out;
}

}  // namespace line_odom
