// numpy <-> engine types for every area of the bindings: checked arrays, lines, planes, segments, poses.
#pragma once

#include <pybind11/eigen.h>
#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

#include <cstdint>
#include <string>
#include <vector>

#include "common/types.hpp"

namespace py_types {

namespace py = pybind11;

std::string shape_text(const std::vector<py::ssize_t>& shape);
// A C-contiguous float64 copy of `obj` with exactly `shape`; ValueError naming the argument otherwise
// (non-numeric or complex dtype, wrong shape, NaN or infinity).
py::array_t<double, py::array::c_style> as_float_array(const char* function, const char* name, py::handle obj,
                                                       const std::vector<py::ssize_t>& shape);
line_odom::PluckerLine line_at(const double* v);
line_odom::Plane plane_at(const double* v);
line_odom::Segment segment_at(const double* v);
// A 4x4 rigid transform: rotation block orthonormal with det +1 (1e-6), last row (0, 0, 0, 1).
line_odom::RigidTransform pose_from(const char* function, const char* name, py::handle obj);
py::list pose_list(const line_odom::RigidTransform* poses, int count);
py::array_t<double> matrix_array(const Eigen::Ref<const Eigen::MatrixXd>& M);
py::array_t<double> vector_array(const Eigen::Ref<const Eigen::VectorXd>& v);
py::array_t<bool> mask_array(const std::vector<std::uint8_t>& mask);

}  // namespace py_types
