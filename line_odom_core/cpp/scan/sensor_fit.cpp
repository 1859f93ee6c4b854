#include "scan/sensor_fit.hpp"

#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <vector>

namespace line_odom {
namespace {

constexpr double kDegPerRad = 180.0 / kPi;

double percentile(std::vector<double>* values, double share) {
  if (values->empty()) return 0.0;
  const auto k = static_cast<std::size_t>(share * static_cast<double>(values->size() - 1));
  std::nth_element(values->begin(), values->begin() + static_cast<std::ptrdiff_t>(k), values->end());
  return (*values)[k];
}

template <typename T>
SensorFit fit(const T* data, std::size_t count, std::size_t stride, const std::int32_t* ring, const SensorModel& model,
              const RangeLimits& limits) {
  if (stride < 3) throw std::invalid_argument("points: stride must be >= 3 (x, y, z per point)");
  SensorFit out;
  out.model = model.name;
  out.rows = model.rows;
  const bool table = !model.beam_elevations.empty();
  out.max_elevation_deg = kDegPerRad * (table ? model.beam_elevations.front() : model.max_elevation);
  out.min_elevation_deg = kDegPerRad * (table ? model.beam_elevations.back() : model.min_elevation);

  std::vector<double> elevations;
  elevations.reserve(count);
  for (std::size_t i = 0; i < count; ++i) {
    const T* p = data + i * stride;
    const double x = p[0], y = p[1], z = p[2];
    const double r = std::sqrt(x * x + y * y + z * z);
    if (!std::isfinite(r) || r == 0.0 || r < limits.min_range || r > limits.max_range) continue;
    elevations.push_back(kDegPerRad * std::atan2(z, std::hypot(x, y)));
  }
  out.points = elevations.size();
  out.cloud_high_deg = percentile(&elevations, 0.995);
  out.cloud_low_deg = percentile(&elevations, 0.005);

  if (ring != nullptr && count > 0) out.ring_rows = 1LL + *std::max_element(ring, ring + count);
  if (out.ring_rows > model.rows || (ring != nullptr && count > 0 && *std::min_element(ring, ring + count) < 0))
    return out;

  OrganizeStats stats;
  const RangeImage image = organize_points(data, count, stride, ring, model, limits, &stats);
  out.row_method = stats.row_method;
  out.outside_rows = stats.outside_rows;
  const int least = std::max(1, image.cols / 100);
  int first = -1, last = -1;
  for (int r = 0; r < image.rows; ++r) {
    int valid = 0;
    for (int c = 0; c < image.cols; ++c) valid += image.is_valid(r, c) ? 1 : 0;
    if (valid < least) continue;
    ++out.filled_rows;
    if (first < 0) first = r;
    last = r;
  }
  out.band_rows = first < 0 ? 0 : last - first + 1;
  return out;
}

}  // namespace

SensorFit fit_to_sensor(const float* data, std::size_t count, std::size_t stride, const std::int32_t* ring,
                        const SensorModel& model, const RangeLimits& limits) {
  return fit(data, count, stride, ring, model, limits);
}

SensorFit fit_to_sensor(const double* data, std::size_t count, std::size_t stride, const std::int32_t* ring,
                        const SensorModel& model, const RangeLimits& limits) {
  return fit(data, count, stride, ring, model, limits);
}

}  // namespace line_odom
