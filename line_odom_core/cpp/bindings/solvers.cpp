// Bindings of the minimal solvers (paper §4, §5.1, §5.2).
#include <pybind11/eigen.h>
#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

#include <array>
#include <string>

#include "bindings/module.hpp"
#include "bindings/types.hpp"
#include "solvers/solve_1l2p.hpp"
#include "solvers/solve_3l1p.hpp"
#include "solvers/solve_7l.hpp"

namespace py = pybind11;

namespace solver_bindings {

using py_types::as_float_array;
using py_types::line_at;
using py_types::plane_at;
using py_types::pose_from;
using py_types::pose_list;
using py_types::segment_at;

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

}  // namespace solver_bindings

void line_odom_bindings::register_solvers(py::module_& m) {
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
}
