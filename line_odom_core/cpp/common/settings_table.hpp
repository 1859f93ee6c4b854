// A declarative table of an options struct's settings: one row per setting holds its dotted name, the member it
// sets, the values it accepts (a range or choices), its unit, a one-line description and whether a running node may
// change it. Applying a value, dumping a config, checking one and the schema the bindings export all read the rows.
// A setting's default is its member's own initializer: the value in a default-constructed struct.
//
//   SettingsTable<PlaneFitConfig> planes("feature parameter", {
//       flag("enabled", &PlaneFitConfig::enabled, "fit planes"),
//       number("max_rms", &PlaneFitConfig::max_rms, "(0, 10]", "m", "point-to-plane rms"), ...});
//   features.add("planes", &FeatureConfig::planes, planes);  // its rows as planes.enabled, ... of FeatureConfig
#pragma once

#include <algorithm>
#include <cstdint>
#include <functional>
#include <limits>
#include <stdexcept>
#include <string>
#include <type_traits>
#include <utility>
#include <variant>
#include <vector>

namespace line_odom {

// A setting's value as parameter files, ROS parameters and Python hold it.
using SettingValue = std::variant<bool, std::int64_t, std::uint64_t, double, std::string>;

enum class SettingType { kBool, kInteger, kFloat, kString };

// The numbers a setting accepts: min..max, either end open or infinite; with zero_is_off 0 as well (the value that
// switches the feature off, outside the range it otherwise takes).
struct SettingRange {
  double min = -std::numeric_limits<double>::infinity();
  double max = std::numeric_limits<double>::infinity();
  bool min_open = false;
  bool max_open = false;
  bool zero_is_off = false;

  // "[0, 90)", "(0, 10]", "> 0", ">= 1", "<= 5", "0 (off) or [3, 20]", "" (any); std::logic_error otherwise.
  static SettingRange parse(const std::string& text);
  // long double: exact for every 64-bit integer (x86-64's 80-bit and AArch64's 128-bit formats)
  bool contains(long double x) const;
};

// What a row tells about its setting: the schema the bindings export, and the words of its errors.
struct SettingInfo {
  std::string name;
  SettingType type = SettingType::kFloat;
  SettingValue default_value;
  SettingRange range;                // integer and float settings
  std::vector<std::string> choices;  // string settings
  std::string unit;
  std::string description;
  bool runtime = false;  // a running node may apply a new value

  // What the setting accepts: "float in (0, 10.0] m", "integer >= 1", "bool", "one of auto, 7L, 3L1P, 1L2P".
  std::string expected() const;
};

// A value as the errors show it: "-1.0", "3", "'5pt'", "true".
std::string setting_value_text(const SettingValue& value);
// The value as the setting's type (an integer for a float setting, an integral float for an integer one, a choice
// matched without regard to case), checked against its range or choices; std::invalid_argument
// "name: expected float in (0, 10.0] m, got -1.0" otherwise.
SettingValue checked_setting_value(const SettingInfo& info, const SettingValue& value);

template <typename Config>
class SettingRow {
 public:
  using Getter = std::function<SettingValue(const Config&)>;
  // Stores a value already of the row's type and checked.
  using Setter = std::function<void(Config&, const SettingValue&)>;

  SettingRow(SettingInfo info, Getter get, Setter set)
      : info_(std::move(info)), get_(std::move(get)), set_(std::move(set)) {
    info_.default_value = get_(Config{});
  }

  const SettingInfo& info() const { return info_; }
  const std::string& name() const { return info_.name; }
  SettingValue get(const Config& config) const { return get_(config); }
  void set(Config* config, const SettingValue& value) const { set_(*config, checked_setting_value(info_, value)); }
  // Throws naming the setting when its value in `config` is outside what it accepts.
  void check(const Config& config) const { checked_setting_value(info_, get_(config)); }

  SettingRow changes_while_running() const {
    SettingRow row = *this;
    row.info_.runtime = true;
    return row;
  }

  // This row inside a larger struct: named prefix.name there, reached through `part`.
  template <typename Outer>
  SettingRow<Outer> within(const std::string& prefix, Config Outer::*part) const {
    SettingInfo info = info_;
    if (!prefix.empty()) info.name = prefix + "." + info.name;
    Getter get = get_;
    Setter set = set_;
    return SettingRow<Outer>(
        std::move(info), [part, get](const Outer& o) { return get(o.*part); },
        [part, set](Outer& o, const SettingValue& v) { set(o.*part, v); });
  }

 private:
  SettingInfo info_;
  Getter get_;
  Setter set_;
};

template <typename Config>
class SettingsTable {
 public:
  // `kind` names the rows in errors ("unknown engine setting"); names must be unique.
  SettingsTable(std::string kind, std::vector<SettingRow<Config>> rows) : kind_(std::move(kind)) {
    for (auto& row : rows) append(std::move(row));
  }

  // The rows of a part of Config (its member `part`), named prefix.name ("" : the part's names as they are).
  template <typename Part>
  SettingsTable& add(const std::string& prefix, Part Config::*part, const SettingsTable<Part>& table) {
    for (const auto& row : table.rows()) append(row.template within<Config>(prefix, part));
    return *this;
  }
  // The rows of another table of the same struct.
  SettingsTable& add(const SettingsTable& table) {
    for (const auto& row : table.rows()) append(row);
    return *this;
  }

  const std::vector<SettingRow<Config>>& rows() const { return rows_; }
  const std::string& kind() const { return kind_; }
  const SettingRow<Config>* find(const std::string& name) const {
    for (const auto& row : rows_)
      if (row.name() == name) return &row;
    return nullptr;
  }
  // The row of `name`; std::invalid_argument naming it and every known name otherwise.
  const SettingRow<Config>& row(const std::string& name) const {
    if (const auto* found = find(name)) return *found;
    std::string known;
    for (const auto& r : rows_) known += (known.empty() ? "" : ", ") + r.name();
    throw std::invalid_argument(name + ": unknown " + kind_ + " (known: " + known + ")");
  }

  void apply(Config* config, const std::string& name, const SettingValue& value) const {
    row(name).set(config, value);
  }
  // Every setting with its value in `config`, in the table's order.
  std::vector<std::pair<std::string, SettingValue>> dump(const Config& config) const {
    std::vector<std::pair<std::string, SettingValue>> out;
    out.reserve(rows_.size());
    for (const auto& row : rows_) out.emplace_back(row.name(), row.get(config));
    return out;
  }
  // Throws naming the first setting whose value in `config` is outside what it accepts.
  void validate(const Config& config) const {
    for (const auto& row : rows_) row.check(config);
  }
  std::vector<SettingInfo> schema() const {
    std::vector<SettingInfo> out;
    out.reserve(rows_.size());
    for (const auto& row : rows_) out.push_back(row.info());
    return out;
  }

 private:
  void append(SettingRow<Config> row) {
    if (find(row.name())) throw std::logic_error("settings table: " + row.name() + " twice");
    rows_.push_back(std::move(row));
  }

  std::string kind_;
  std::vector<SettingRow<Config>> rows_;
};

// ---- Rows: number (integers and floats), flag (bools), choice (strings and enums).

namespace settings_detail {

// An integer member's own limits, within which its range must lie.
template <typename T>
SettingRange integer_range(SettingRange range) {
  static_assert(std::is_same_v<T, int> || std::is_same_v<T, std::uint64_t>, "integer settings are int or uint64");
  if constexpr (std::is_same_v<T, int>) {
    range.min = std::max(range.min, static_cast<double>(std::numeric_limits<int>::min()));
    range.max = std::min(range.max, static_cast<double>(std::numeric_limits<int>::max()));
  } else if (range.min < 0.0) {
    throw std::logic_error("settings table: an unsigned setting needs a range >= 0");
  }
  return range;
}

template <typename T>
SettingValue number_value(T x) {
  if constexpr (std::is_same_v<T, double>) return x;
  else if constexpr (std::is_same_v<T, std::uint64_t>) return x;
  else return static_cast<std::int64_t>(x);
}

template <typename T>
T number_from(const SettingValue& v) {
  if constexpr (std::is_same_v<T, double>) return std::get<double>(v);
  else if (std::holds_alternative<std::uint64_t>(v)) return static_cast<T>(std::get<std::uint64_t>(v));
  else return static_cast<T>(std::get<std::int64_t>(v));
}

template <typename T>
SettingInfo number_info(const char* name, const char* range, const char* unit, const char* description) {
  SettingInfo info;
  info.name = name;
  info.unit = unit;
  info.description = description;
  if constexpr (std::is_same_v<T, double>) {
    info.type = SettingType::kFloat;
    info.range = SettingRange::parse(range);
  } else {
    info.type = SettingType::kInteger;
    info.range = integer_range<T>(SettingRange::parse(range));
  }
  return info;
}

}  // namespace settings_detail

// An integer (int, uint64) or float (double) member; `range` as SettingRange::parse reads it.
template <typename Config, typename T>
SettingRow<Config> number(const char* name, T Config::*member, const char* range, const char* unit,
                          const char* description) {
  return SettingRow<Config>(
      settings_detail::number_info<T>(name, range, unit, description),
      [member](const Config& c) { return settings_detail::number_value(c.*member); },
      [member](Config& c, const SettingValue& v) { c.*member = settings_detail::number_from<T>(v); });
}

// A number inside a member of Config (sensor.limits.min_range).
template <typename Config, typename Part, typename T>
SettingRow<Config> number(const char* name, Part Config::*part, T Part::*member, const char* range, const char* unit,
                          const char* description) {
  return SettingRow<Config>(
      settings_detail::number_info<T>(name, range, unit, description),
      [part, member](const Config& c) { return settings_detail::number_value((c.*part).*member); },
      [part, member](Config& c, const SettingValue& v) { (c.*part).*member = settings_detail::number_from<T>(v); });
}

template <typename Config>
SettingRow<Config> flag(const char* name, bool Config::*member, const char* description) {
  SettingInfo info;
  info.name = name;
  info.type = SettingType::kBool;
  info.description = description;
  return SettingRow<Config>(
      std::move(info), [member](const Config& c) { return SettingValue(c.*member); },
      [member](Config& c, const SettingValue& v) { c.*member = std::get<bool>(v); });
}

// A string member that takes one of `choices`.
template <typename Config>
SettingRow<Config> choice(const char* name, std::string Config::*member, std::vector<std::string> choices,
                          const char* description) {
  SettingInfo info;
  info.name = name;
  info.type = SettingType::kString;
  info.choices = std::move(choices);
  info.description = description;
  return SettingRow<Config>(
      std::move(info), [member](const Config& c) { return SettingValue(c.*member); },
      [member](Config& c, const SettingValue& v) { c.*member = std::get<std::string>(v); });
}

// An enum member, by the names of its values.
template <typename Config, typename Enum>
SettingRow<Config> choice(const char* name, Enum Config::*member, std::vector<std::pair<std::string, Enum>> names,
                          const char* description) {
  static_assert(std::is_enum_v<Enum>, "choice: a string or an enum member");
  SettingInfo info;
  info.name = name;
  info.type = SettingType::kString;
  for (const auto& entry : names) info.choices.push_back(entry.first);
  info.description = description;
  return SettingRow<Config>(
      std::move(info),
      [member, names](const Config& c) {
        for (const auto& [text, value] : names)
          if (value == c.*member) return SettingValue(text);
        throw std::logic_error("settings table: an enum value without a name");
      },
      [member, names](Config& c, const SettingValue& v) {
        for (const auto& [text, value] : names)
          if (text == std::get<std::string>(v)) c.*member = value;
      });
}

}  // namespace line_odom
