// What the odometry keeps of the previous scans to register the next one against.
#pragma once

#include "common/scan_features.hpp"
#include "features/feature_window.hpp"
#include "registration/surface_map.hpp"

namespace line_odom {

struct ScanHistory {
  ScanFeatures previous;         // the last scan's features: frame a of the next registration
  ScanFeatures previous_coarse;  // ... at registration.coarse_downsample, kept while the first motion is searched
  FeatureWindow window;          // the last registration.window scans' features, in the previous scan's frame
  SurfaceMap previous_surface;   // the previous scan's surface (points.weight > 0)
  int fit_step = 1;              // rows and columns the next scan's lines are fitted on (line_selection.hpp)

  void clear() {
    previous = ScanFeatures{};
    previous_coarse = ScanFeatures{};
    window.clear();
    previous_surface = SurfaceMap{};
    fit_step = 1;
  }
};

}  // namespace line_odom
