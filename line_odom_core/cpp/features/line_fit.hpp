// Line fitting on every row (H-lines) and column (V-lines) of a range image (paper §6.2 "Line Fitting").
//
// The paper runs RANSAC per scan line (3 s per KITTI frame). Here each scan line is fitted by split-and-merge,
// which is deterministic, O(n log n) per scan line and keeps the scan order (a line never takes points from
// unrelated parts of the scan line): (1) runs are cut at holes longer than max_gap and at depth jumps (the
// step between neighbouring points runs along the viewing ray: incidence below min_incidence_deg); (2) each
// run is split recursively at the point farthest from the chord while that distance exceeds the split
// threshold (corners, curved surfaces); (3) neighbouring pieces are merged while the least-squares line of
// their union keeps every point within the threshold, skipping up to max_outliers stray points between them;
// (4) every line is refitted by least squares (centroid + principal direction), a point shared by two lines
// at a corner goes to the one it fits better, end points farther than the threshold or than trim_sigmas x rms
// from the line of the middle half are trimmed; (5) lines with too few points, too short or with too large
// an rms are dropped. Thresholds grow with range r by (1 + threshold_per_m r + threshold_per_m2 r^2) (LiDAR:
// ~linear; depth cameras: ~quadratic).
//
// fit_scan_lines (line_fit.cpp) runs the rows and the columns in blocks, on worker threads; a scan line is gathered
// by scan_line_buffer, its lines found by scan_line_fitter (steps 1-5) with the arithmetic of line_fit_kernels.hpp
// and the least-squares fits of line_least_squares.
#pragma once

#include <cstdint>
#include <vector>

#include "common/scan_features.hpp"
#include "features/line_least_squares.hpp"  // PointMoments, fit_line: the least-squares fits of the lines

namespace line_odom {

struct LineFitConfig {
  int min_points_h = 5;             // lines.min_points_h: inliers of an H-line
  int min_points_v = 3;             // lines.min_points_v: inliers of a V-line (few rows when downsampled)
  double min_length = 0.3;          // lines.min_length (m): distance between the end points
  double split_distance = 0.06;     // lines.split_distance (m at range 0): max point-to-line distance in a line
  double max_rms = 0.03;            // lines.max_rms (m at range 0)
  double threshold_per_m = 0.01;    // lines.threshold_per_m: thresholds scale by 1 + a r + b r^2 ...
  double threshold_per_m2 = 0.0;    // lines.threshold_per_m2: ... with r the point's range (m)
  int max_gap = 2;                  // lines.max_gap: missing cells bridged inside one line
  double min_incidence_deg = 4.0;   // lines.min_incidence_deg: steps closer than this to the ray are jumps
  int max_outliers = 2;             // lines.max_outliers: stray points skipped between two collinear pieces
  double trim_sigmas = 5.0;         // lines.trim_sigmas: end points beyond this x rms of the line's middle half go

  double threshold_scale(double range) const {
    return 1.0 + threshold_per_m * range + threshold_per_m2 * range * range;
  }
};

// Lines of one range image with, per cell, the index of the H-line / V-line holding that point (-1 none).
struct ScanLines {
  std::vector<LineFeature> h_lines;
  std::vector<LineFeature> v_lines;
  std::vector<std::int32_t> h_label;
  std::vector<std::int32_t> v_label;
};

class WorkerPool;

// Rows and columns every scan_step-th; with a pool of several threads, in blocks on all of them (the same lines).
ScanLines fit_scan_lines(const RangeImage& image, const LineFitConfig& config, int scan_step = 1,
                         WorkerPool* pool = nullptr);

}  // namespace line_odom
