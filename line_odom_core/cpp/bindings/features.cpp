// Bindings of the scan and feature layers: range images from points or depth, lines, normals and planes.
#include <pybind11/eigen.h>
#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

#include <cmath>
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "bindings/module.hpp"
#include "bindings/settings.hpp"
#include "common/worker_pool.hpp"
#include "features/feature_extraction.hpp"
#include "odometry/engine_settings.hpp"
#include "scan/range_image.hpp"

namespace py = pybind11;

namespace feature_bindings {

using namespace line_odom;

py::dict organize_stats_dict(const OrganizeStats& s) {
  py::dict d;
  d["input_points"] = s.input_points;
  d["kept_points"] = s.kept_points;
  d["invalid_points"] = s.invalid_points;
  d["out_of_range"] = s.out_of_range;
  d["outside_rows"] = s.outside_rows;
  d["cell_collisions"] = s.cell_collisions;
  d["row_method"] = s.row_method;
  return d;
}

py::dict range_image_dict(const RangeImage& img, const OrganizeStats& stats) {
  py::array_t<double> points({img.rows, img.cols, 3});
  py::array_t<bool> valid({img.rows, img.cols});
  auto P = points.mutable_unchecked<3>();
  auto M = valid.mutable_unchecked<2>();
  const double nan = std::nan("");
  for (int r = 0; r < img.rows; ++r)
    for (int c = 0; c < img.cols; ++c) {
      const bool ok = img.is_valid(r, c);
      M(r, c) = ok;
      for (int k = 0; k < 3; ++k) P(r, c, k) = ok ? img.at(r, c)(k) : nan;
    }
  py::dict d;
  d["points"] = points;
  d["valid"] = valid;
  if (!img.source_index.empty()) {
    py::array_t<std::int32_t> src({img.rows, img.cols});
    std::copy(img.source_index.begin(), img.source_index.end(), src.mutable_data());
    d["source_index"] = src;
  }
  d["stats"] = organize_stats_dict(stats);
  return d;
}

RangeLimits limits_from(double min_range, double max_range) {
  RangeLimits l;
  l.min_range = min_range;
  l.max_range = max_range;
  return l;
}

py::dict organize_points_py(const py::array& points, const py::object& ring, const std::string& sensor,
                            double min_range, double max_range, int downsample_step, bool while_organizing) {
  if (points.ndim() != 2 || points.shape(1) < 3)
    throw py::value_error("points: expected an (N, 3) or (N, >=3) array (x, y, z first), got ndim " +
                          std::to_string(points.ndim()));
  if (downsample_step < 1) throw py::value_error("downsample: expected >= 1");
  const size_t n = static_cast<size_t>(points.shape(0));
  const size_t stride = static_cast<size_t>(points.shape(1));
  py::array_t<std::int32_t, py::array::c_style | py::array::forcecast> ring_arr;
  if (!ring.is_none()) {
    ring_arr = py::array_t<std::int32_t, py::array::c_style | py::array::forcecast>::ensure(ring);
    if (!ring_arr || ring_arr.ndim() != 1 || static_cast<size_t>(ring_arr.shape(0)) != n)
      throw py::value_error("ring: expected a 1-D integer array with one entry per point (" + std::to_string(n) + ")");
  }
  const SensorModel model = sensor_preset(sensor);
  const RangeLimits limits = limits_from(min_range, max_range);
  const std::int32_t* ring_ptr = ring.is_none() ? nullptr : ring_arr.data();
  OrganizeStats stats;
  RangeImage img;
  if (points.dtype().is(py::dtype::of<float>())) {
    auto a = py::array_t<float, py::array::c_style>::ensure(points);
    py::gil_scoped_release release;
    img = while_organizing
              ? organize_points_downsampled(a.data(), n, stride, ring_ptr, model, limits, downsample_step, &stats)
              : downsample(organize_points(a.data(), n, stride, ring_ptr, model, limits, &stats), downsample_step);
  } else {
    auto a = py::array_t<double, py::array::c_style | py::array::forcecast>::ensure(points);
    if (!a) throw py::value_error("points: expected a numeric array");
    py::gil_scoped_release release;
    img = while_organizing
              ? organize_points_downsampled(a.data(), n, stride, ring_ptr, model, limits, downsample_step, &stats)
              : downsample(organize_points(a.data(), n, stride, ring_ptr, model, limits, &stats), downsample_step);
  }
  return range_image_dict(img, stats);
}

py::dict organize_depth_py(const py::array& depth, const Eigen::Matrix3d& K, double min_depth, double max_depth,
                           int downsample_step, bool while_organizing) {
  if (depth.ndim() != 2) throw py::value_error("depth: expected an (H, W) array of metres");
  if (downsample_step < 1) throw py::value_error("downsample: expected >= 1");
  auto a = py::array_t<float, py::array::c_style | py::array::forcecast>::ensure(depth);
  if (!a) throw py::value_error("depth: expected a numeric array");
  const int rows = static_cast<int>(a.shape(0)), cols = static_cast<int>(a.shape(1));
  const RangeLimits limits = limits_from(min_depth, max_depth);
  OrganizeStats stats;
  RangeImage img;
  {
    py::gil_scoped_release release;
    img = while_organizing ? organize_depth_downsampled(a.data(), rows, cols, K, limits, downsample_step, &stats)
                           : downsample(organize_depth(a.data(), rows, cols, K, limits, &stats), downsample_step);
  }
  return range_image_dict(img, stats);
}

FeatureConfig config_from(const py::object& config) {
  if (config.is_none()) return FeatureConfig{};
  if (!py::isinstance<py::dict>(config)) throw py::value_error("config: expected a dict of dotted names");
  return py_settings::from_dict(feature_settings(), config.cast<py::dict>());
}

py::dict lines_dict(const std::vector<LineFeature>& lines) {
  const py::ssize_t n = static_cast<py::ssize_t>(lines.size());
  py::array_t<double> segments({n, py::ssize_t(2), py::ssize_t(3)}), plucker({n, py::ssize_t(6)}),
      normals({n, py::ssize_t(3)}), rms(n);
  py::array_t<std::int32_t> cluster(n), support(n), scan_index(n), first(n), last(n), normal_support(n), plane(n);
  auto S = segments.mutable_unchecked<3>();
  auto L = plucker.mutable_unchecked<2>();
  auto N = normals.mutable_unchecked<2>();
  for (py::ssize_t i = 0; i < n; ++i) {
    const LineFeature& f = lines[i];
    for (int k = 0; k < 3; ++k) {
      S(i, 0, k) = f.segment.a(k);
      S(i, 1, k) = f.segment.b(k);
      L(i, k) = f.line.d(k);
      L(i, 3 + k) = f.line.m(k);
      N(i, k) = f.normal(k);
    }
    rms.mutable_data()[i] = f.rms;
    cluster.mutable_data()[i] = f.cluster;
    support.mutable_data()[i] = f.support;
    scan_index.mutable_data()[i] = f.scan_index;
    first.mutable_data()[i] = f.first;
    last.mutable_data()[i] = f.last;
    normal_support.mutable_data()[i] = f.normal_support;
    plane.mutable_data()[i] = f.plane;
  }
  py::dict d;
  d["segments"] = segments;
  d["plucker"] = plucker;
  d["normals"] = normals;
  d["cluster"] = cluster;
  d["rms"] = rms;
  d["support"] = support;
  d["scan_index"] = scan_index;
  d["first"] = first;
  d["last"] = last;
  d["normal_support"] = normal_support;
  d["plane"] = plane;
  return d;
}

py::dict extract_features_py(const py::array& xyz, const py::object& config, int threads) {
  if (threads < 1) throw py::value_error("threads: expected >= 1, got " + std::to_string(threads));
  if (xyz.ndim() != 3 || xyz.shape(2) != 3)
    throw py::value_error("range_image: expected an (H, W, 3) organized cloud (NaN or zero = hole)");
  auto a = py::array_t<double, py::array::c_style | py::array::forcecast>::ensure(xyz);
  if (!a) throw py::value_error("range_image: expected a numeric array");
  const FeatureConfig cfg = config_from(config);
  const int rows = static_cast<int>(a.shape(0)), cols = static_cast<int>(a.shape(1));
  ScanFeatures features;
  FeatureStats stats;
  {
    py::gil_scoped_release release;
    const RangeImage img = organize_cloud(a.data(), rows, cols, 3, RangeLimits{});
    std::unique_ptr<WorkerPool> pool = threads > 1 ? std::make_unique<WorkerPool>(threads) : nullptr;
    features = extract_features(img, cfg, &stats, 1, 0, pool.get());
  }
  py::dict d;
  d["h_lines"] = lines_dict(features.h_lines);
  d["v_lines"] = lines_dict(features.v_lines);
  const py::ssize_t np = static_cast<py::ssize_t>(features.planes.size());
  py::array_t<double> planes({np, py::ssize_t(4)}), centroids({np, py::ssize_t(3)}), prms(np);
  py::array_t<std::int32_t> psupport(np);
  auto P = planes.mutable_unchecked<2>();
  auto C = centroids.mutable_unchecked<2>();
  for (py::ssize_t i = 0; i < np; ++i) {
    const PlaneFeature& f = features.planes[i];
    for (int k = 0; k < 3; ++k) {
      P(i, k) = f.plane.n(k);
      C(i, k) = f.centroid(k);
    }
    P(i, 3) = f.plane.delta;
    prms.mutable_data()[i] = f.rms;
    psupport.mutable_data()[i] = f.support;
  }
  py::dict pd;
  pd["planes"] = planes;
  pd["centroids"] = centroids;
  pd["rms"] = prms;
  pd["support"] = psupport;
  d["planes"] = pd;
  Eigen::Matrix3d dirs;
  for (int k = 0; k < 3; ++k) dirs.row(k) = features.cluster_directions[k].transpose();
  d["cluster_directions"] = dirs;
  py::dict st;
  st["h_lines"] = stats.h_lines;
  st["v_lines"] = stats.v_lines;
  st["lines_with_normal"] = stats.lines_with_normal;
  st["crossings"] = stats.crossings;
  st["planes"] = stats.planes;
  st["cluster_sizes"] = py::make_tuple(stats.cluster_sizes[0], stats.cluster_sizes[1], stats.cluster_sizes[2]);
  st["lines_ms"] = stats.lines_ms;
  st["normals_ms"] = stats.normals_ms;
  st["planes_ms"] = stats.planes_ms;
  d["stats"] = st;
  return d;
}

}  // namespace feature_bindings

void line_odom_bindings::register_features(py::module_& m) {
  m.def("organize_points", &feature_bindings::organize_points_py, py::arg("points"), py::arg("ring") = py::none(),
        py::arg("sensor") = "hdl64", py::arg("min_range") = 0.0, py::arg("max_range") = 1e9,
        py::arg("downsample") = 1, py::arg("downsample_while_organizing") = false,
        "Unorganized LiDAR points (N, >=3) -> range image dict: points (H, W, 3) with NaN holes, valid (H, W), "
        "source_index (H, W), stats. Rows from `ring`, else the KITTI ring order, else elevation. "
        "downsample_while_organizing: bin only the kept rows (same image; stats count the kept rows).");
  m.def("organize_depth", &feature_bindings::organize_depth_py, py::arg("depth"), py::arg("K"),
        py::arg("min_depth") = 0.0, py::arg("max_depth") = 1e9, py::arg("downsample") = 1,
        py::arg("downsample_while_organizing") = false,
        "Depth image (H, W) in metres back-projected with K -> range image dict (camera optical frame). "
        "downsample_while_organizing: back-project only the kept pixels (same image; stats count them).");
  m.def("extract_features", &feature_bindings::extract_features_py, py::arg("range_image"),
        py::arg("config") = py::none(), py::kw_only(), py::arg("threads") = 1,
        "Organized cloud (H, W, 3) (NaN/zero = hole) -> dict of H/V lines, planes, cluster directions, stats. "
        "`config`: feature settings by dotted name over the defaults (see feature_config); `threads`: the line "
        "fit's (the same features).");
  m.def("feature_config",
        []() { return py_settings::to_dict(line_odom::feature_settings(), line_odom::FeatureConfig{}); },
        "The feature settings (lines.*, normals.*, planes.*) by dotted name, with their defaults.");
  m.def("sensor_presets", &line_odom::sensor_preset_names, "Names accepted by organize_points(sensor=...).");
}
