#include "odometry/frame_features.hpp"

#include <algorithm>
#include <cstdint>

#include "common/stopwatch.hpp"
#include "features/feature_extraction.hpp"
#include "scan/range_image.hpp"

namespace line_odom {

void extract_frame_features(const RangeImage& image, const OdometryConfig& config, const FeatureRequest& request,
                            WorkerPool* pool, FrameFeatures* out, FrameStats* st) {
  Stopwatch stage;
  out->input = &image;
  if (config.downsample > request.organized_step) {
    out->sparse = downsample(image, config.downsample / request.organized_step);
    out->input = &out->sparse;
  }
  const RangeImage& input = *out->input;
  st->ms.downsample = stage.ms();
  st->points = static_cast<int>(std::count(input.valid.begin(), input.valid.end(), std::uint8_t{1}));

  stage = Stopwatch();
  FeatureStats fstats;
  out->features = extract_features(input, config.features, &fstats, request.fit_step, config.registration.max_lines,
                                   pool);
  st->ms.features = stage.ms();
  st->ms.lines = fstats.lines_ms;
  st->ms.normals = fstats.normals_ms;
  st->ms.planes = fstats.planes_ms;
  st->fit_step = request.fit_step;
  st->h_lines = fstats.fitted_h_lines;
  st->v_lines = fstats.fitted_v_lines;
  st->planes = static_cast<int>(out->features.planes.size());
  st->line_step = fstats.line_step;
  st->registered_lines = static_cast<int>(out->features.h_lines.size() + out->features.v_lines.size());

  if (request.coarse) {
    stage = Stopwatch();
    const int coarse_step = config.registration.coarse_downsample;
    out->coarse = extract_features(downsample(image, coarse_step / request.organized_step), config.features, nullptr, 1,
                                   0, pool);
    st->ms.features += stage.ms();
  }
  if (request.surface) {
    stage = Stopwatch();
    out->surface.build(input, config.points.voxel, config.points.stride);
    st->ms.points = stage.ms();
  }
  if (request.points) {
    // Every k-th valid point, at most kMapInputPoints: the point map keeps a few points per voxel of a metre or so,
    // which a dense scan fills many times over.
    constexpr int kMapInputPoints = 30000;
    const int step = std::max(1, (st->points + kMapInputPoints - 1) / kMapInputPoints);
    out->points.reserve(static_cast<std::size_t>(st->points / step + 1));
    int k = 0;
    for (std::size_t i = 0; i < input.points.size(); ++i)
      if (input.valid[i] && k++ % step == 0) out->points.push_back(input.points[i]);
  }
}

}  // namespace line_odom
