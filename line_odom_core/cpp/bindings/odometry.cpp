// Bindings of the odometry pipeline: Odometry, FrameResult, the settings, the rotation conversions of the Python side.
#include <pybind11/eigen.h>
#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

#include <cstdint>
#include <memory>
#include <optional>
#include <stdexcept>
#include <string>
#include <vector>

#include "bindings/module.hpp"
#include "bindings/settings.hpp"
#include "bindings/types.hpp"
#include "odometry/engine_settings.hpp"
#include "odometry/odometry.hpp"
#include "scan/sensor_fit.hpp"

namespace py = pybind11;

namespace odometry_bindings {

py::dict stats_dict(const line_odom::FrameStats& s) {
  py::dict ms;
  ms["organize"] = s.ms.organize;
  ms["deskew"] = s.ms.deskew;
  ms["downsample"] = s.ms.downsample;
  ms["features"] = s.ms.features;
  ms["lines"] = s.ms.lines;
  ms["normals"] = s.ms.normals;
  ms["planes"] = s.ms.planes;
  ms["candidates"] = s.ms.candidates;
  ms["ransac"] = s.ms.ransac;
  ms["points"] = s.ms.points;
  ms["validation"] = s.ms.validation;
  ms["total"] = s.ms.total;
  py::dict d;
  d["solver"] = line_odom::solver_name(s.solver);
  d["points"] = s.points;
  d["h_lines"] = s.h_lines;
  d["v_lines"] = s.v_lines;
  d["fit_step"] = s.fit_step;
  d["line_step"] = s.line_step;
  d["registered_lines"] = s.registered_lines;
  d["planes"] = s.planes;
  d["candidates"] = s.candidates;
  d["plane_candidates"] = s.plane_candidates;
  d["inliers"] = s.inliers;
  d["plane_inliers"] = s.plane_inliers;
  d["inlier_weight"] = s.inlier_weight;
  d["residual_rms"] = s.residual_rms;
  d["iterations"] = s.iterations;
  d["passes"] = s.passes;
  d["registered"] = s.registered;
  d["degenerate"] = s.degenerate;
  d["held_directions"] = s.held_directions;
  d["persistence"] = py::make_tuple(s.persistence(0), s.persistence(1), s.persistence(2), s.persistence(3),
                                    s.persistence(4), s.persistence(5));
  d["prediction"] = s.prediction;
  d["failure"] = s.failure;
  d["unmeasured_directions"] = s.unmeasured_directions;
  d["recovered"] = s.recovered;
  d["turn_searched"] = s.turn_searched;
  d["turn_recovered"] = s.turn_recovered;
  d["window_scans"] = s.window_scans;
  d["deskewed"] = s.deskewed;
  d["previous_deskewed_again"] = s.previous_deskewed_again;
  d["deskewed_again"] = s.deskewed_again;
  d["points_refined"] = s.points_refined;
  d["point_matches"] = s.point_matches;
  d["observability"] = py::make_tuple(s.observability(0), s.observability(1), s.observability(2), s.observability(3),
                                      s.observability(4), s.observability(5));
  d["unobserved"] = s.unobserved;
  d["points_aligned"] = s.points_aligned;
  d["point_map_matches"] = s.point_map_matches;
  d["map_entry"] = s.map_entry;
  d["ms"] = ms;
  return d;
}

// Values from one point to the next of (N, k >= 3) or (H, W, k >= 3) float32/float64 points when the engine can read
// them in place: each point's x, y, z adjacent and aligned, points a whole number of values apart (a view such as
// cloud[:, :3] of an (N, 4) array or a PointCloud2 buffer), rows of an organized array one after another; else 0.
std::size_t in_place_stride(const py::array& xyz) {
  const int ndim = static_cast<int>(xyz.ndim());
  if (ndim < 2 || xyz.shape(ndim - 1) < 3) return 0;
  if (xyz.size() == 0) return static_cast<std::size_t>(xyz.shape(ndim - 1));
  const py::ssize_t item = xyz.itemsize();
  const py::ssize_t step = xyz.shape(ndim - 2) > 1 ? xyz.strides(ndim - 2) : xyz.shape(ndim - 1) * item;
  const bool rows_follow = ndim < 3 || xyz.shape(0) <= 1 || xyz.strides(0) == xyz.shape(1) * step;
  const bool aligned = reinterpret_cast<std::uintptr_t>(xyz.data()) % static_cast<std::uintptr_t>(item) == 0;
  if (!aligned || xyz.strides(ndim - 1) != item || step % item != 0 || step / item < 3 || !rows_follow) return 0;
  return static_cast<std::size_t>(step / item);
}

// in_place_stride of points that must be readable in place (ValueError naming xyz otherwise).
std::size_t point_stride(const py::array& xyz, int ndim, const char* what) {
  if (xyz.ndim() != ndim || xyz.shape(ndim - 1) < 3) throw py::value_error(std::string("xyz: expected ") + what);
  if (!py::isinstance<py::array_t<float>>(xyz) && !py::isinstance<py::array_t<double>>(xyz))
    throw py::value_error("xyz: expected float32 or float64 values");
  const std::size_t stride = in_place_stride(xyz);
  if (stride == 0)
    throw py::value_error("xyz: expected each point's x, y, z adjacent in memory and aligned (np.ascontiguousarray)");
  return stride;
}

const std::int32_t* ring_pointer(const std::optional<py::array_t<std::int32_t>>& ring, std::size_t n) {
  if (!ring) return nullptr;
  if (ring->ndim() != 1 || static_cast<std::size_t>(ring->shape(0)) != n)
    throw py::value_error("ring: expected one int32 beam index per point");
  return ring->data();
}

std::unique_ptr<line_odom::Odometry> make_odometry(const py::dict& settings) {
  const line_odom::OdometryConfig config = py_settings::from_dict(line_odom::odometry_settings(), settings);
  try {
    return std::make_unique<line_odom::Odometry>(config);
  } catch (const std::invalid_argument& e) {
    throw py::value_error(e.what());
  }
}

// The optional motion guess T_prev_curr (4x4) as the engine's transform (its checks are the engine's).
std::optional<line_odom::RigidTransform> guess_transform(const std::optional<line_odom::Mat4>& guess) {
  if (!guess) return std::nullopt;
  if (guess->row(3) != Eigen::RowVector4d(0, 0, 0, 1))
    throw py::value_error("guess: expected a 4x4 homogeneous transform with last row 0 0 0 1");
  return line_odom::RigidTransform::from_matrix(*guess);
}

// Per-point times (s from the stamp), one per point of `shape`; the engine checks that they are finite.
using TimeArray = py::array_t<double, py::array::c_style | py::array::forcecast>;
const double* time_pointer(const std::optional<TimeArray>& time, const std::vector<py::ssize_t>& shape,
                           const char* what) {
  if (!time) return nullptr;
  bool same = time->ndim() == static_cast<py::ssize_t>(shape.size());
  for (std::size_t k = 0; same && k < shape.size(); ++k) same = time->shape(k) == shape[k];
  if (!same) throw py::value_error(std::string("time: expected ") + what + ", got shape " + py_types::shape_text(
      std::vector<py::ssize_t>(time->shape(), time->shape() + time->ndim())));
  return time->data();
}

// An (N, >=3) float32 / float64 cloud read in place, with its ring field; checked (xyz, then ring) when made.
struct CloudView {
  CloudView(const py::array& xyz, const std::optional<py::array_t<std::int32_t>>& ring)
      : stride(point_stride(xyz, 2, "an (N, 3) array of points")),
        count(static_cast<std::size_t>(xyz.shape(0))),
        ring(ring_pointer(ring, count)),
        is_float(py::isinstance<py::array_t<float>>(xyz)),
        data(xyz.data()) {}
  std::size_t stride;
  std::size_t count;
  const std::int32_t* ring;
  bool is_float;
  const void* data;
};

// f(points, count, stride, ring) on the cloud without the GIL; the engine's std::invalid_argument becomes ValueError.
template <typename F>
auto on_cloud(const CloudView& cloud, F&& f) {
  py::gil_scoped_release release;
  try {
    return cloud.is_float ? f(static_cast<const float*>(cloud.data), cloud.count, cloud.stride, cloud.ring)
                          : f(static_cast<const double*>(cloud.data), cloud.count, cloud.stride, cloud.ring);
  } catch (const std::invalid_argument& e) {
    throw py::value_error(e.what());
  }
}

line_odom::FrameResult register_points(line_odom::Odometry& o, const py::array& xyz, double stamp,
                                       const std::optional<py::array_t<std::int32_t>>& ring,
                                       const std::optional<line_odom::Mat4>& guess,
                                       const std::optional<line_odom::Mat3>& rotation_guess,
                                       const std::optional<TimeArray>& time,
                                       const std::optional<line_odom::Vec3>& sweep_rate) {
  const CloudView cloud(xyz, ring);
  const double* time_ptr = time_pointer(time, {xyz.shape(0)}, "one time (s from the stamp) per point, shape (N,)");
  const std::optional<line_odom::RigidTransform> T = guess_transform(guess);
  const line_odom::RigidTransform* guess_ptr = T ? &*T : nullptr;
  const line_odom::Mat3* rotation_ptr = rotation_guess ? &*rotation_guess : nullptr;
  const line_odom::Vec3* rate_ptr = sweep_rate ? &*sweep_rate : nullptr;
  return on_cloud(cloud, [&](const auto* data, auto n, auto stride, auto rings) {
    return o.register_points(data, n, stride, rings, stamp, guess_ptr, rotation_ptr, time_ptr, rate_ptr);
  });
}

line_odom::FrameResult register_organized(line_odom::Odometry& o, const py::array& xyz, double stamp,
                                          const std::optional<line_odom::Mat4>& guess,
                                          const std::optional<line_odom::Mat3>& rotation_guess,
                                          const std::optional<TimeArray>& time,
                                          const std::optional<line_odom::Vec3>& sweep_rate) {
  const std::size_t stride = point_stride(xyz, 3, "an (H, W, 3) organized point array");
  const int rows = static_cast<int>(xyz.shape(0)), cols = static_cast<int>(xyz.shape(1));
  const double* time_ptr =
      time_pointer(time, {xyz.shape(0), xyz.shape(1)}, "one time (s from the stamp) per point, shape (H, W)");
  const std::optional<line_odom::RigidTransform> T = guess_transform(guess);
  const line_odom::RigidTransform* guess_ptr = T ? &*T : nullptr;
  const line_odom::Mat3* rotation_ptr = rotation_guess ? &*rotation_guess : nullptr;
  const line_odom::Vec3* rate_ptr = sweep_rate ? &*sweep_rate : nullptr;
  const bool is_float = py::isinstance<py::array_t<float>>(xyz);
  const void* data = xyz.data();
  py::gil_scoped_release release;
  try {
    return is_float ? o.register_organized(static_cast<const float*>(data), rows, cols, stride, stamp, guess_ptr,
                                           rotation_ptr, time_ptr, rate_ptr)
                    : o.register_organized(static_cast<const double*>(data), rows, cols, stride, stamp, guess_ptr,
                                           rotation_ptr, time_ptr, rate_ptr);
  } catch (const std::invalid_argument& e) {
    throw py::value_error(e.what());
  }
}

line_odom::FrameResult register_depth(line_odom::Odometry& o,
                                      const py::array_t<float, py::array::c_style | py::array::forcecast>& depth,
                                      const line_odom::Mat3& K, double stamp,
                                      const std::optional<line_odom::Mat4>& guess,
                                      const std::optional<line_odom::Mat3>& rotation_guess) {
  if (depth.ndim() != 2) throw py::value_error("depth: expected an (H, W) depth image in metres");
  const int rows = static_cast<int>(depth.shape(0)), cols = static_cast<int>(depth.shape(1));
  const std::optional<line_odom::RigidTransform> T = guess_transform(guess);
  const line_odom::RigidTransform* guess_ptr = T ? &*T : nullptr;
  const line_odom::Mat3* rotation_ptr = rotation_guess ? &*rotation_guess : nullptr;
  const float* data = depth.data();
  py::gil_scoped_release release;
  try {
    return o.register_depth(data, rows, cols, K, stamp, guess_ptr, rotation_ptr);
  } catch (const std::invalid_argument& e) {
    throw py::value_error(e.what());
  }
}

// Points as an (n, 3) array.
py::array_t<double> points_array(const std::vector<line_odom::Vec3>& points) {
  py::array_t<double> out({static_cast<py::ssize_t>(points.size()), static_cast<py::ssize_t>(3)});
  auto w = out.mutable_unchecked<2>();
  for (py::ssize_t i = 0; i < static_cast<py::ssize_t>(points.size()); ++i)
    for (py::ssize_t k = 0; k < 3; ++k) w(i, k) = points[i][k];
  return out;
}

py::array_t<double> downsampled_points(const line_odom::Odometry& o, const py::array& xyz,
                                       const std::optional<py::array_t<std::int32_t>>& ring) {
  return points_array(on_cloud(CloudView(xyz, ring), [&](const auto* data, auto n, auto stride, auto rings) {
    return o.downsampled_points(data, n, stride, rings);
  }));
}

py::dict sensor_fit(const line_odom::Odometry& o, const py::array& xyz,
                    const std::optional<py::array_t<std::int32_t>>& ring) {
  const line_odom::SensorFit fit =
      on_cloud(CloudView(xyz, ring), [&](const auto* data, auto n, auto stride, auto rings) {
        return line_odom::fit_to_sensor(data, n, stride, rings, o.sensor_model(), o.config().sensor.limits);
      });
  py::dict d;
  d["model"] = fit.model;
  d["rows"] = fit.rows;
  d["max_elevation_deg"] = fit.max_elevation_deg;
  d["min_elevation_deg"] = fit.min_elevation_deg;
  d["row_method"] = fit.row_method;
  d["points"] = fit.points;
  d["outside_rows"] = fit.outside_rows;
  d["filled_rows"] = fit.filled_rows;
  d["band_rows"] = fit.band_rows;
  d["ring_rows"] = fit.ring_rows;
  d["cloud_high_deg"] = fit.cloud_high_deg;
  d["cloud_low_deg"] = fit.cloud_low_deg;
  return d;
}

// The segments (n, 2, 3) of a scan's lines: their two ends, in the scan's sensor frame.
py::array_t<double> segments_array(const std::vector<line_odom::LineFeature>& lines) {
  py::array_t<double> out({static_cast<py::ssize_t>(lines.size()), py::ssize_t(2), py::ssize_t(3)});
  auto S = out.mutable_unchecked<3>();
  for (py::ssize_t i = 0; i < S.shape(0); ++i)
    for (int k = 0; k < 3; ++k) S(i, 0, k) = lines[i].segment.a(k), S(i, 1, k) = lines[i].segment.b(k);
  return out;
}

}  // namespace odometry_bindings

void line_odom_bindings::register_odometry(py::module_& m) {
  using line_odom::FrameResult;
  using line_odom::Odometry;
  namespace ob = odometry_bindings;
  py::class_<FrameResult>(m, "FrameResult", "One registered frame (see line_odom_core.FrameResult).")
      .def_readonly("stamp", &FrameResult::stamp)
      .def_property_readonly("pose", [](const FrameResult& r) -> line_odom::Mat4 { return r.pose.matrix(); })
      .def_property_readonly("delta", [](const FrameResult& r) -> line_odom::Mat4 { return r.delta.matrix(); })
      .def_readonly("covariance", &FrameResult::covariance)
      .def_property_readonly("stats", [](const FrameResult& r) { return ob::stats_dict(r.stats); });
  py::class_<Odometry>(m, "Odometry", "Stateful frame-to-frame odometry; settings: dict of dotted names.")
      .def(py::init(&ob::make_odometry), py::arg("settings"))
      .def("register_points", &ob::register_points, py::arg("xyz"), py::arg("stamp"), py::arg("ring") = py::none(),
           py::arg("guess") = py::none(), py::arg("rotation_guess") = py::none(), py::arg("time") = py::none(),
           py::arg("sweep_rate") = py::none())
      .def("register_organized", &ob::register_organized, py::arg("xyz"), py::arg("stamp"),
           py::arg("guess") = py::none(), py::arg("rotation_guess") = py::none(), py::arg("time") = py::none(),
           py::arg("sweep_rate") = py::none())
      .def("register_depth", &ob::register_depth, py::arg("depth"), py::arg("K"), py::arg("stamp"),
           py::arg("guess") = py::none(), py::arg("rotation_guess") = py::none())
      .def("downsampled_points", &ob::downsampled_points, py::arg("xyz"), py::arg("ring") = py::none())
      .def("sensor_fit", &ob::sensor_fit, py::arg("xyz"), py::arg("ring") = py::none())
      .def("reset",
           [](Odometry& o, const line_odom::Mat4& pose) { o.reset(line_odom::RigidTransform::from_matrix(pose)); },
           py::arg("pose"))
      .def("pose", [](const Odometry& o) -> line_odom::Mat4 { return o.pose().matrix(); })
      .def("frames", &Odometry::frames)
      .def(
          "last_lines",
          [](const Odometry& o) {
            return py::make_tuple(ob::segments_array(o.last_features().h_lines),
                                  ob::segments_array(o.last_features().v_lines));
          },
          "The H-lines and V-lines the last scan was registered with, as segments (n, 2, 3) in its sensor frame "
          "(deskewed, as registered).")
      .def("keep_points", &Odometry::keep_points, py::arg("keep"),
           "While on, each frame keeps the points it was registered with, for last_points() (off by default).")
      .def(
          "last_points", [](const Odometry& o) { return ob::points_array(o.last_points()); },
          "The points the last frame was registered with (after organizing, downsampling and deskewing), (n, 3) in "
          "its sensor frame; empty unless keep_points(True) was set before it.")
      .def("settings", [](const Odometry& o) { return py_settings::to_dict(line_odom::odometry_settings(), o.config()); });
  m.def("reads_in_place", [](const py::array& xyz) { return ob::in_place_stride(xyz) > 0; }, py::arg("xyz"),
        "Whether register_points / register_organized read these points without a copy.");
  // Per-frame rotation conversions of the Python side (result twist, ROS messages): Eigen's, because scipy's
  // Rotation is slow per call right after a registration has flushed the caches.
  m.def("rotation_vector",
        [](const line_odom::Mat3& R) -> line_odom::Vec3 {
          const Eigen::AngleAxisd aa(Eigen::Quaterniond(R).normalized());
          return aa.angle() * aa.axis();
        },
        py::arg("R"), "Rotation vector (axis * angle, angle in [0, pi]) of a 3x3 rotation matrix.");
  m.def("quaternion_xyzw",
        [](const line_odom::Mat3& R) -> Eigen::Vector4d {
          Eigen::Quaterniond q(R);
          q.normalize();
          if (q.w() < 0.0) q.coeffs() = -q.coeffs();
          return q.coeffs();  // Eigen stores x, y, z, w
        },
        py::arg("R"), "Unit quaternion [x, y, z, w] (w >= 0) of a 3x3 rotation matrix.");
  m.def("settings_schema", []() { return py_settings::schema_list(line_odom::odometry_settings().schema()); },
        "The engine settings' schema (odometry/engine_settings.cpp): one dict per setting with its name, type, "
        "default, range or choices, unit, description and whether a running node may change it.");
  m.def(
      "check_setting",
      [](const py::str& name, const py::handle& value) {
        line_odom::OdometryConfig config;
        py_settings::apply(line_odom::odometry_settings(), &config, name, value);
        return py_settings::to_python(line_odom::odometry_settings().row(name).get(config));
      },
      py::arg("name"), py::arg("value"),
      "The value as the engine setting `name` takes it (an int for a float setting becomes a float, a choice its "
      "spelling in the schema); ValueError naming the setting and what it accepts otherwise.");
}
