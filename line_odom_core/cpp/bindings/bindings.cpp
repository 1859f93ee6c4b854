// The one file that knows about Python: numpy in, numpy out, GIL released on every heavy call.
#include <pybind11/eigen.h>
#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

#include <array>
#include <cmath>
#include <cstdint>
#include <string>
#include <vector>

#include "bindings/solver_benchmark.hpp"
#include "solvers/solve_1l2p.hpp"
#include "solvers/solve_3l1p.hpp"
#include "solvers/solve_7l.hpp"

namespace py = pybind11;

#ifndef LINE_ODOM_VERSION
#define LINE_ODOM_VERSION "0.0.0"
#endif
#ifndef LINE_ODOM_COMPILE_FLAGS
#define LINE_ODOM_COMPILE_FLAGS ""
#endif

namespace {

py::dict build_info() {
  py::dict info;
#if defined(__clang__)
  info["compiler"] = std::string("clang ") + __clang_version__;
#elif defined(__GNUC__)
  info["compiler"] = std::string("gcc ") + __VERSION__;
#else
  info["compiler"] = "unknown";
#endif
  info["flags"] = LINE_ODOM_COMPILE_FLAGS;
  info["cxx_standard"] = static_cast<long>(__cplusplus);
  info["eigen_version"] = std::to_string(EIGEN_WORLD_VERSION) + "." + std::to_string(EIGEN_MAJOR_VERSION) + "." +
                          std::to_string(EIGEN_MINOR_VERSION);
  info["pybind11_version"] = std::to_string(PYBIND11_VERSION_MAJOR) + "." + std::to_string(PYBIND11_VERSION_MINOR) +
                             "." + std::to_string(PYBIND11_VERSION_PATCH);
#ifdef NDEBUG
  info["ndebug"] = true;
#else
  info["ndebug"] = false;
#endif
  return info;
}

}  // namespace

// ---- solver bindings helpers (solvers) ----
namespace solver_bindings {

std::string shape_text(const std::vector<py::ssize_t>& shape) {
  std::string text = "(";
  for (size_t i = 0; i < shape.size(); ++i) {
    text += std::to_string(shape[i]);
    if (shape.size() == 1 || i + 1 < shape.size()) text += shape.size() == 1 ? "," : ", ";
  }
  return text + ")";
}

// A C-contiguous float64 copy of `obj` with exactly `shape`; ValueError naming the argument otherwise
// (non-numeric or complex dtype, wrong shape, NaN or infinity).
py::array_t<double, py::array::c_style> as_float_array(const char* function, const char* name, py::handle obj,
                                                       const std::vector<py::ssize_t>& shape) {
  const std::string expected = std::string(function) + ": " + name + " must be a real array of shape " +
                               shape_text(shape);
  py::array arr = py::array::ensure(obj);
  if (!arr) throw py::value_error(expected + ", got " + std::string(py::str(py::type::of(obj).attr("__name__"))));
  const char kind = arr.dtype().kind();
  if (kind != 'f' && kind != 'i' && kind != 'u')
    throw py::value_error(expected + ", got dtype " + std::string(py::str(arr.dtype())));
  std::vector<py::ssize_t> actual(arr.shape(), arr.shape() + arr.ndim());
  if (actual != shape) throw py::value_error(expected + ", got shape " + solver_bindings::shape_text(actual));
  auto out = py::array_t<double, py::array::c_style | py::array::forcecast>::ensure(arr);
  if (!out) throw py::value_error(expected);
  const double* data = out.data();
  for (py::ssize_t i = 0; i < out.size(); ++i)
    if (!std::isfinite(data[i])) throw py::value_error(expected + " of finite values, got NaN or infinity");
  return out;
}

line_odom::PluckerLine line_at(const double* v) {
  return {line_odom::Vec3(v[0], v[1], v[2]), line_odom::Vec3(v[3], v[4], v[5])};
}
line_odom::Plane plane_at(const double* v) { return {line_odom::Vec3(v[0], v[1], v[2]), v[3]}; }
line_odom::Segment segment_at(const double* v) {
  return {line_odom::Vec3(v[0], v[1], v[2]), line_odom::Vec3(v[3], v[4], v[5])};
}

// A 4x4 rigid transform: rotation block orthonormal with det +1 (1e-6), last row (0, 0, 0, 1).
line_odom::RigidTransform pose_from(const char* function, const char* name, py::handle obj) {
  const auto arr = as_float_array(function, name, obj, {4, 4});
  const double* v = arr.data();
  line_odom::Mat4 T;
  for (int r = 0; r < 4; ++r)
    for (int c = 0; c < 4; ++c) T(r, c) = v[4 * r + c];
  const line_odom::RigidTransform pose = line_odom::RigidTransform::from_matrix(T);
  const bool last_row = T(3, 0) == 0.0 && T(3, 1) == 0.0 && T(3, 2) == 0.0 && T(3, 3) == 1.0;
  if (!last_row || (pose.R.transpose() * pose.R - line_odom::Mat3::Identity()).cwiseAbs().maxCoeff() > 1e-6 ||
      pose.R.determinant() <= 0.0)
    throw py::value_error(std::string(function) + ": " + name +
                          " must be a 4x4 rigid transform (rotation block in SO(3), last row 0 0 0 1)");
  return pose;
}

py::list pose_list(const line_odom::RigidTransform* poses, int count) {
  py::list out;
  for (int i = 0; i < count; ++i) {
    py::array_t<double> T({4, 4});
    auto view = T.mutable_unchecked<2>();
    const line_odom::Mat4 M = poses[i].matrix();
    for (int r = 0; r < 4; ++r)
      for (int c = 0; c < 4; ++c) view(r, c) = M(r, c);
    out.append(T);
  }
  return out;
}

line_odom::Solve7LMethod method_7l(const std::string& method) {
  if (method == "gauss_newton") return line_odom::Solve7LMethod::kGaussNewton;
  if (method == "alternating_projection") return line_odom::Solve7LMethod::kAlternatingProjection;
  throw py::value_error("solve_7l: method must be 'gauss_newton' or 'alternating_projection', got '" + method + "'");
}

py::list solve_1l2p(py::handle line_a, py::handle line_b, py::handle planes_a, py::handle planes_b,
                    double max_dihedral_difference) {
  const auto la = as_float_array("solve_1l2p", "line_a", line_a, {6});
  const auto lb = as_float_array("solve_1l2p", "line_b", line_b, {6});
  const auto pa = as_float_array("solve_1l2p", "planes_a", planes_a, {2, 4});
  const auto pb = as_float_array("solve_1l2p", "planes_b", planes_b, {2, 4});
  const std::array<line_odom::Plane, 2> planes_a_{plane_at(pa.data()), plane_at(pa.data() + 4)};
  const std::array<line_odom::Plane, 2> planes_b_{plane_at(pb.data()), plane_at(pb.data() + 4)};
  line_odom::RigidTransform solutions[line_odom::kMaxSolutions1L2P];
  int count;
  {
    py::gil_scoped_release release;
    count = line_odom::solve_1l2p(line_at(la.data()), line_at(lb.data()), planes_a_, planes_b_, solutions,
                                  max_dihedral_difference);
  }
  return pose_list(solutions, count);
}

py::list solve_3l1p(py::handle lines_a, py::handle lines_b, py::handle plane_a, py::handle plane_b) {
  const auto la = as_float_array("solve_3l1p", "lines_a", lines_a, {3, 6});
  const auto lb = as_float_array("solve_3l1p", "lines_b", lines_b, {3, 6});
  const auto pa = as_float_array("solve_3l1p", "plane_a", plane_a, {4});
  const auto pb = as_float_array("solve_3l1p", "plane_b", plane_b, {4});
  std::array<line_odom::PluckerLine, 3> lines_a_, lines_b_;
  for (int i = 0; i < 3; ++i) {
    lines_a_[i] = line_at(la.data() + 6 * i);
    lines_b_[i] = line_at(lb.data() + 6 * i);
  }
  line_odom::RigidTransform solutions[line_odom::kMaxSolutions3L1P];
  int count;
  {
    py::gil_scoped_release release;
    count = line_odom::solve_3l1p(lines_a_, lines_b_, plane_at(pa.data()), plane_at(pb.data()), solutions);
  }
  return pose_list(solutions, count);
}

py::list solve_7l(py::handle segments_a, py::handle segments_b, py::handle init, const std::string& method,
                  int max_iterations, double tolerance, double max_residual) {
  const auto sa = as_float_array("solve_7l", "segments_a", segments_a, {7, 2, 3});
  const auto sb = as_float_array("solve_7l", "segments_b", segments_b, {7, 2, 3});
  const line_odom::RigidTransform init_ =
      init.is_none() ? line_odom::RigidTransform::identity() : pose_from("solve_7l", "init", init);
  line_odom::Solve7LOptions options;
  options.method = method_7l(method);
  if (max_iterations < 1) throw py::value_error("solve_7l: max_iterations must be >= 1");
  if (!(tolerance > 0.0)) throw py::value_error("solve_7l: tolerance must be > 0");
  if (!(max_residual > 0.0)) throw py::value_error("solve_7l: max_residual must be > 0");
  options.max_iterations = max_iterations;
  options.tolerance = tolerance;
  options.max_residual = max_residual;
  std::array<line_odom::Segment, 7> segments_a_, segments_b_;
  for (int i = 0; i < 7; ++i) {
    segments_a_[i] = segment_at(sa.data() + 6 * i);
    segments_b_[i] = segment_at(sb.data() + 6 * i);
  }
  line_odom::RigidTransform solution;
  int count;
  {
    py::gil_scoped_release release;
    count = line_odom::solve_7l(segments_a_, segments_b_, init_, &solution, options);
  }
  return pose_list(&solution, count);
}

py::dict benchmark_solver(const std::string& solver, int instances, int repetitions, std::uint64_t seed,
                          const std::string& method, int max_iterations, double tolerance, double found_tolerance,
                          double guess_rotation_deg, double guess_translation, double max_translation,
                          double scene_radius, int chunk) {
  line_odom::SolverBenchmarkOptions o;
  o.chunk = chunk;
  o.solver = solver;
  o.instances = instances;
  o.repetitions = repetitions;
  o.seed = seed;
  o.solve_7l.method = method_7l(method);
  o.solve_7l.max_iterations = max_iterations;
  o.solve_7l.tolerance = tolerance;
  o.found_tolerance = found_tolerance;
  o.guess_rotation_deg = guess_rotation_deg;
  o.guess_translation = guess_translation;
  o.max_translation = max_translation;
  o.scene_radius = scene_radius;
  line_odom::SolverBenchmarkResult r;
  {
    py::gil_scoped_release release;
    r = line_odom::benchmark_solver(o);
  }
  py::dict d;
  d["solver"] = solver;
  d["method"] = solver == "7l" ? method : std::string();
  d["instances"] = r.instances;
  d["repetitions"] = r.repetitions;
  d["median_us"] = r.median_us;
  d["min_us"] = r.min_us;
  d["p90_us"] = r.p90_us;
  d["mean_us"] = r.mean_us;
  d["chunk"] = r.chunk;
  d["solutions_per_call"] = r.solutions_per_call;
  d["found_rate"] = r.found_rate;
  d["no_solution_rate"] = r.no_solution_rate;
  d["median_error"] = r.median_error;
  d["p99_error"] = r.p99_error;
  d["mean_iterations"] = r.mean_iterations;
  return d;
}

}  // namespace solver_bindings

// ---- motion estimation bindings helpers (ransac) ----
#include <algorithm>
#include <limits>

#include "bindings/ransac_examples.hpp"
#include "registration/motion_estimation.hpp"

namespace motion_bindings {

// Row count of an (N, cols...) array argument; ValueError naming it and the expected shape otherwise.
py::ssize_t leading_dim(const char* name, py::handle obj, const std::vector<py::ssize_t>& tail, const char* shape) {
  py::array arr = py::array::ensure(obj);
  const std::string expected = std::string("estimate_motion: ") + name + " must be a real array of shape " + shape;
  if (!arr) throw py::value_error(expected);
  if (arr.ndim() == 1 && arr.shape(0) == 0) return 0;
  std::vector<py::ssize_t> actual(arr.shape(), arr.shape() + arr.ndim());
  if (arr.ndim() != static_cast<py::ssize_t>(tail.size()) + 1 ||
      !std::equal(tail.begin(), tail.end(), actual.begin() + 1))
    throw py::value_error(expected + ", got shape " + solver_bindings::shape_text(actual));
  return arr.shape(0);
}

py::array_t<double, py::array::c_style> rows(const char* name, py::handle obj, py::ssize_t n,
                                             std::vector<py::ssize_t> tail) {
  py::array arr = py::array::ensure(obj);
  if (n == 0 && arr && arr.size() == 0 && arr.ndim() == 1) return py::array_t<double, py::array::c_style>();
  tail.insert(tail.begin(), n);
  return solver_bindings::as_float_array("estimate_motion", name, obj, tail);
}

[[noreturn]] void bad_option(const std::string& key, const std::string& expected, py::handle value) {
  throw py::value_error("estimate_motion: option '" + key + "' must be " + expected + ", got " +
                        std::string(py::repr(value)));
}

bool is_bool(py::handle v) {
  const std::string type = py::str(py::type::of(v).attr("__name__"));
  return py::isinstance<py::bool_>(v) || type == "bool_";
}

long long option_int(const std::string& key, py::handle v, long long min) {
  if (is_bool(v) || !PyIndex_Check(v.ptr())) bad_option(key, "an integer >= " + std::to_string(min), v);
  const long long x = py::int_(py::reinterpret_borrow<py::object>(v)).cast<long long>();
  if (x < min || x > std::numeric_limits<int>::max()) bad_option(key, "an integer >= " + std::to_string(min), v);
  return x;
}

double option_float(const std::string& key, py::handle v, double lo, double hi, bool lo_open, const char* text) {
  if (is_bool(v) || py::isinstance<py::str>(v) || !(PyIndex_Check(v.ptr()) || PyFloat_Check(v.ptr()) ||
                                                      py::hasattr(v, "__float__")))
    bad_option(key, text, v);
  const double x = py::float_(py::reinterpret_borrow<py::object>(v)).cast<double>();
  if (!std::isfinite(x) || x > hi || x < lo || (lo_open && x == lo)) bad_option(key, text, v);
  return x;
}

bool option_bool(const std::string& key, py::handle v) {
  if (!is_bool(v)) bad_option(key, "True or False", v);
  return py::bool_(py::reinterpret_borrow<py::object>(v)).cast<bool>();
}

std::string option_str(const std::string& key, py::handle v, const std::string& expected) {
  if (!py::isinstance<py::str>(v)) bad_option(key, expected, v);
  return v.cast<std::string>();
}

line_odom::MotionOptions motion_options(const py::dict& d) {
  line_odom::MotionOptions o;
  for (auto item : d) {
    if (!py::isinstance<py::str>(item.first))
      throw py::value_error("estimate_motion: option names must be strings, got " +
                            std::string(py::repr(item.first)));
    const std::string key = item.first.cast<std::string>();
    const py::handle v = item.second;
    if (key == "solver") {
      const char* expected = "one of 'auto', '7L', '3L1P', '1L2P'";
      const std::string s = option_str(key, v, expected);
      if (s == "auto") o.solver = line_odom::SolverMode::kAuto;
      else if (s == "7L") o.solver = line_odom::SolverMode::k7L;
      else if (s == "3L1P") o.solver = line_odom::SolverMode::k3L1P;
      else if (s == "1L2P") o.solver = line_odom::SolverMode::k1L2P;
      else bad_option(key, expected, v);
    } else if (key == "max_iterations") {
      o.max_iterations = static_cast<int>(option_int(key, v, 0));
    } else if (key == "min_iterations") {
      o.min_iterations = static_cast<int>(option_int(key, v, 0));
    } else if (key == "confidence") {
      o.confidence = option_float(key, v, 0.0, 1.0, false, "a number in [0, 1]");
    } else if (key == "inlier_threshold") {
      o.inlier_threshold = option_float(key, v, 0.0, 1e9, true, "a number > 0 (metres)");
    } else if (key == "plane_angle_threshold_deg") {
      o.plane_angle_threshold_deg = option_float(key, v, 0.0, 180.0, true, "a number in (0, 180] (degrees)");
    } else if (key == "plane_distance_threshold") {
      o.plane_distance_threshold = option_float(key, v, 0.0, 1e9, true, "a number > 0 (metres)");
    } else if (key == "refine_iterations") {
      o.refine_iterations = static_cast<int>(option_int(key, v, 0));
    } else if (key == "huber_delta") {
      o.huber_delta = option_float(key, v, 0.0, 1e9, false, "a number >= 0 (metres; 0 = inlier_threshold)");
    } else if (key == "seed") {
      if (is_bool(v) || !PyIndex_Check(v.ptr())) bad_option(key, "an integer in [0, 2^64)", v);
      const py::int_ i(py::reinterpret_borrow<py::object>(v));
      if (i < py::int_(0) || i > py::int_(std::numeric_limits<std::uint64_t>::max()))
        bad_option(key, "an integer in [0, 2^64)", v);
      o.seed = i.cast<std::uint64_t>();
    } else if (key == "min_inliers") {
      o.min_inliers = static_cast<int>(option_int(key, v, 0));
    } else if (key == "degeneracy_threshold") {
      o.degeneracy_threshold = option_float(key, v, 0.0, 1.0, false, "a number in [0, 1]");
    } else if (key == "local_optimisation") {
      o.local_optimisation = option_bool(key, v);
    } else if (key == "pretest") {
      o.pretest = option_bool(key, v);
    } else if (key == "min_inlier_contrast") {
      o.min_inlier_contrast = option_float(key, v, 0.0, 1e9, false, "a number >= 0");
    } else if (key == "solve_7l_method") {
      const char* expected = "'gauss_newton' or 'alternating_projection'";
      const std::string s = option_str(key, v, expected);
      if (s == "gauss_newton") o.solve_7l_method = line_odom::Solve7LMethod::kGaussNewton;
      else if (s == "alternating_projection") o.solve_7l_method = line_odom::Solve7LMethod::kAlternatingProjection;
      else bad_option(key, expected, v);
    } else if (key == "solve_7l_max_iterations") {
      o.solve_7l_max_iterations = static_cast<int>(option_int(key, v, 0));
    } else {
      throw py::value_error("estimate_motion: unknown option '" + key +
                            "' (known: solver, max_iterations, min_iterations, confidence, inlier_threshold, "
                            "plane_angle_threshold_deg, plane_distance_threshold, refine_iterations, huber_delta, "
                            "seed, min_inliers, degeneracy_threshold, local_optimisation, pretest, min_inlier_contrast, "
                            "solve_7l_method, "
                            "solve_7l_max_iterations)");
    }
  }
  return o;
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

py::array_t<double> matrix_array(const Eigen::Ref<const Eigen::MatrixXd>& M) {
  py::array_t<double> out({M.rows(), M.cols()});
  auto view = out.mutable_unchecked<2>();
  for (Eigen::Index r = 0; r < M.rows(); ++r)
    for (Eigen::Index c = 0; c < M.cols(); ++c) view(r, c) = M(r, c);
  return out;
}

py::array_t<double> vector_array(const Eigen::Ref<const Eigen::VectorXd>& v) {
  py::array_t<double> out(v.size());
  auto view = out.mutable_unchecked<1>();
  for (Eigen::Index i = 0; i < v.size(); ++i) view(i) = v(i);
  return out;
}

py::array_t<bool> mask_array(const std::vector<std::uint8_t>& mask) {
  py::array_t<bool> out(static_cast<py::ssize_t>(mask.size()));
  auto view = out.mutable_unchecked<1>();
  for (size_t i = 0; i < mask.size(); ++i) view(static_cast<py::ssize_t>(i)) = mask[i] != 0;
  return out;
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
    data.lines_a[i] = solver_bindings::line_at(la.data() + 6 * i);
    data.lines_b[i] = solver_bindings::line_at(lb.data() + 6 * i);
  }
  for (py::ssize_t j = 0; j < m; ++j) {
    data.planes_a.push_back(solver_bindings::plane_at(pa.data() + 4 * j));
    data.planes_b.push_back(solver_bindings::plane_at(pb.data() + 4 * j));
  }
  if (!segments_a.is_none()) {
    const auto sa = rows("segments_a", segments_a, n, {2, 3});
    const auto sb = rows("segments_b", segments_b, n, {2, 3});
    data.segments_a.resize(n);
    data.segments_b.resize(n);
    for (py::ssize_t i = 0; i < n; ++i) {
      data.segments_a[i] = solver_bindings::segment_at(sa.data() + 6 * i);
      data.segments_b[i] = solver_bindings::segment_at(sb.data() + 6 * i);
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
      init.is_none() ? line_odom::RigidTransform::identity() : solver_bindings::pose_from("estimate_motion", "init", init);
  const line_odom::MotionOptions options_ = motion_options(options);

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
  const auto a = solver_bindings::as_float_array(fn, name, obj, {arr.shape(0), 2});
  std::vector<Eigen::Vector2d> out(arr.shape(0));
  for (size_t i = 0; i < out.size(); ++i) out[i] = Eigen::Vector2d(a.data()[2 * i], a.data()[2 * i + 1]);
  return out;
}

std::vector<double> values_1d(const char* fn, const char* name, py::handle obj, py::ssize_t n) {
  const auto a = solver_bindings::as_float_array(fn, name, obj, {n});
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


// ---- scan features helpers (features) ----
#include <memory>

#include "common/worker_pool.hpp"
#include "features/feature_extraction.hpp"
#include "scan/range_image.hpp"

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

FeatureConfig config_from(const py::object& config, const std::string& preset) {
  FeatureConfig cfg = FeatureConfig::preset(preset);
  if (!config.is_none()) {
    if (!py::isinstance<py::dict>(config)) throw py::value_error("config: expected a dict of dotted names");
    for (auto item : config.cast<py::dict>()) {
      const std::string key = py::str(item.first);
      double value;
      try {
        value = item.second.cast<double>();
      } catch (const py::cast_error&) {
        throw py::value_error(key + ": expected a number or bool");
      }
      set_feature_config_field(&cfg, key, value);
    }
  }
  cfg.validate();
  return cfg;
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

py::dict extract_features_py(const py::array& xyz, const py::object& config, const std::string& preset,
                             int threads) {
  if (threads < 1) throw py::value_error("threads: expected >= 1, got " + std::to_string(threads));
  if (xyz.ndim() != 3 || xyz.shape(2) != 3)
    throw py::value_error("range_image: expected an (H, W, 3) organized cloud (NaN or zero = hole)");
  auto a = py::array_t<double, py::array::c_style | py::array::forcecast>::ensure(xyz);
  if (!a) throw py::value_error("range_image: expected a numeric array");
  const FeatureConfig cfg = config_from(config, preset);
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

py::dict feature_config_py(const std::string& preset) {
  py::dict d;
  for (const auto& [name, value] : feature_config_fields(FeatureConfig::preset(preset))) d[py::str(name)] = value;
  return d;
}

}  // namespace feature_bindings

// ---- odometry pipeline helpers (registration) ----
#include <memory>
#include <optional>
#include <variant>

#include "odometry/odometry.hpp"
#include "scan/sensor_fit.hpp"

namespace odometry_bindings {

line_odom::SettingValue to_setting(const std::string& name, const py::handle& value) {
  if (py::isinstance<py::bool_>(value)) return value.cast<bool>();
  if (py::isinstance<py::int_>(value)) return value.cast<std::int64_t>();
  if (py::isinstance<py::float_>(value)) return value.cast<double>();
  if (py::isinstance<py::str>(value)) return value.cast<std::string>();
  throw py::value_error(name + ": expected a bool, int, float or str, got " +
                        std::string(py::str(py::type::of(value).attr("__name__"))));
}

py::dict settings_dict(const line_odom::OdometryConfig& config) {
  py::dict d;
  for (const auto& [name, value] : line_odom::config_settings(config))
    d[py::str(name)] = std::visit([](const auto& x) -> py::object { return py::cast(x); }, value);
  return d;
}

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
  ms["evidence"] = s.ms.evidence;
  ms["total"] = s.ms.total;
  py::dict d;
  d["solver"] = s.solver;
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
  d["evidence"] = s.evidence;
  d["evidence_matches"] = s.evidence_matches;
  d["evidence_inliers"] = s.evidence_inliers;
  d["evidence_z"] = s.evidence_z;
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
  line_odom::OdometryConfig config;
  for (const auto& item : settings) {
    const std::string name = py::str(item.first);
    const std::string error = line_odom::apply_setting(&config, name, to_setting(name, item.second));
    if (!error.empty()) throw py::value_error(name + ": " + error);
  }
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
  if (!same) throw py::value_error(std::string("time: expected ") + what + ", got shape " + solver_bindings::shape_text(
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


py::array_t<double> downsampled_points(const line_odom::Odometry& o, const py::array& xyz,
                                       const std::optional<py::array_t<std::int32_t>>& ring) {
  const std::vector<line_odom::Vec3> pts =
      on_cloud(CloudView(xyz, ring), [&](const auto* data, auto n, auto stride, auto rings) {
        return o.downsampled_points(data, n, stride, rings);
      });
  py::array_t<double> out({static_cast<py::ssize_t>(pts.size()), static_cast<py::ssize_t>(3)});
  auto w = out.mutable_unchecked<2>();
  for (py::ssize_t i = 0; i < static_cast<py::ssize_t>(pts.size()); ++i)
    for (py::ssize_t k = 0; k < 3; ++k) w(i, k) = pts[i][k];
  return out;
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

}  // namespace odometry_bindings


PYBIND11_MODULE(_core, m) {
  m.doc() = "line_odom engine: line-intersection registration (7L, 3L1P, 1L2P) and odometry";
  m.attr("__version__") = LINE_ODOM_VERSION;
  m.def("build_info", &build_info, "Compiler, flags, C++ standard, Eigen and pybind11 versions of this build.");

  // ---- solvers and motion estimation ----
  m.attr("MAX_DIHEDRAL_DIFFERENCE_1L2P") = line_odom::kMaxDihedralDifference1L2P;
  m.def("solve_1l2p", &solver_bindings::solve_1l2p, py::arg("line_a"), py::arg("line_b"), py::arg("planes_a"),
        py::arg("planes_b"), py::kw_only(), py::arg("max_dihedral_difference") = line_odom::kMaxDihedralDifference1L2P,
        "1L2P minimal solver (paper 5.1): line_a (6,) meets T line_b (6,), planes_a (2,4) = T planes_b (2,4).\n"
        "Returns a list of 0 or 1 poses T_ab (4,4).");
  m.def("solve_3l1p", &solver_bindings::solve_3l1p, py::arg("lines_a"), py::arg("lines_b"), py::arg("plane_a"),
        py::arg("plane_b"),
        "3L1P minimal solver (paper 5.2): lines_a[i] (3,6) meets T lines_b[i] (3,6), plane_a (4,) = T plane_b (4,).\n"
        "Returns a list of 0 to 4 poses T_ab (4,4).");
  m.def("solve_7l", &solver_bindings::solve_7l, py::arg("segments_a"), py::arg("segments_b"),
        py::arg("init") = py::none(), py::kw_only(), py::arg("method") = "gauss_newton",
        py::arg("max_iterations") = line_odom::Solve7LOptions{}.max_iterations,
        py::arg("tolerance") = line_odom::Solve7LOptions{}.tolerance,
        py::arg("max_residual") = line_odom::Solve7LOptions{}.max_residual,
        "7L solver (paper 4): segments_a[i] (7,2,3) meets T segments_b[i] (7,2,3), from init (4,4) (None = identity)\n"
        "by Gauss-Newton on SE(3) or by the paper's alternating projection. Returns a list of 0 or 1 poses T_ab.");
  m.def("benchmark_solver", &solver_bindings::benchmark_solver, py::arg("solver"), py::arg("instances") = 1000,
        py::arg("repetitions") = 5, py::arg("seed") = 0, py::kw_only(), py::arg("method") = "gauss_newton",
        py::arg("max_iterations") = line_odom::Solve7LOptions{}.max_iterations,
        py::arg("tolerance") = line_odom::Solve7LOptions{}.tolerance, py::arg("found_tolerance") = 1e-6,
        py::arg("guess_rotation_deg") = 5.0, py::arg("guess_translation") = 0.5, py::arg("max_translation") = 2.0,
        py::arg("scene_radius") = 10.0, py::arg("chunk") = 0,
        "C++ timing loop over seeded noise-free instances of solver '1l2p', '3l1p' or '7l' (method for 7L), timed in\n"
        "chunks of consecutive calls. Returns median_us/p90_us/min_us per call over the chunks, mean_us, chunk,\n"
        "solutions_per_call, found_rate (a solution within found_tolerance of\n"
        "the truth), no_solution_rate, median_error, p99_error, mean_iterations (7L).");

  m.def("estimate_motion", &motion_bindings::estimate_motion, py::arg("lines_a"), py::arg("lines_b"),
        py::arg("planes_a"), py::arg("planes_b"), py::kw_only(), py::arg("segments_a") = py::none(),
        py::arg("segments_b") = py::none(), py::arg("weights") = py::none(), py::arg("clusters") = py::none(),
        py::arg("init") = py::none(), py::arg("options") = py::dict(),
        "Hybrid RANSAC over {7L, 3L1P, 1L2P} on candidate line intersections (row i of lines_a (N,6) with row i\n"
        "of lines_b) and plane pairs (M,4), then robust refinement on all inliers (paper 6.3).\n"
        "Returns (T_ab (4,4), stats dict); T_ab = init (identity) with stats['success'] False when nothing is found.");
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

  // ---- scan features ----
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
        py::arg("config") = py::none(), py::arg("preset") = "kitti", py::kw_only(), py::arg("threads") = 1,
        "Organized cloud (H, W, 3) (NaN/zero = hole) -> dict of H/V lines, planes, cluster directions, stats. "
        "`config` overrides preset fields by dotted name (see feature_config); `threads`: the line fit's (the same "
        "features).");
  m.def("feature_config", &feature_bindings::feature_config_py, py::arg("preset") = "kitti",
        "Feature parameters of a preset by dotted name.");
  m.def("sensor_presets", &line_odom::sensor_preset_names, "Names accepted by organize_points(sensor=...).");

  // ---- odometry pipeline ----
  {
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
        .def("settings", [](const Odometry& o) { return ob::settings_dict(o.config()); });
    m.def("reads_in_place", [](const py::array& xyz) { return ob::in_place_stride(xyz) > 0; }, py::arg("xyz"),
          "Whether register_points / register_organized read these points without a copy.");
    // Per-frame rotation conversions of the Python side (result twist, ROS messages): Eigen's, because scipy's
    // Rotation costs ~0.2 ms a call right after a registration has flushed the caches.
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
    m.def("_motion_persistence",
          [](const Eigen::Matrix<double, Eigen::Dynamic, 6, Eigen::RowMajor>& motions, int window,
             const std::optional<std::vector<bool>>& registered, const std::optional<std::vector<double>>& dt) {
            if (window < 0) throw py::value_error("window: expected >= 0 (frames)");
            const auto rows = static_cast<std::size_t>(motions.rows());
            if (registered && registered->size() != rows)
              throw py::value_error("registered: expected one flag per row of motions");
            if (dt && dt->size() != rows) throw py::value_error("dt: expected one stamp interval per row of motions");
            line_odom::MotionPersistence persistence(window);
            Eigen::Matrix<double, Eigen::Dynamic, 6, Eigen::RowMajor> factors(motions.rows(), 6);
            for (Eigen::Index i = 0; i < motions.rows(); ++i) {
              if (!registered || (*registered)[i]) persistence.add(motions.row(i).transpose(), dt ? (*dt)[i] : 1.0);
              else persistence.interrupt();
              factors.row(i) = persistence.factors().transpose();
            }
            return factors;
          },
          py::arg("motions"), py::arg("window"), py::arg("registered") = py::none(), py::arg("dt") = py::none(),
          "Test hook: MotionPersistence (motion_persistence.hpp) fed the motions (N, 6) (x y z rx ry rz) of frames in "
          "order over their stamp intervals dt (default 1 s; registered[i] False: a frame without a registration); the "
          "per-axis factors after each (N, 6).");
    m.def("odometry_config_defaults", []() { return ob::settings_dict(line_odom::OdometryConfig{}); },
          "Every dotted engine setting the C++ side knows, with its default.");
  }
}
