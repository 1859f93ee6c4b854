#include "common/settings_table.hpp"

#include <algorithm>
#include <cctype>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <string>

namespace line_odom {

namespace {

std::string trimmed(const std::string& text) {
  const auto first = text.find_first_not_of(' ');
  if (first == std::string::npos) return {};
  return text.substr(first, text.find_last_not_of(' ') - first + 1);
}

double bound(const std::string& text, const std::string& range) {
  const std::string t = trimmed(text);
  char* end = nullptr;
  const double x = std::strtod(t.c_str(), &end);
  if (t.empty() || *end != '\0' || std::isnan(x)) throw std::logic_error("settings table: bad range '" + range + "'");
  return x;
}

// A float as Python's repr writes it (the shortest text that reads back the same: 0.001, 10.0, 1e-05, 1e+16), so an
// error reads like the parameter file that caused it.
std::string float_text(double x) {
  if (std::isnan(x)) return "nan";
  if (std::isinf(x)) return x > 0 ? "inf" : "-inf";
  char buf[40];
  for (int digits = 1; digits <= 17; ++digits) {
    std::snprintf(buf, sizeof buf, "%.*e", digits - 1, x);
    if (std::strtod(buf, nullptr) == x) break;
  }
  std::string text(buf);  // [-]d[.ddd]e(+|-)XX
  std::string sign;
  if (text[0] == '-') sign = "-", text.erase(0, 1);
  const auto e = text.find('e');
  std::string mantissa = text.substr(0, e);
  const int exponent = std::atoi(text.c_str() + e + 1);
  mantissa.erase(std::remove(mantissa.begin(), mantissa.end(), '.'), mantissa.end());
  if (exponent < -4 || exponent >= 16) {
    std::string out = sign + mantissa.substr(0, 1);
    if (mantissa.size() > 1) out += "." + mantissa.substr(1);
    char exp[8];
    std::snprintf(exp, sizeof exp, "e%c%02d", exponent < 0 ? '-' : '+', std::abs(exponent));
    return out + exp;
  }
  if (exponent < 0) return sign + "0." + std::string(-exponent - 1, '0') + mantissa;
  if (static_cast<int>(mantissa.size()) <= exponent + 1)
    return sign + mantissa + std::string(exponent + 1 - mantissa.size(), '0') + ".0";
  return sign + mantissa.substr(0, exponent + 1) + "." + mantissa.substr(exponent + 1);
}

std::string bound_text(double x, SettingType type) {
  if (type == SettingType::kInteger && std::abs(x) < 9.2e18) return std::to_string(static_cast<long long>(x));
  return float_text(x);
}

std::string range_text(const SettingRange& r, SettingType type) {
  const bool low = std::isfinite(r.min), high = std::isfinite(r.max);
  std::string text;
  if (low && high) {
    text = std::string("in ") + (r.min_open ? "(" : "[") + bound_text(r.min, type) + ", " + bound_text(r.max, type) +
           (r.max_open ? ")" : "]");
  } else if (low) {
    text = (r.min_open ? "> " : ">= ") + bound_text(r.min, type);
  } else if (high) {
    text = (r.max_open ? "< " : "<= ") + bound_text(r.max, type);
  }
  if (r.zero_is_off) text = "0 (off) or " + text;
  return text;
}

bool same_ignoring_case(const std::string& a, const std::string& b) {
  if (a.size() != b.size()) return false;
  for (std::size_t i = 0; i < a.size(); ++i)
    if (std::tolower(static_cast<unsigned char>(a[i])) != std::tolower(static_cast<unsigned char>(b[i]))) return false;
  return true;
}

}  // namespace

SettingRange SettingRange::parse(const std::string& text) {
  SettingRange r;
  std::string t = trimmed(text);
  const std::string off = "0 (off) or ";
  if (t.rfind(off, 0) == 0) {
    r = parse(t.substr(off.size()));
    r.zero_is_off = true;
    return r;
  }
  if (t.empty()) return r;
  if (t[0] == '[' || t[0] == '(') {
    const auto comma = t.find(',');
    const char last = t.back();
    if (comma == std::string::npos || (last != ']' && last != ')'))
      throw std::logic_error("settings table: bad range '" + text + "'");
    r.min = bound(t.substr(1, comma - 1), text);
    r.max = bound(t.substr(comma + 1, t.size() - comma - 2), text);
    r.min_open = t[0] == '(';
    r.max_open = last == ')';
  } else if (t.rfind(">=", 0) == 0) {
    r.min = bound(t.substr(2), text);
  } else if (t.rfind('>', 0) == 0) {
    r.min = bound(t.substr(1), text);
    r.min_open = true;
  } else if (t.rfind("<=", 0) == 0) {
    r.max = bound(t.substr(2), text);
  } else if (t.rfind('<', 0) == 0) {
    r.max = bound(t.substr(1), text);
    r.max_open = true;
  } else {
    throw std::logic_error("settings table: bad range '" + text + "'");
  }
  if (!(r.min <= r.max)) throw std::logic_error("settings table: empty range '" + text + "'");
  return r;
}

bool SettingRange::contains(long double x) const {
  if (zero_is_off && x == 0.0L) return true;
  const long double lo = min, hi = max;
  return (min_open ? x > lo : x >= lo) && (max_open ? x < hi : x <= hi);
}

std::string SettingInfo::expected() const {
  std::string text;
  switch (type) {
    case SettingType::kBool:
      return "bool";
    case SettingType::kString: {
      if (choices.empty()) return "str";
      text = "one of ";
      for (std::size_t i = 0; i < choices.size(); ++i) text += (i ? ", " : "") + choices[i];
      return text;
    }
    case SettingType::kInteger:
      text = "integer";
      break;
    case SettingType::kFloat:
      text = "float";
      break;
  }
  const std::string range_words = range_text(range, type);
  if (!range_words.empty()) text += " " + range_words;
  if (!unit.empty()) text += " " + unit;
  return text;
}

std::string setting_value_text(const SettingValue& value) {
  if (const auto* b = std::get_if<bool>(&value)) return *b ? "true" : "false";
  if (const auto* i = std::get_if<std::int64_t>(&value)) return std::to_string(*i);
  if (const auto* u = std::get_if<std::uint64_t>(&value)) return std::to_string(*u);
  if (const auto* d = std::get_if<double>(&value)) return float_text(*d);
  return "'" + std::get<std::string>(value) + "'";
}

SettingValue checked_setting_value(const SettingInfo& info, const SettingValue& value) {
  auto refuse = [&]() -> SettingValue {
    throw std::invalid_argument(info.name + ": expected " + info.expected() + ", got " + setting_value_text(value));
  };
  switch (info.type) {
    case SettingType::kBool:
      return std::holds_alternative<bool>(value) ? value : refuse();
    case SettingType::kString: {
      if (!std::holds_alternative<std::string>(value)) return refuse();
      if (info.choices.empty()) return value;
      for (const auto& c : info.choices)
        if (same_ignoring_case(c, std::get<std::string>(value))) return c;
      return refuse();
    }
    case SettingType::kInteger: {
      if (const auto* i = std::get_if<std::int64_t>(&value))
        return info.range.contains(static_cast<long double>(*i)) ? value : refuse();
      if (const auto* u = std::get_if<std::uint64_t>(&value))
        return info.range.contains(static_cast<long double>(*u)) ? value : refuse();
      const auto* d = std::get_if<double>(&value);
      if (d == nullptr || !std::isfinite(*d) || *d != std::floor(*d) || !info.range.contains(*d)) return refuse();
      if (*d >= 9223372036854775808.0) return static_cast<std::uint64_t>(*d);
      return static_cast<std::int64_t>(*d);
    }
    case SettingType::kFloat: {
      double x = 0.0;
      if (const auto* i = std::get_if<std::int64_t>(&value)) x = static_cast<double>(*i);
      else if (const auto* u = std::get_if<std::uint64_t>(&value)) x = static_cast<double>(*u);
      else if (const auto* d = std::get_if<double>(&value)) x = *d;
      else return refuse();
      return std::isfinite(x) && info.range.contains(x) ? SettingValue(x) : refuse();
    }
  }
  return refuse();
}

}  // namespace line_odom
