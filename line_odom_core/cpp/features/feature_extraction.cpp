#include "features/feature_extraction.hpp"

#include <chrono>
#include <cmath>
#include <ctime>
#include <stdexcept>

#include "common/worker_pool.hpp"
#include "features/line_selection.hpp"

namespace line_odom {

namespace {

// Stage timings in thread CPU time: on a loaded machine wall time mostly measures the other processes. Work shared
// with other threads is timed in wall time (the calling thread's CPU time would leave theirs out).
class StageClock {
 public:
  explicit StageClock(bool wall) : id_(wall ? CLOCK_MONOTONIC : CLOCK_THREAD_CPUTIME_ID) {}
  std::chrono::nanoseconds now() const {
    timespec ts{};
    clock_gettime(id_, &ts);
    return std::chrono::seconds(ts.tv_sec) + std::chrono::nanoseconds(ts.tv_nsec);
  }
  double ms_since(std::chrono::nanoseconds t0) const {
    return std::chrono::duration<double, std::milli>(now() - t0).count();
  }

 private:
  clockid_t id_;
};

struct FieldRef {
  const char* name;
  int* i = nullptr;
  double* d = nullptr;
  bool* b = nullptr;
};

std::vector<FieldRef> field_refs(FeatureConfig& c) {
  auto I = [](const char* n, int* p) { return FieldRef{n, p, nullptr, nullptr}; };
  auto D = [](const char* n, double* p) { return FieldRef{n, nullptr, p, nullptr}; };
  auto B = [](const char* n, bool* p) { return FieldRef{n, nullptr, nullptr, p}; };
  return {
      I("lines.min_points_h", &c.lines.min_points_h),
      I("lines.min_points_v", &c.lines.min_points_v),
      D("lines.min_length", &c.lines.min_length),
      D("lines.split_distance", &c.lines.split_distance),
      D("lines.max_rms", &c.lines.max_rms),
      D("lines.threshold_per_m", &c.lines.threshold_per_m),
      D("lines.threshold_per_m2", &c.lines.threshold_per_m2),
      I("lines.max_gap", &c.lines.max_gap),
      D("lines.min_incidence_deg", &c.lines.min_incidence_deg),
      I("lines.max_outliers", &c.lines.max_outliers),
      D("lines.trim_sigmas", &c.lines.trim_sigmas),
      D("normals.min_crossing_angle_deg", &c.normals.min_crossing_angle_deg),
      D("normals.max_deviation_deg", &c.normals.max_deviation_deg),
      I("normals.min_crossings", &c.normals.min_crossings),
      D("normals.min_agreement", &c.normals.min_agreement),
      D("normals.vote_angle_deg", &c.normals.vote_angle_deg),
      D("normals.min_separation_deg", &c.normals.min_separation_deg),
      D("normals.max_cluster_angle_deg", &c.normals.max_cluster_angle_deg),
      D("normals.min_cluster_fraction", &c.normals.min_cluster_fraction),
      D("normals.end_crossing_weight", &c.normals.end_crossing_weight),
      B("planes.enabled", &c.planes.enabled),
      D("planes.max_distance", &c.planes.max_distance),
      D("planes.max_normal_angle_deg", &c.planes.max_normal_angle_deg),
      I("planes.min_points", &c.planes.min_points),
      I("planes.min_lines", &c.planes.min_lines),
      D("planes.min_extent", &c.planes.min_extent),
      D("planes.max_rms", &c.planes.max_rms),
      I("planes.max_planes", &c.planes.max_planes),
  };
}

}  // namespace

std::vector<std::pair<std::string, double>> feature_config_fields(const FeatureConfig& config) {
  FeatureConfig copy = config;
  std::vector<std::pair<std::string, double>> out;
  for (const auto& f : field_refs(copy))
    out.emplace_back(f.name, f.i ? static_cast<double>(*f.i) : f.d ? *f.d : (*f.b ? 1.0 : 0.0));
  return out;
}

void set_feature_config_field(FeatureConfig* config, const std::string& name, double value) {
  for (const auto& f : field_refs(*config)) {
    if (name != f.name) continue;
    if (!std::isfinite(value)) throw std::invalid_argument(name + ": expected a finite number");
    if (f.d) {
      *f.d = value;
    } else if (f.i) {
      if (value != std::floor(value) || std::abs(value) > 1e9)
        throw std::invalid_argument(name + ": expected an integer, got " + std::to_string(value));
      *f.i = static_cast<int>(value);
    } else {
      if (value != 0.0 && value != 1.0) throw std::invalid_argument(name + ": expected a boolean");
      *f.b = value != 0.0;
    }
    return;
  }
  throw std::invalid_argument("unknown feature parameter '" + name + "'");
}

FeatureConfig FeatureConfig::kitti() { return FeatureConfig{}; }

FeatureConfig FeatureConfig::tum() {
  FeatureConfig c;
  c.lines.min_points_h = 5;
  c.lines.min_points_v = 4;
  c.lines.min_length = 0.08;
  c.lines.split_distance = 0.006;
  c.lines.max_rms = 0.004;
  c.lines.threshold_per_m = 0.0;
  c.lines.threshold_per_m2 = 1.0;
  c.lines.max_gap = 2;
  c.planes.max_distance = 0.01;
  c.planes.min_points = 30;
  c.planes.min_extent = 0.3;
  c.planes.max_rms = 0.02;
  return c;
}

FeatureConfig FeatureConfig::preset(const std::string& name) {
  if (name == "kitti" || name == "kitti_hdl64" || name == "hdl64") return kitti();
  if (name == "tum" || name == "tum_kinect") return tum();
  throw std::invalid_argument("features preset: unknown '" + name + "' (expected kitti, tum)");
}

void FeatureConfig::validate() const {
  lines.validate();
  normals.validate();
  planes.validate();
}

ScanFeatures extract_features(const RangeImage& image, const FeatureConfig& config, FeatureStats* stats,
                              int scan_step, int max_lines, WorkerPool* pool) {
  config.validate();
  FeatureStats st;
  const StageClock clock(has_workers(pool));
  auto t0 = clock.now();
  ScanLines lines = fit_scan_lines(image, config.lines, scan_step, pool);
  st.fitted_h_lines = static_cast<int>(lines.h_lines.size());
  st.fitted_v_lines = static_cast<int>(lines.v_lines.size());
  st.line_step = registration_line_step(lines.h_lines, lines.v_lines, max_lines, scan_step);
  keep_lines_every(st.line_step, &lines);
  st.lines_ms = clock.ms_since(t0);

  t0 = clock.now();
  const std::vector<LineCrossing> crossings = find_crossings(image, lines, config.normals);
  assign_line_normals(crossings, config.normals, &lines);
  ScanFeatures out;
  out.cluster_directions = cluster_line_normals(config.normals, &lines.h_lines, &lines.v_lines);
  st.normals_ms = clock.ms_since(t0);

  t0 = clock.now();
  out.planes = fit_planes(image, crossings, config.planes, config.lines, &lines);
  st.planes_ms = clock.ms_since(t0);

  out.h_lines = std::move(lines.h_lines);
  out.v_lines = std::move(lines.v_lines);
  if (stats) {
    st.h_lines = static_cast<int>(out.h_lines.size());
    st.v_lines = static_cast<int>(out.v_lines.size());
    st.crossings = static_cast<int>(crossings.size());
    st.planes = static_cast<int>(out.planes.size());
    for (const auto* list : {&out.h_lines, &out.v_lines})
      for (const auto& f : *list) {
        if (f.normal.squaredNorm() > 0.25) ++st.lines_with_normal;
        if (f.cluster >= 0 && f.cluster < 3) ++st.cluster_sizes[f.cluster];
      }
    *stats = st;
  }
  return out;
}

}  // namespace line_odom
