// Settings tables (common/settings_table.hpp) and Python: a dict of dotted names applied to an options struct, a
// struct's values as a dict, the schema line_odom_core.config reads. Errors are ValueError naming the setting.
#pragma once

#include <pybind11/pybind11.h>

#include <optional>
#include <stdexcept>
#include <string>
#include <vector>

#include "common/settings_table.hpp"

namespace py_settings {

namespace py = pybind11;

// A bool, integer, float or str (numpy scalars included) as a setting's value; nullopt for anything else.
std::optional<line_odom::SettingValue> setting_from(py::handle value);
py::object to_python(const line_odom::SettingValue& value);
// One dict per setting: name, type ("bool", "int", "float", "str"), default, min, max (None: unbounded), min_open,
// max_open, zero_is_off, choices, unit, description, runtime, expected (the words of its errors).
py::list schema_list(const std::vector<line_odom::SettingInfo>& schema);

// Sets `name` in `config` from a Python value; ValueError "<context>name: expected ..., got ..." when the name is
// unknown or the value is not one the setting accepts.
template <typename Config>
void apply(const line_odom::SettingsTable<Config>& table, Config* config, py::handle name, py::handle value,
           const std::string& context = "") {
  if (!py::isinstance<py::str>(name))
    throw py::value_error(context + table.kind() + " names must be strings, got " + std::string(py::repr(name)));
  const std::string key = name.cast<std::string>();
  try {
    const auto& row = table.row(key);
    const std::optional<line_odom::SettingValue> converted = setting_from(value);
    if (!converted)
      throw std::invalid_argument(key + ": expected " + row.info().expected() + ", got " + std::string(py::repr(value)));
    row.set(config, *converted);
  } catch (const std::invalid_argument& e) {
    throw py::value_error(context + e.what());
  }
}

template <typename Config>
Config from_dict(const line_odom::SettingsTable<Config>& table, const py::dict& values, const std::string& context = "") {
  Config config;
  for (const auto& item : values) apply(table, &config, item.first, item.second, context);
  return config;
}

template <typename Config>
py::dict to_dict(const line_odom::SettingsTable<Config>& table, const Config& config) {
  py::dict d;
  for (const auto& [name, value] : table.dump(config)) d[py::str(name)] = to_python(value);
  return d;
}

}  // namespace py_settings
