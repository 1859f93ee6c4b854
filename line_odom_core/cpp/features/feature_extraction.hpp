// Scan features in one call (paper §6.2): H/V lines, their normals and 3 normal clusters, planes.
// FeatureConfig holds every threshold; its fields map to the dotted parameter names given beside them
// (lines.*, normals.*, planes.*). Presets: kitti() for the HDL-64E, tum() for the Kinect depth camera.
#pragma once

#include <string>
#include <utility>
#include <vector>

#include "common/scan_features.hpp"
#include "features/line_fit.hpp"
#include "features/line_normals.hpp"
#include "features/plane_fit.hpp"

namespace line_odom {

struct FeatureConfig {
  LineFitConfig lines;
  NormalConfig normals;
  PlaneFitConfig planes;

  static FeatureConfig kitti();  // HDL-64E: ~2 cm range noise, thresholds growing ~linearly with range
  static FeatureConfig tum();    // Kinect: depth noise and quantization growing ~quadratically with depth
  static FeatureConfig preset(const std::string& name);  // "kitti" / "kitti_hdl64" / "hdl64", "tum" / "tum_kinect"
  void validate() const;
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

// Every config field by its dotted name ("lines.min_points_h", ...) with its value as a double
// (ints and bools included), in declaration order.
std::vector<std::pair<std::string, double>> feature_config_fields(const FeatureConfig& config);
// Sets one field by dotted name; throws std::invalid_argument for an unknown name or a value that is not
// representable (non-integer for an int field, not 0/1 for a bool). Call validate() after the last one.
void set_feature_config_field(FeatureConfig* config, const std::string& name, double value);

// Lines fitted on every scan_step-th row and column; past max_lines (0: no budget) only those of every s-th row and
// column are kept for normals, planes and the result (line_selection.hpp).
// With a pool of several threads the line fit runs on all of them (the same lines) and the stage times are wall time.
ScanFeatures extract_features(const RangeImage& image, const FeatureConfig& config, FeatureStats* stats = nullptr,
                              int scan_step = 1, int max_lines = 0, WorkerPool* pool = nullptr);

}  // namespace line_odom
