// The module `_testing`: hooks for the tests and bench/solvers.py into engine parts that have no entry of their own
// in `_core`. Built beside `_core` from the same engine sources (setup.py); nothing the node imports loads it.
#include <pybind11/eigen.h>
#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

#include <algorithm>
#include <array>
#include <cstdint>
#include <limits>
#include <map>
#include <optional>
#include <tuple>
#include <string>
#include <vector>

#include "bindings/settings.hpp"
#include "bindings/types.hpp"
#include "odometry/engine_settings.hpp"
#include "odometry/motion_persistence.hpp"
#include "odometry/odometry.hpp"
#include "registration/candidates.hpp"
#include "registration/point_alignment.hpp"
#include "registration/voxel_points.hpp"
#include "testing/ransac_examples.hpp"
#include "testing/solver_benchmark.hpp"

namespace py = pybind11;

namespace {

line_odom::Solve7LMethod method_7l(const std::string& method) {
  if (method == "gauss_newton") return line_odom::Solve7LMethod::kGaussNewton;
  if (method == "alternating_projection") return line_odom::Solve7LMethod::kAlternatingProjection;
  throw py::value_error("method: expected 'gauss_newton' or 'alternating_projection', got '" + method + "'");
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

py::tuple ransac_fit_line_2d(py::handle points, double threshold, py::handle weights, int max_iterations,
                             int min_iterations, double confidence, std::uint64_t seed, bool local_optimisation) {
  const auto p = points_2d("ransac_fit_line_2d", "points", points);
  const auto w = weights.is_none() ? std::vector<double>() : values_1d("ransac_fit_line_2d", "weights", weights,
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
  return py::make_tuple(py_types::vector_array(line), ransac_stats(ok, st));
}

py::tuple ransac_translation_2d(py::handle points_a, py::handle points_b, py::handle directions,
                                py::handle projections, double threshold, int max_iterations, int min_iterations,
                                double confidence, std::uint64_t seed) {
  const auto pa = points_2d("ransac_translation_2d", "points_a", points_a);
  const auto pb = points_2d("ransac_translation_2d", "points_b", points_b);
  if (pa.size() != pb.size()) throw py::value_error("ransac_translation_2d: points_b must have the shape of points_a");
  const auto u = points_2d("ransac_translation_2d", "directions", directions);
  const auto o = values_1d("ransac_translation_2d", "projections", projections, static_cast<py::ssize_t>(u.size()));
  Eigen::Vector2d t = Eigen::Vector2d::Zero();
  line_odom::RansacStats st;
  bool ok;
  {
    py::gil_scoped_release release;
    ok = line_odom::ransac_translation_2d(pa, pb, u, o, threshold,
                                          ransac_options(max_iterations, min_iterations, confidence, seed, false), &t,
                                          &st);
  }
  return py::make_tuple(py_types::vector_array(t), ransac_stats(ok, st));
}

using Motions = Eigen::Matrix<double, Eigen::Dynamic, 6, Eigen::RowMajor>;

Motions motion_persistence(const Motions& motions, int window, const std::optional<std::vector<bool>>& registered,
                           const std::optional<std::vector<double>>& dt) {
  if (window < 0) throw py::value_error("window: expected >= 0 (frames)");
  const auto rows = static_cast<std::size_t>(motions.rows());
  if (registered && registered->size() != rows)
    throw py::value_error("registered: expected one flag per row of motions");
  if (dt && dt->size() != rows) throw py::value_error("dt: expected one stamp interval per row of motions");
  line_odom::MotionPersistence persistence(window);
  Motions factors(motions.rows(), 6);
  for (Eigen::Index i = 0; i < motions.rows(); ++i) {
    if (!registered || (*registered)[i]) persistence.add(motions.row(i).transpose(), dt ? (*dt)[i] : 1.0);
    else persistence.interrupt();
    factors.row(i) = persistence.factors().transpose();
  }
  return factors;
}

using Points = Eigen::Matrix<double, Eigen::Dynamic, 3, Eigen::RowMajor>;

std::vector<line_odom::Vec3> vec3s(const Points& points) {
  std::vector<line_odom::Vec3> out(static_cast<std::size_t>(points.rows()));
  for (Eigen::Index i = 0; i < points.rows(); ++i) out[static_cast<std::size_t>(i)] = points.row(i).transpose();
  return out;
}

// VoxelPointMap (voxel_points.hpp) holding `points` (world frame), each scan of them (`scan_of`: consecutive runs, none:
// one scan) added in turn by a sensor at sensor_positions[scan] (none: the origin), a full voxel's points from within
// `same_place` of another scan's place giving way: for each query, the map point nearest() returns within max_distance
// (NaN where none) and the index of its voxel (-1).
py::tuple voxel_map_nearest(const Points& points, double voxel, int max_points_per_voxel, const Points& queries,
                            double max_distance, std::optional<std::vector<int>> scan_of,
                            std::optional<Points> sensor_positions, double same_place) {
  if (!(voxel > 0.0)) throw py::value_error("voxel: expected > 0 (m)");
  if (max_points_per_voxel < 1) throw py::value_error("max_points_per_voxel: expected >= 1");
  const std::vector<int> scans = scan_of.value_or(std::vector<int>(static_cast<std::size_t>(points.rows()), 0));
  if (scans.size() != static_cast<std::size_t>(points.rows()))
    throw py::value_error("scan_of: expected one scan index per point");
  const int scan_count = scans.empty() ? 0 : *std::max_element(scans.begin(), scans.end()) + 1;
  if (!scans.empty() && *std::min_element(scans.begin(), scans.end()) < 0)
    throw py::value_error("scan_of: expected indices >= 0");
  if (sensor_positions && sensor_positions->rows() < scan_count)
    throw py::value_error("sensor_positions: expected a row per scan of scan_of");
  line_odom::VoxelPointMap map(voxel, max_points_per_voxel, same_place);
  for (std::size_t begin = 0; begin < scans.size();) {
    std::size_t end = begin;
    while (end < scans.size() && scans[end] == scans[begin]) ++end;
    line_odom::RigidTransform pose = line_odom::RigidTransform::identity();
    if (sensor_positions) pose.t = sensor_positions->row(scans[begin]).transpose();
    std::vector<line_odom::Vec3> scan;
    for (std::size_t i = begin; i < end; ++i)
      scan.push_back(points.row(static_cast<Eigen::Index>(i)).transpose() - pose.t);
    map.add(scan, pose, 1e9);
    begin = end;
  }
  Points nearest(queries.rows(), 3);
  std::vector<int> voxels(static_cast<std::size_t>(queries.rows()), -1);
  for (Eigen::Index i = 0; i < queries.rows(); ++i) {
    line_odom::Vec3 q = queries.row(i).transpose(), found;
    int index = -1;
    if (map.nearest(q, max_distance, &found, &index)) {
      nearest.row(i) = found.transpose();
      voxels[static_cast<std::size_t>(i)] = index;
    } else {
      nearest.row(i).setConstant(std::numeric_limits<double>::quiet_NaN());
    }
  }
  return py::make_tuple(nearest, voxels);
}

using Segments = Eigen::Matrix<double, Eigen::Dynamic, 6, Eigen::RowMajor>;
using Pose = Eigen::Matrix<double, 4, 4, Eigen::RowMajor>;

// Lines with segments (N, 6: a, b) and surface normals (N, 3; zero where unknown).
std::vector<line_odom::LineFeature> line_features(const char* name, const Segments& segments, const Points& normals) {
  if (normals.rows() != segments.rows())
    throw py::value_error(std::string(name) + ": expected one normal per segment");
  std::vector<line_odom::LineFeature> lines(static_cast<std::size_t>(segments.rows()));
  for (Eigen::Index i = 0; i < segments.rows(); ++i) {
    line_odom::LineFeature& l = lines[static_cast<std::size_t>(i)];
    l.segment = {segments.row(i).head<3>().transpose(), segments.row(i).tail<3>().transpose()};
    l.line = l.segment.line();
    l.normal = normals.row(i).transpose();
  }
  return lines;
}

// build_candidates (candidates.hpp) of the H-lines of frame a against the V-lines of frame b, one call per guess and
// distance in order on one index and the same b (as the passes of a frame): per call the pairs (index in a, index in
// b, distance). `taken_a` >= 0: only the first taken_a lines of a are partners (CandidateSubset).
std::vector<std::vector<std::tuple<int, int, double>>> candidate_pairs(
    const Segments& segments_a, const Points& normals_a, const Segments& segments_b, const Points& normals_b,
    const std::vector<Pose>& guesses, const std::vector<double>& max_distances, int max_pairs_per_line,
    int taken_a) {
  if (max_distances.size() != guesses.size())
    throw py::value_error("max_distances: expected one distance per guess");
  line_odom::ScanFeatures a, b;
  a.h_lines = line_features("normals_a", segments_a, normals_a);
  b.v_lines = line_features("normals_b", segments_b, normals_b);
  line_odom::CandidateOptions options;
  options.max_pairs_per_line = max_pairs_per_line;
  line_odom::CandidateSubset subset;
  if (taken_a >= 0) subset.h_lines = static_cast<std::size_t>(taken_a);
  line_odom::CandidateIndex index(a);
  std::map<std::array<double, 6>, int> index_of;  // segment of frame a -> its index
  auto key = [](const line_odom::Segment& s) {
    return std::array<double, 6>{s.a.x(), s.a.y(), s.a.z(), s.b.x(), s.b.y(), s.b.z()};
  };
  for (std::size_t i = 0; i < a.h_lines.size(); ++i) index_of.emplace(key(a.h_lines[i].segment), static_cast<int>(i));
  std::vector<std::vector<std::tuple<int, int, double>>> out;
  for (std::size_t call = 0; call < guesses.size(); ++call) {
    const line_odom::RigidTransform T = line_odom::RigidTransform::from_matrix(guesses[call]);
    options.max_distance = max_distances[call];
    line_odom::Correspondences corr;
    line_odom::build_candidates(index, b, T, options, &corr, nullptr, nullptr, subset);
    auto& pairs = out.emplace_back();
    for (std::size_t i = 0; i < corr.lines_a.size(); ++i) {
      pairs.emplace_back(index_of.at(key(corr.segments_a[i])), corr.lines_b_index[i],
                         line_odom::segment_distance(corr.segments_a[i], corr.segments_b[i].moved(T)));
    }
  }
  return out;
}

// align_points (point_alignment.hpp) of `scan` (sensor frame) from `initial_pose` to a VoxelPointMap of cubes of
// `voxel` holding `map_points` added at the identity, measured over `ground` (a, b, c, d: a x + b y + c z + d = 0;
// None: no ground known): the pose it ends at.
Pose point_map_alignment(const Points& map_points, std::optional<Eigen::Vector4d> ground, double voxel,
                         const Points& scan, const Pose& initial_pose, double sigma) {
  if (!(voxel > 0.0)) throw py::value_error("voxel: expected > 0 (m)");
  if (!(sigma > 0.0)) throw py::value_error("sigma: expected > 0 (m)");
  line_odom::VoxelPointMap map(voxel, 20);
  const line_odom::Plane plane = ground ? py_types::plane_at(ground->data()) : line_odom::Plane{};
  map.add(vec3s(map_points), line_odom::RigidTransform::identity(), 1e9, ground ? &plane : nullptr);
  const line_odom::PointAlignment aligned = line_odom::align_points(
      map, vec3s(scan), line_odom::RigidTransform::from_matrix(initial_pose), sigma, line_odom::PointAlignmentOptions{},
      true);
  return aligned.pose.matrix();
}

}  // namespace

PYBIND11_MODULE(_testing, m) {
  m.doc() = "line_odom engine hooks for tests and benchmarks (not imported by the node)";
  m.def("benchmark_solver", &benchmark_solver, py::arg("solver"), py::arg("instances") = 1000,
        py::arg("repetitions") = 5, py::arg("seed") = 0, py::kw_only(), py::arg("method") = "gauss_newton",
        py::arg("max_iterations") = line_odom::Solve7LOptions{}.max_iterations,
        py::arg("tolerance") = line_odom::Solve7LOptions{}.tolerance, py::arg("found_tolerance") = 1e-6,
        py::arg("guess_rotation_deg") = 5.0, py::arg("guess_translation") = 0.5, py::arg("max_translation") = 2.0,
        py::arg("scene_radius") = 10.0, py::arg("chunk") = 0,
        "C++ timing loop over seeded noise-free instances of solver '1l2p', '3l1p' or '7l' (method for 7L), timed in\n"
        "chunks of consecutive calls. Returns median_us/p90_us/min_us per call over the chunks, mean_us, chunk,\n"
        "solutions_per_call, found_rate (a solution within found_tolerance of\n"
        "the truth), no_solution_rate, median_error, p99_error, mean_iterations (7L).");
  m.def("ransac_fit_line_2d", &ransac_fit_line_2d, py::arg("points"), py::arg("threshold"), py::kw_only(),
        py::arg("weights") = py::none(), py::arg("max_iterations") = 1000, py::arg("min_iterations") = 0,
        py::arg("confidence") = 0.999, py::arg("seed") = 0, py::arg("local_optimisation") = true,
        "The generic RANSAC (ransac.hpp) fitting a 2D line (a, b, c), a^2 + b^2 = 1, to points (N,2).");
  m.def("ransac_translation_2d", &ransac_translation_2d, py::arg("points_a"), py::arg("points_b"),
        py::arg("directions"), py::arg("projections"), py::arg("threshold"), py::kw_only(),
        py::arg("max_iterations") = 1000, py::arg("min_iterations") = 0, py::arg("confidence") = 0.999,
        py::arg("seed") = 0,
        "The hybrid RANSAC (ransac.hpp) estimating a 2D translation from point pairs (solver 0, one\n"
        "pair) and scalar projections u.t = o (solver 1, two projections).");
  m.def("motion_persistence", &motion_persistence, py::arg("motions"), py::arg("window"),
        py::arg("registered") = py::none(), py::arg("dt") = py::none(),
        "MotionPersistence (motion_persistence.hpp) fed the motions (N, 6) (x y z rx ry rz) of frames in order over "
        "their stamp intervals dt (default 1 s; registered[i] False: a frame without a registration); the per-axis "
        "factors after each (N, 6).");
  m.def("voxel_map_nearest", &voxel_map_nearest, py::arg("points"), py::arg("voxel"), py::arg("max_points_per_voxel"),
        py::arg("queries"), py::arg("max_distance"), py::kw_only(), py::arg("scan_of") = py::none(),
        py::arg("sensor_positions") = py::none(), py::arg("same_place") = -1.0,
        "The local point map's nearest-point lookup (voxel_points.hpp) over `points` (N, 3, world frame) in cubes of "
        "`voxel`, added scan by scan (scan_of: each point's scan, consecutive; sensor_positions: (S, 3), where each "
        "scan's sensor stood), a full cube's points from within `same_place` of another scan's place giving way: for "
        "each query (M, 3), the map point returned within max_distance (NaN where none) and its voxel's index (-1).");
  m.def("point_map_alignment", &point_map_alignment, py::arg("map_points"), py::arg("ground"), py::arg("voxel"),
        py::arg("scan"), py::arg("initial_pose"), py::arg("sigma"),
        "The point map's alignment (point_alignment.hpp) of `scan` (N, 3) from initial_pose (4x4) to a map of "
        "`map_points` (M, 3) in cubes of `voxel`, measured over the plane `ground` (a, b, c, d) or None, its kernel "
        "from `sigma`: the 4x4 pose it ends at.");
  m.def("candidate_pairs", &candidate_pairs, py::arg("segments_a"), py::arg("normals_a"), py::arg("segments_b"),
        py::arg("normals_b"), py::arg("guesses"), py::arg("max_distances"), py::arg("max_pairs_per_line"),
        py::arg("taken_a") = -1,
        "The candidate search (candidates.hpp) of the lines of frame a (segments (N, 6), normals (N, 3), 0 where "
        "unknown) against those of frame b moved by each guess (4x4) within its distance, in turn on one index: per "
        "guess the pairs (index in a, index in b, segment distance). taken_a >= 0: only the first taken_a lines of a "
        "are partners.");
  m.def("odometry_config_defaults",
        []() { return py_settings::to_dict(line_odom::odometry_settings(), line_odom::OdometryConfig{}); },
        "Every dotted engine setting with the default of its OdometryConfig member.");
}
