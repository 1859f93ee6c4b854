// Bindings of the motion estimation (hybrid RANSAC and refinement, paper §6.3) and of the generic RANSAC's test hooks.
#include <pybind11/eigen.h>
#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <string>
#include <vector>

#include "bindings/module.hpp"
#include "bindings/settings.hpp"
#include "bindings/ransac_examples.hpp"
#include "bindings/types.hpp"
#include "odometry/engine_settings.hpp"
#include "registration/motion_estimation.hpp"

namespace py = pybind11;

namespace motion_bindings {

using py_types::mask_array;
using py_types::matrix_array;
using py_types::vector_array;

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

line_odom::RansacOptions ransac_options(int max_iterations, int min_iterations, double confidence, std::uint64_t seed,
                                        bool local_optimisation) {
  line_odom::RansacOptions o;
  o.max_iterations = max_iterations;
  o.min_iterations = min_iterations;
  o.confidence = confidence;
  o.seed = seed;
  o.local_optimisation = local_optimisation;
  return o;
}

py::dict ransac_stats(bool ok, const line_odom::RansacStats& st) {
  py::dict d;
  d["success"] = ok;
  d["iterations"] = st.iterations;
  d["models"] = st.models;
  d["refinements"] = st.refinements;
  d["best_solver"] = st.best_solver;
  d["best_iteration"] = st.best_iteration;
  d["score"] = ok ? st.best_score.value : 0.0;
  d["inliers"] = st.best_score.inliers;
  d["inlier_fraction"] = py::make_tuple(st.best_score.inlier_fraction[0], st.best_score.inlier_fraction[1]);
  d["solver_iterations"] = py::make_tuple(st.solver_iterations[0], st.solver_iterations[1]);
  d["solver_wins"] = py::make_tuple(st.solver_wins[0], st.solver_wins[1]);
  return d;
}

std::vector<Eigen::Vector2d> points_2d(const char* fn, const char* name, py::handle obj) {
  py::array arr = py::array::ensure(obj);
  if (!arr || arr.ndim() != 2 || arr.shape(1) != 2)
    throw py::value_error(std::string(fn) + ": " + name + " must be a real array of shape (N, 2)");
  const auto a = py_types::as_float_array(fn, name, obj, {arr.shape(0), 2});
  std::vector<Eigen::Vector2d> out(arr.shape(0));
  for (size_t i = 0; i < out.size(); ++i) out[i] = Eigen::Vector2d(a.data()[2 * i], a.data()[2 * i + 1]);
  return out;
}

std::vector<double> values_1d(const char* fn, const char* name, py::handle obj, py::ssize_t n) {
  const auto a = py_types::as_float_array(fn, name, obj, {n});
  return std::vector<double>(a.data(), a.data() + n);
}

py::tuple fit_line_2d(py::handle points, double threshold, py::handle weights, int max_iterations,
                      int min_iterations, double confidence, std::uint64_t seed, bool local_optimisation) {
  const auto p = points_2d("_ransac_fit_line_2d", "points", points);
  const auto w = weights.is_none() ? std::vector<double>() : values_1d("_ransac_fit_line_2d", "weights", weights,
                                                                       static_cast<py::ssize_t>(p.size()));
  Eigen::Vector3d line = Eigen::Vector3d::Zero();
  line_odom::RansacStats st;
  bool ok;
  {
    py::gil_scoped_release release;
    ok = line_odom::ransac_fit_line_2d(p, w, threshold,
                                       ransac_options(max_iterations, min_iterations, confidence, seed, local_optimisation),
                                       &line, &st);
  }
  return py::make_tuple(vector_array(line), ransac_stats(ok, st));
}

py::tuple translation_2d(py::handle points_a, py::handle points_b, py::handle directions, py::handle projections,
                         double threshold, int max_iterations, int min_iterations, double confidence,
                         std::uint64_t seed) {
  const auto pa = points_2d("_ransac_translation_2d", "points_a", points_a);
  const auto pb = points_2d("_ransac_translation_2d", "points_b", points_b);
  if (pa.size() != pb.size()) throw py::value_error("_ransac_translation_2d: points_b must have the shape of points_a");
  const auto u = points_2d("_ransac_translation_2d", "directions", directions);
  const auto o = values_1d("_ransac_translation_2d", "projections", projections, static_cast<py::ssize_t>(u.size()));
  Eigen::Vector2d t = Eigen::Vector2d::Zero();
  line_odom::RansacStats st;
  bool ok;
  {
    py::gil_scoped_release release;
    ok = line_odom::ransac_translation_2d(pa, pb, u, o, threshold,
                                          ransac_options(max_iterations, min_iterations, confidence, seed, false), &t,
                                          &st);
  }
  return py::make_tuple(vector_array(t), ransac_stats(ok, st));
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
  m.def("_ransac_fit_line_2d", &motion_bindings::fit_line_2d, py::arg("points"), py::arg("threshold"),
        py::kw_only(), py::arg("weights") = py::none(), py::arg("max_iterations") = 1000,
        py::arg("min_iterations") = 0, py::arg("confidence") = 0.999, py::arg("seed") = 0,
        py::arg("local_optimisation") = true,
        "Test hook: the generic RANSAC (ransac.hpp) fitting a 2D line (a, b, c), a^2 + b^2 = 1, to points (N,2).");
  m.def("_ransac_translation_2d", &motion_bindings::translation_2d, py::arg("points_a"), py::arg("points_b"),
        py::arg("directions"), py::arg("projections"), py::arg("threshold"), py::kw_only(),
        py::arg("max_iterations") = 1000, py::arg("min_iterations") = 0, py::arg("confidence") = 0.999,
        py::arg("seed") = 0,
        "Test hook: the hybrid RANSAC (ransac.hpp) estimating a 2D translation from point pairs (solver 0, one\n"
        "pair) and scalar projections u.t = o (solver 1, two projections).");
}
