// Bindings of the motion estimation (hybrid RANSAC and refinement, paper §6.3).
#include <pybind11/eigen.h>
#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <string>
#include <vector>

#include "bindings/module.hpp"
#include "bindings/settings.hpp"
#include "bindings/types.hpp"
#include "odometry/engine_settings.hpp"
#include "registration/motion_estimation.hpp"

namespace py = pybind11;

namespace motion_bindings {

using py_types::mask_array;
using py_types::matrix_array;

// Row count of an (N, cols...) array argument; ValueError naming it and the expected shape otherwise.
py::ssize_t leading_dim(const char* name, py::handle obj, const std::vector<py::ssize_t>& tail, const char* shape) {
  py::array arr = py::array::ensure(obj);
  const std::string expected = std::string("estimate_motion: ") + name + " must be a real array of shape " + shape;
  if (!arr) throw py::value_error(expected);
  if (arr.ndim() == 1 && arr.shape(0) == 0) return 0;
  std::vector<py::ssize_t> actual(arr.shape(), arr.shape() + arr.ndim());
  if (arr.ndim() != static_cast<py::ssize_t>(tail.size()) + 1 ||
      !std::equal(tail.begin(), tail.end(), actual.begin() + 1))
    throw py::value_error(expected + ", got shape " + py_types::shape_text(actual));
  return arr.shape(0);
}

py::array_t<double, py::array::c_style> rows(const char* name, py::handle obj, py::ssize_t n,
                                             std::vector<py::ssize_t> tail) {
  py::array arr = py::array::ensure(obj);
  if (n == 0 && arr && arr.size() == 0 && arr.ndim() == 1) return py::array_t<double, py::array::c_style>();
  tail.insert(tail.begin(), n);
  return py_types::as_float_array("estimate_motion", name, obj, tail);
}

const char* solver_name(int s) {
  static const char* kNames[3] = {"7L", "3L1P", "1L2P"};
  return s >= 0 && s < 3 ? kNames[s] : nullptr;
}

py::dict per_solver(const std::array<int, 3>& counts) {
  py::dict d;
  for (int s = 0; s < 3; ++s) d[solver_name(s)] = counts[s];
  return d;
}

py::tuple estimate_motion(py::handle lines_a, py::handle lines_b, py::handle planes_a, py::handle planes_b,
                          py::handle segments_a, py::handle segments_b, py::handle weights, py::handle clusters,
                          py::handle init, const py::dict& options) {
  const py::ssize_t n = leading_dim("lines_a", lines_a, {6}, "(N, 6)");
  const auto la = rows("lines_a", lines_a, n, {6});
  const auto lb = rows("lines_b", lines_b, n, {6});
  const py::ssize_t m = planes_a.is_none() ? 0 : leading_dim("planes_a", planes_a, {4}, "(M, 4)");
  const auto pa = planes_a.is_none() ? py::array_t<double, py::array::c_style>() : rows("planes_a", planes_a, m, {4});
  py::array_t<double, py::array::c_style> pb;
  if (planes_b.is_none()) {
    if (m != 0) throw py::value_error("estimate_motion: planes_b must be a real array of shape (M, 4) like planes_a");
  } else {
    pb = rows("planes_b", planes_b, m, {4});
  }
  if (segments_a.is_none() != segments_b.is_none())
    throw py::value_error("estimate_motion: segments_a and segments_b must be given together, each of shape (N, 2, 3)");

  line_odom::Correspondences data;
  data.lines_a.resize(n);
  data.lines_b.resize(n);
  for (py::ssize_t i = 0; i < n; ++i) {
    data.lines_a[i] = py_types::line_at(la.data() + 6 * i);
    data.lines_b[i] = py_types::line_at(lb.data() + 6 * i);
  }
  for (py::ssize_t j = 0; j < m; ++j) {
    data.planes_a.push_back(py_types::plane_at(pa.data() + 4 * j));
    data.planes_b.push_back(py_types::plane_at(pb.data() + 4 * j));
  }
  if (!segments_a.is_none()) {
    const auto sa = rows("segments_a", segments_a, n, {2, 3});
    const auto sb = rows("segments_b", segments_b, n, {2, 3});
    data.segments_a.resize(n);
    data.segments_b.resize(n);
    for (py::ssize_t i = 0; i < n; ++i) {
      data.segments_a[i] = py_types::segment_at(sa.data() + 6 * i);
      data.segments_b[i] = py_types::segment_at(sb.data() + 6 * i);
    }
  }
  if (!weights.is_none()) {
    const auto w = rows("weights", weights, n, {});
    data.weights.assign(w.data(), w.data() + n);
    for (double x : data.weights)
      if (x < 0.0) throw py::value_error("estimate_motion: weights must be >= 0");
  }
  if (!clusters.is_none()) {
    const std::string expected = "estimate_motion: clusters must be an integer array of shape (" + std::to_string(n) +
                                 ",) with values -1, 0, 1 or 2";
    py::array arr = py::array::ensure(clusters);
    if (!arr || (arr.dtype().kind() != 'i' && arr.dtype().kind() != 'u') || arr.ndim() != 1 || arr.shape(0) != n)
      throw py::value_error(expected);
    const auto c = py::array_t<long long, py::array::c_style | py::array::forcecast>::ensure(arr);
    data.clusters.resize(n);
    for (py::ssize_t i = 0; i < n; ++i) {
      if (c.data()[i] < -1 || c.data()[i] > 2) throw py::value_error(expected);
      data.clusters[i] = static_cast<int>(c.data()[i]);
    }
  }
  const line_odom::RigidTransform init_ =
      init.is_none() ? line_odom::RigidTransform::identity() : py_types::pose_from("estimate_motion", "init", init);
  const line_odom::MotionOptions options_ =
      py_settings::from_dict(line_odom::motion_settings(), options, "estimate_motion: ");

  line_odom::RigidTransform T;
  line_odom::MotionStats stats;
  {
    py::gil_scoped_release release;
    line_odom::estimate_motion(data, init_, options_, &T, &stats);
  }
  py::dict s;
  s["success"] = stats.success;
  s["inliers"] = stats.inliers;
  s["inlier_weight"] = stats.inlier_weight;
  s["plane_inliers"] = stats.plane_inliers;
  s["iterations"] = stats.iterations;
  s["models"] = stats.models;
  s["solver_counts"] = per_solver(stats.solver_counts);
  s["solver_iterations"] = per_solver(stats.solver_iterations);
  s["best_solver"] = stats.best_solver >= 0 ? py::object(py::str(solver_name(stats.best_solver))) : py::object(py::none());
  s["covariance"] = matrix_array(stats.covariance);
  s["residual_rms"] = stats.residual_rms;
  s["degenerate"] = stats.degenerate;
  s["condition"] = stats.condition;
  s["perturbed_inlier_weight"] = stats.perturbed_inlier_weight;
  s["dropped_line_pairs"] = stats.dropped_line_pairs;
  s["dropped_plane_pairs"] = stats.dropped_plane_pairs;
  s["line_inlier_mask"] = mask_array(stats.line_inlier_mask);
  s["plane_inlier_mask"] = mask_array(stats.plane_inlier_mask);
  return py::make_tuple(matrix_array(T.matrix()), s);
}

}  // namespace motion_bindings

void line_odom_bindings::register_registration(py::module_& m) {
  m.def("estimate_motion", &motion_bindings::estimate_motion, py::arg("lines_a"), py::arg("lines_b"),
        py::arg("planes_a"), py::arg("planes_b"), py::kw_only(), py::arg("segments_a") = py::none(),
        py::arg("segments_b") = py::none(), py::arg("weights") = py::none(), py::arg("clusters") = py::none(),
        py::arg("init") = py::none(), py::arg("options") = py::dict(),
        "Hybrid RANSAC over {7L, 3L1P, 1L2P} on candidate line intersections (row i of lines_a (N,6) with row i\n"
        "of lines_b) and plane pairs (M,4), then robust refinement on all inliers (paper 6.3).\n"
        "Returns (T_ab (4,4), stats dict); T_ab = init (identity) with stats['success'] False when nothing is found.\n"
        "options: see estimate_motion_options().");
  m.def("estimate_motion_options", []() { return py_settings::schema_list(line_odom::motion_settings().schema()); },
        "The schema of estimate_motion's options (odometry/engine_settings.cpp), as settings_schema().");
}
