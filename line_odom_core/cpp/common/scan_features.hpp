// What one scan gives the registration: an organized range image and the lines and planes fitted to it
// (paper §6.2). Produced by range_image + line_fit + plane_fit, consumed by candidates + odometry.
#pragma once

#include <array>
#include <cstdint>
#include <vector>

#include "common/types.hpp"

namespace line_odom {

// rows = elevation (ring) or pixel row, cols = azimuth or pixel column; row-major; holes have valid = 0.
struct RangeImage {
  int rows = 0;
  int cols = 0;
  std::vector<Vec3> points;
  std::vector<std::uint8_t> valid;
  // Index of the input point stored in each cell (-1 for holes); empty when the input was already organized.
  std::vector<std::int32_t> source_index;

  const Vec3& at(int r, int c) const { return points[static_cast<size_t>(r) * cols + c]; }
  bool is_valid(int r, int c) const { return valid[static_cast<size_t>(r) * cols + c] != 0; }
};

struct LineFeature {
  Segment segment;          // endpoints of the fitted segment (projections of the extreme inliers)
  PluckerLine line;         // the fitted line
  Vec3 normal = Vec3::Zero();  // normal of the surface the line lies on (from H/V intersections), 0 if unknown
  int cluster = -1;         // normal cluster 0..2, -1 if unknown
  int normal_support = 0;   // crossings whose normals agree with `normal` (0 if unknown)
  int plane = -1;           // index into ScanFeatures::planes of the plane the line lies on, -1 if none
  double rms = 0.0;         // fit residual (m)
  int support = 0;          // inlier points
  int scan_index = 0;       // row (H-line) or column (V-line) of the range image
  int first = 0, last = 0;  // range of column (H) or row (V) indices covered
};

struct PlaneFeature {
  Plane plane;
  Vec3 centroid = Vec3::Zero();
  int support = 0;
  double rms = 0.0;
};

struct ScanFeatures {
  std::vector<LineFeature> h_lines;  // fitted along rows
  std::vector<LineFeature> v_lines;  // fitted along columns
  std::vector<PlaneFeature> planes;
  std::array<Vec3, 3> cluster_directions{Vec3::UnitX(), Vec3::UnitY(), Vec3::UnitZ()};
};

}  // namespace line_odom
