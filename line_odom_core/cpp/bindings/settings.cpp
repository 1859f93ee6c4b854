#include "bindings/settings.hpp"

#include <pybind11/stl.h>

#include <cmath>
#include <cstdint>
#include <string>
#include <variant>

namespace py_settings {

namespace {

const char* type_name(line_odom::SettingType type) {
  switch (type) {
    case line_odom::SettingType::kBool: return "bool";
    case line_odom::SettingType::kInteger: return "int";
    case line_odom::SettingType::kFloat: return "float";
    case line_odom::SettingType::kString: return "str";
  }
  return "";
}

// A range's end as the setting's type; None when unbounded.
py::object bound(double x, line_odom::SettingType type) {
  if (!std::isfinite(x)) return py::none();
  if (type == line_odom::SettingType::kInteger) return py::int_(static_cast<long long>(x));
  return py::float_(x);
}

}  // namespace

std::optional<line_odom::SettingValue> setting_from(py::handle value) {
  const std::string type = py::str(py::type::of(value).attr("__name__"));
  if (py::isinstance<py::bool_>(value) || type == "bool_") return value.cast<bool>();
  if (py::isinstance<py::str>(value)) return value.cast<std::string>();
  if (PyIndex_Check(value.ptr())) {
    const py::int_ i(py::reinterpret_borrow<py::object>(value));
    int overflow = 0;
    const long long x = PyLong_AsLongLongAndOverflow(i.ptr(), &overflow);
    if (overflow == 0) return static_cast<std::int64_t>(x);
    if (overflow > 0) {
      const unsigned long long u = PyLong_AsUnsignedLongLong(i.ptr());
      if (!PyErr_Occurred()) return static_cast<std::uint64_t>(u);
      PyErr_Clear();
    }
    return std::nullopt;
  }
  if (PyFloat_Check(value.ptr()) || (!py::isinstance<py::bytes>(value) && py::hasattr(value, "__float__"))) {
    const double x = PyFloat_AsDouble(value.ptr());
    if (x == -1.0 && PyErr_Occurred()) {
      PyErr_Clear();
      return std::nullopt;
    }
    return x;
  }
  return std::nullopt;
}

py::object to_python(const line_odom::SettingValue& value) {
  return std::visit([](const auto& x) -> py::object { return py::cast(x); }, value);
}

py::list schema_list(const std::vector<line_odom::SettingInfo>& schema) {
  py::list out;
  for (const auto& s : schema) {
    py::dict d;
    d["name"] = s.name;
    d["type"] = type_name(s.type);
    d["default"] = to_python(s.default_value);
    const bool numeric = s.type == line_odom::SettingType::kInteger || s.type == line_odom::SettingType::kFloat;
    d["min"] = numeric ? bound(s.range.min, s.type) : py::object(py::none());
    d["max"] = numeric ? bound(s.range.max, s.type) : py::object(py::none());
    d["min_open"] = numeric && s.range.min_open;
    d["max_open"] = numeric && s.range.max_open;
    d["zero_is_off"] = numeric && s.range.zero_is_off;
    d["choices"] = s.choices;
    d["unit"] = s.unit;
    d["description"] = s.description;
    d["runtime"] = s.runtime;
    d["expected"] = s.expected();
    out.append(d);
  }
  return out;
}

}  // namespace py_settings
