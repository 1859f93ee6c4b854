// The engine's settings by dotted name (the ROS parameters' names): one list, visit_settings, that apply_setting and
// config_settings (odometry.hpp) walk; the bindings, the presets and the schema follow it.
#include "odometry/odometry.hpp"

#include <cmath>
#include <cstdint>
#include <string>
#include <utility>
#include <variant>
#include <vector>

namespace line_odom {

namespace {

// Calls visit(name, field) for every setting; the one list of names the bindings, presets and schema follow.
template <typename Config, typename Visit>
void visit_settings(Config& c, Visit&& visit) {
  visit("downsample", c.downsample);
  visit("seed", c.seed);
  visit("threads", c.threads);
  visit("sensor.model", c.sensor.model);
  visit("sensor.rows", c.sensor.rows);
  visit("sensor.cols", c.sensor.cols);
  visit("sensor.max_elevation_deg", c.sensor.max_elevation_deg);
  visit("sensor.min_elevation_deg", c.sensor.min_elevation_deg);
  visit("sensor.min_range", c.sensor.limits.min_range);
  visit("sensor.max_range", c.sensor.limits.max_range);
  visit("sensor.deskew", c.sensor.deskew);
  visit("sensor.deskew_tolerance", c.sensor.deskew_tolerance);
  visit("sensor.deskew_iterations", c.sensor.deskew_iterations);
  visit("sensor.deskew_trend", c.sensor.deskew_trend);
  // FEATURE_SETTINGS
  visit("candidates.max_distance", c.candidates.max_distance);
  visit("candidates.min_line_angle_deg", c.candidates.min_line_angle_deg);
  visit("candidates.max_normal_angle_deg", c.candidates.max_normal_angle_deg);
  visit("candidates.plane_max_angle_deg", c.candidates.plane_max_angle_deg);
  visit("candidates.plane_max_distance", c.candidates.plane_max_distance);
  visit("candidates.max_pairs_per_line", c.candidates.max_pairs_per_line);
  visit("ransac.solver", c.ransac.solver);
  visit("ransac.max_iterations", c.ransac.max_iterations);
  visit("ransac.min_iterations", c.ransac.min_iterations);
  visit("ransac.confidence", c.ransac.confidence);
  visit("ransac.inlier_threshold", c.ransac.inlier_threshold);
  visit("ransac.plane_angle_threshold_deg", c.ransac.plane_angle_threshold_deg);
  visit("ransac.plane_distance_threshold", c.ransac.plane_distance_threshold);
  visit("ransac.refine_iterations", c.ransac.refine_iterations);
  visit("ransac.huber_delta", c.ransac.huber_delta);
  visit("ransac.degeneracy_threshold", c.ransac.degeneracy_threshold);
  visit("registration.passes", c.registration.passes);
  visit("registration.pass_distance_scale", c.registration.pass_distance_scale);
  visit("registration.max_lines", c.registration.max_lines);
  visit("registration.first_motion_pairs_per_line", c.registration.first_motion_pairs_per_line);
  visit("registration.window", c.registration.window);
  visit("registration.min_inliers", c.registration.min_inliers);
  visit("registration.max_translation", c.registration.max_translation);
  visit("registration.max_rotation_deg", c.registration.max_rotation_deg);
  visit("registration.constant_velocity", c.registration.constant_velocity);
  visit("registration.persistence_window", c.registration.persistence_window);
  visit("registration.max_axis_support", c.registration.max_axis_support);
  visit("registration.max_axis_pair_support", c.registration.max_axis_pair_support);
  visit("registration.min_inlier_ratio", c.registration.min_inlier_ratio);
  visit("registration.max_prediction_gap", c.registration.max_prediction_gap);
  visit("registration.guess_preference", c.registration.guess_preference);
  visit("registration.min_sample_pair_share", c.registration.min_sample_pair_share);
  visit("registration.coarse_downsample", c.registration.coarse_downsample);
  visit("registration.covariance_scale", c.registration.covariance_scale);
  visit("registration.covariance_per_inlier", c.registration.covariance_per_inlier);
  visit("registration.motion_prior_translation_sigma", c.registration.motion_prior_translation_sigma);
  visit("registration.motion_prior_rotation_sigma_deg", c.registration.motion_prior_rotation_sigma_deg);
  visit("registration.partial_updates", c.registration.partial_updates);
  visit("registration.fallback_translation_sigma", c.registration.fallback_translation_sigma);
  visit("registration.fallback_rotation_sigma_deg", c.registration.fallback_rotation_sigma_deg);
  visit("points.weight", c.points.weight);
  visit("points.max_downsample", c.points.max_downsample);
  visit("points.voxel", c.points.voxel);
  visit("points.stride", c.points.stride);
  visit("points.min_points", c.points.min_points);
  visit("points.min_planarity", c.points.min_planarity);
  visit("points.huber", c.points.huber);
  visit("points.iterations", c.points.iterations);
  visit("points.max_translation", c.points.max_translation);
  visit("points.max_rotation_deg", c.points.max_rotation_deg);
  visit("point_map.enabled", c.point_map.enabled);
  visit("point_map.voxel", c.point_map.voxel);
  visit("point_map.max_points_per_voxel", c.point_map.max_points_per_voxel);
  visit("point_map.max_iterations", c.point_map.alignment.max_iterations);
  visit("point_map.initial_threshold", c.point_map.alignment.initial_threshold);
  visit("point_map.min_motion", c.point_map.alignment.min_motion);
  visit("validation.enabled", c.validation.enabled);
  visit("validation.tolerance", c.validation.tolerance);
  visit("validation.motion_share", c.validation.motion_share);
  visit("validation.significance", c.validation.significance);
}

const char* const kSolverNames[] = {"auto", "7L", "3L1P", "1L2P"};

SettingValue to_value(bool v) { return v; }
SettingValue to_value(int v) { return static_cast<std::int64_t>(v); }
SettingValue to_value(std::uint64_t v) { return static_cast<std::int64_t>(v); }
SettingValue to_value(double v) { return v; }
SettingValue to_value(const std::string& v) { return v; }
SettingValue to_value(SolverMode v) { return std::string(kSolverNames[static_cast<int>(v)]); }

std::string assign(bool* field, const SettingValue& v) {
  if (!std::holds_alternative<bool>(v)) return "expected a bool";
  *field = std::get<bool>(v);
  return {};
}
std::string assign(int* field, const SettingValue& v) {
  if (!std::holds_alternative<std::int64_t>(v)) return "expected an int";
  *field = static_cast<int>(std::get<std::int64_t>(v));
  return {};
}
std::string assign(std::uint64_t* field, const SettingValue& v) {
  if (!std::holds_alternative<std::int64_t>(v) || std::get<std::int64_t>(v) < 0) return "expected an int >= 0";
  *field = static_cast<std::uint64_t>(std::get<std::int64_t>(v));
  return {};
}
std::string assign(double* field, const SettingValue& v) {
  if (std::holds_alternative<double>(v)) {
    *field = std::get<double>(v);
  } else if (std::holds_alternative<std::int64_t>(v)) {
    *field = static_cast<double>(std::get<std::int64_t>(v));
  } else {
    return "expected a float";
  }
  return std::isfinite(*field) ? std::string() : std::string("expected a finite float");
}
std::string assign(std::string* field, const SettingValue& v) {
  if (!std::holds_alternative<std::string>(v)) return "expected a string";
  *field = std::get<std::string>(v);
  return {};
}
std::string assign(SolverMode* field, const SettingValue& v) {
  if (std::holds_alternative<std::string>(v)) {
    const std::string& s = std::get<std::string>(v);
    for (int i = 0; i < 4; ++i) {
      if (s == kSolverNames[i]) {
        *field = static_cast<SolverMode>(i);
        return {};
      }
    }
  }
  return "expected one of auto, 7L, 3L1P, 1L2P";
}

}  // namespace

std::string apply_setting(OdometryConfig* config, const std::string& name, const SettingValue& value) {
  for (const auto& field : feature_config_fields(config->features)) {
    if (field.first != name) continue;
    double number = 0.0;
    if (std::holds_alternative<bool>(value)) {
      number = std::get<bool>(value) ? 1.0 : 0.0;
    } else if (std::holds_alternative<std::int64_t>(value)) {
      number = static_cast<double>(std::get<std::int64_t>(value));
    } else if (std::holds_alternative<double>(value)) {
      number = std::get<double>(value);
    } else {
      return "expected a number";
    }
    try {
      set_feature_config_field(&config->features, name, number);
    } catch (const std::invalid_argument& e) {
      return e.what();
    }
    return {};
  }
  std::string error = "unknown setting";
  visit_settings(*config, [&](const char* key, auto& field) {
    if (name == key) error = assign(&field, value);
  });
  return error;
}

std::vector<std::pair<std::string, SettingValue>> config_settings(const OdometryConfig& config) {
  std::vector<std::pair<std::string, SettingValue>> out;
  visit_settings(config, [&](const char* key, const auto& field) { out.emplace_back(key, to_value(field)); });
  for (const auto& [name, value] : feature_config_fields(config.features)) out.emplace_back(name, value);
  return out;
}

}  // namespace line_odom
