// One scan line (a row or a column of the range image) gathered for the line fit: its valid points in scan order as
// arrays, their split thresholds and the prefix sums of their moments; and the per-cell thresholds of a frame.
#pragma once

#include <cstddef>
#include <vector>

#include "common/scan_features.hpp"
#include "common/simd.hpp"
#include "features/line_fit.hpp"
#include "features/line_least_squares.hpp"

namespace line_odom::line_fit_detail {

constexpr int kPad = simd::kLanes;  // elements readable past the end of a scan buffer's arrays (lanes past n are masked)

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

// Per-cell split thresholds, computed once for both passes (holes: 1).
struct CellThresholds {
  std::vector<double> tau;    // per cell: tau, 1 / tau^2 interleaved (one memory stream for the column pass)
};

// The functions below are defined with AVX2 and baseline clones (LINE_ODOM_VECTOR_CLONES); declared without them, a
// caller in another file calls the one the loader picked.

// Per cell: the split threshold split_distance x threshold_scale(range) and 1 / its square (holes: 1). A branch-free
// loop over the cells (vectorized; the same IEEE operations as Vec3::norm and threshold_scale).
void cell_thresholds(const RangeImage& img, const LineFitConfig& cfg, CellThresholds& t);

// Row (horizontal) or column `index` of the image into `buf`, called once per scan line. Out of line: inlined into
// the fitter's loop it would share the registers of the whole fitter.
void fill_buffer(const RangeImage& img, const CellThresholds& th, bool horizontal, int index, ScanBuffer* buf);

}  // namespace line_odom::line_fit_detail
