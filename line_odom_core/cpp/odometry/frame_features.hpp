// What the pipeline extracts from one scan: the downsampled points, the lines and planes (paper §6.2), the coarse
// scan's while the first motion or an unmeasured velocity is searched, and the surface of the point-to-plane
// refinement.
#pragma once

#include <vector>

#include "common/scan_features.hpp"
#include "common/worker_pool.hpp"
#include "odometry/frame_result.hpp"
#include "odometry/odometry_config.hpp"
#include "registration/surface_map.hpp"

namespace line_odom {

struct FrameFeatures {
  RangeImage sparse;             // the image downsampled (empty when the image already was)
  const RangeImage* input = nullptr;  // what the features were fitted on
  ScanFeatures features;
  ScanFeatures coarse;           // at registration.coarse_downsample, when asked for
  SurfaceMap surface;            // of the point-to-plane refinement, when it runs
  std::vector<Vec3> points;      // the valid points of `input`, when the point map runs

  FrameFeatures() = default;
  FrameFeatures(const FrameFeatures&) = delete;  // `input` may point at `sparse`
  FrameFeatures& operator=(const FrameFeatures&) = delete;
};

struct FeatureRequest {
  int organized_step = 1;  // of `image`
  int fit_step = 1;        // rows and columns the lines are fitted on (line_selection.hpp)
  bool coarse = false;     // also the coarse scan's features
  bool surface = false;    // the point-to-plane refinement's surface
  bool points = false;     // the valid points
};

// Fills *out from `image`; the stage times and feature counts into st.
void extract_frame_features(const RangeImage& image, const OdometryConfig& config, const FeatureRequest& request,
                            WorkerPool* pool, FrameFeatures* out, FrameStats* st);

}  // namespace line_odom
