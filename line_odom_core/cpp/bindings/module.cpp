// The module `_core`: numpy in, numpy out, GIL released on every heavy call. Only the files of bindings/ know
// about Python; each area registers its functions (bindings/module.hpp).
#include <pybind11/eigen.h>
#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

#include <string>

#include "bindings/module.hpp"

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

PYBIND11_MODULE(_core, m) {
  m.doc() = "line_odom engine: line-intersection registration (7L, 3L1P, 1L2P) and odometry";
  m.attr("__version__") = LINE_ODOM_VERSION;
  m.def("build_info", &build_info, "Compiler, flags, C++ standard, Eigen and pybind11 versions of this build.");

  line_odom_bindings::register_solvers(m);
  line_odom_bindings::register_registration(m);
  line_odom_bindings::register_features(m);
  line_odom_bindings::register_odometry(m);
}
