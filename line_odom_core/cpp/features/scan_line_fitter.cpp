#include "features/scan_line_fitter.hpp"

#include <algorithm>
#include <cmath>
#include <cstddef>
#include <cstring>
#include <limits>
#include <utility>

#include "common/simd.hpp"
#include "features/line_fit_kernels.hpp"
#include "features/line_least_squares.hpp"

namespace line_odom::line_fit_detail {

namespace {

constexpr double kDeg = kPi / 180.0;

// A line is a stretch [first, last] of the scan line minus the stray points skipped while merging.
struct CandidateLine {
  int first = 0, last = 0;
  int skipped_begin = 0, skipped_end = 0;  // range in ScanLineFitter::skipped_
  Moments moments;
  LineLeastSquares fit;
  bool accepted = false;
};

double residual(const LineLeastSquares& f, const Vec3& p) { return std::sqrt(distance2(p, f.centroid, f.direction)); }

// Squared distance to the line over the squared threshold: > 1 means outside.
inline __attribute__((always_inline)) double excess2(const LineLeastSquares& f, const ScanBuffer& buf, int k) {
  return distance2(buf.p(k), f.centroid, f.direction) * buf.inv_tau2[k];
}

void remove_point(Moments* m, const Vec3& p) { m->remove(p); }

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

void fit_scan_block(const RangeImage& image, const LineFitConfig& config, const CellThresholds& thresholds,
                    bool horizontal, int scan_step, int begin, int end, std::vector<LineFeature>* lines,
                    std::vector<std::int32_t>* labels) {
  thread_local ScanBuffer buf;
  thread_local ScanLineFitter fitter;
  fitter.configure(config);
  const int min_points = horizontal ? config.min_points_h : config.min_points_v;
  fit_pass(image, thresholds, horizontal, min_points, fitter, buf, lines, labels, scan_step, begin, end);
}

}  // namespace line_odom::line_fit_detail
