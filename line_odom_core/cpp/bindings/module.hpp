// One register function per area of the module `_core`, called in this order by bindings/module.cpp.
#pragma once

#include <pybind11/pybind11.h>

namespace line_odom_bindings {

void register_solvers(pybind11::module_& m);       // minimal solvers
void register_registration(pybind11::module_& m);  // estimate_motion and its options
void register_features(pybind11::module_& m);      // range images and features
void register_odometry(pybind11::module_& m);      // the pipeline, its results and settings

}  // namespace line_odom_bindings
