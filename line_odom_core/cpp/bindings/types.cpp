#include "bindings/types.hpp"

#include <cmath>

namespace py_types {

std::string shape_text(const std::vector<py::ssize_t>& shape) {
  std::string text = "(";
  for (size_t i = 0; i < shape.size(); ++i) {
    text += std::to_string(shape[i]);
    if (shape.size() == 1 || i + 1 < shape.size()) text += shape.size() == 1 ? "," : ", ";
  }
  return text + ")";
}

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
  if (actual != shape) throw py::value_error(expected + ", got shape " + shape_text(actual));
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

}  // namespace py_types
