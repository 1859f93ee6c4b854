#include "features/feature_extraction.hpp"

#include <chrono>
#include <ctime>

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

}  // namespace

ScanFeatures extract_features(const RangeImage& image, const FeatureConfig& config, FeatureStats* stats,
                              int scan_step, int max_lines, WorkerPool* pool) {
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
