// Scan features in one call (paper §6.2): H/V lines, their normals and 3 normal clusters, planes.
// FeatureConfig holds every threshold: the settings lines.*, normals.*, planes.* (odometry/engine_settings.cpp, which
// also checks them); the sensor presets in config/*.yaml set what differs from the defaults.
#pragma once

#include "common/scan_features.hpp"
#include "features/line_fit.hpp"
#include "features/line_normals.hpp"
#include "features/plane_fit.hpp"

namespace line_odom {

struct FeatureConfig {
  LineFitConfig lines;
  NormalConfig normals;
  PlaneFitConfig planes;
};

struct FeatureStats {
  int fitted_h_lines = 0, fitted_v_lines = 0;  // before the budget (line_selection.hpp)
  int line_step = 1;                           // lines of every line_step-th row and column kept
  int h_lines = 0;
  int v_lines = 0;
  int lines_with_normal = 0;
  int crossings = 0;
  int planes = 0;
  int cluster_sizes[3] = {0, 0, 0};
  // Stage times in milliseconds of thread CPU time (wall time on a shared machine mostly measures others).
  double lines_ms = 0.0;
  double normals_ms = 0.0;  // crossings, normals and clustering
  double planes_ms = 0.0;
};

// Lines fitted on every scan_step-th row and column; past max_lines (0: no budget) only those of every s-th row and
// column are kept for normals, planes and the result (line_selection.hpp).
// With a pool of several threads the line fit runs on all of them (the same lines) and the stage times are wall time.
ScanFeatures extract_features(const RangeImage& image, const FeatureConfig& config, FeatureStats* stats = nullptr,
                              int scan_step = 1, int max_lines = 0, WorkerPool* pool = nullptr);

}  // namespace line_odom
