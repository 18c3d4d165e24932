// Internal to the scene loader: a validating reader of JSON objects that names the full key
// path in every message and stops at the first error. Shared by engine/scene*.cpp only.
#pragma once

#include <algorithm>
#include <charconv>
#include <cmath>
#include <filesystem>
#include <initializer_list>
#include <limits>
#include <nlohmann/json.hpp>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "engine/core/base.h"
#include "engine/core/units.h"
#include "engine/core/vec.h"

namespace zona::scene_detail {

using json = nlohmann::json;

inline constexpr double kInf = std::numeric_limits<double>::infinity();

// ---------------------------------------------------------------------------------------------
// Validation context: the first error wins; every later read becomes a no-op so that the loader
// reads like a list of keys instead of a ladder of early returns.

struct Context {
  std::string source;                   // prefix of every message (the file path)
  std::filesystem::path base_dir;       // relative paths in the scene resolve against it
  std::vector<std::string> overridden;  // key paths set by --set, to say where a value came from
  std::optional<Error> error;

  bool failed() const { return error.has_value(); }

  void fail(const std::string& path, const std::string& message) {
    if (error) return;
    std::string text = source + ": ";
    if (!path.empty()) text += path + ": ";
    text += message;
    for (const std::string& o : overridden) {
      if (path == o || path.rfind(o + ".", 0) == 0) {
        text += " (value from --set)";
        break;
      }
    }
    error = Error{std::move(text)};
  }
};

inline std::string join_path(const std::string& parent, std::string_view key) {
  return parent.empty() ? std::string(key) : parent + "." + std::string(key);
}

// Edit distance for "did you mean" hints on unknown keys.
inline size_t edit_distance(std::string_view a, std::string_view b) {
  std::vector<size_t> row(b.size() + 1);
  for (size_t j = 0; j <= b.size(); ++j) row[j] = j;
  for (size_t i = 1; i <= a.size(); ++i) {
    size_t diagonal = row[0];
    row[0] = i;
    for (size_t j = 1; j <= b.size(); ++j) {
      const size_t up = row[j];
      row[j] = std::min({row[j] + 1, row[j - 1] + 1, diagonal + (a[i - 1] == b[j - 1] ? 0 : 1)});
      diagonal = up;
    }
  }
  return row[b.size()];
}

/// Allowed interval of a value; the message says it with units.
struct Range {
  double lo = -kInf;
  double hi = kInf;
  bool lo_open = false;
  bool hi_open = false;
  const char* note = nullptr;  // why, when not obvious

  static Range any() { return {}; }
  static Range positive() { return {0.0, kInf, true, false}; }
  static Range non_negative() { return {0.0, kInf, false, false}; }
  static Range at_least(double lo) { return {lo, kInf, false, false}; }
  static Range closed(double lo, double hi) { return {lo, hi, false, false}; }
  static Range open_closed(double lo, double hi) { return {lo, hi, true, false}; }
  static Range closed_open(double lo, double hi) { return {lo, hi, false, true}; }

  bool contains(double v) const {
    const bool above_lo = lo_open ? v > lo : v >= lo;
    const bool below_hi = hi_open ? v < hi : v <= hi;
    return above_lo && below_hi;
  }

  std::string describe(Dimension d) const {
    std::string text;
    if (lo == -kInf && hi == kInf) return "must be finite";
    if (hi == kInf) {
      text = std::string(lo_open ? "must be > " : "must be >= ") + format_quantity(lo, d);
    } else if (lo == -kInf) {
      text = std::string(hi_open ? "must be < " : "must be <= ") + format_quantity(hi, d);
    } else {
      text = std::string("must be in ") + (lo_open ? "(" : "[") + format_quantity(lo, dim::kNone) +
             ", " + format_quantity(hi, dim::kNone) + (hi_open ? ")" : "]");
      const std::string unit = si_unit(d);
      if (!unit.empty()) text += " " + unit;
    }
    if (note) text += std::string(" (") + note + ")";
    return text;
  }
};

// The value as the user wrote it, for messages.
inline std::string written(const json& v) {
  if (v.is_string()) return "\"" + v.get<std::string>() + "\"";
  return v.dump();
}

// Parses a quantity from a JSON string ("56 um") or number (dimensionless, or zero).
inline bool read_quantity(Context& ctx, const json& v, const std::string& path, Dimension d,
                   double* out) {
  if (v.is_string()) {
    Result<double> q = parse_quantity(v.get<std::string>(), d);
    if (!q) {
      ctx.fail(path, q.error().message);
      return false;
    }
    *out = *q;
    return true;
  }
  if (v.is_number()) {
    const double x = v.get<double>();
    if (d == dim::kNone || x == 0.0) {
      *out = x;
      return true;
    }
    ctx.fail(path, v.dump() + ": missing unit, expected " + dimension_name(d) + ", e.g. \"" +
                       v.dump() + " " + si_unit(d) + "\"");
    return false;
  }
  if (d == dim::kNone) {
    ctx.fail(path, "expected a number, got " + std::string(v.type_name()));
  } else {
    ctx.fail(path, "expected " + dimension_name(d) + " written with its unit, like \"1 " +
                       si_unit(d) + "\", got " + v.type_name());
  }
  return false;
}

// "x y z unit", "(x, y, z) unit" or "[x, y, z] unit": three numbers sharing one unit.
inline bool read_vec3_string(Context& ctx, const std::string& text, const std::string& path, Dimension d,
                      Vec3d* out) {
  std::string s = text;
  for (char& c : s) {
    if (c == '(' || c == ')' || c == '[' || c == ']' || c == ',') c = ' ';
  }
  const char* p = s.data();
  const char* end = s.data() + s.size();
  double xyz[3] = {0.0, 0.0, 0.0};
  for (double& component : xyz) {
    while (p < end && *p == ' ') ++p;
    if (p < end && *p == '+') ++p;
    const auto [next, ec] = std::from_chars(p, end, component);
    if (ec != std::errc() || !std::isfinite(component)) {
      ctx.fail(path, "\"" + text + "\": expected three numbers and a unit, like \"0 0 -30 um\"");
      return false;
    }
    p = next;
  }
  while (p < end && *p == ' ') ++p;
  double factor = 1.0;
  if (p == end) {
    if (d != dim::kNone && (xyz[0] != 0.0 || xyz[1] != 0.0 || xyz[2] != 0.0)) {
      ctx.fail(path, "\"" + text + "\": missing unit, expected " + dimension_name(d));
      return false;
    }
  } else {
    Result<double> unit = parse_unit(std::string(p, end), d);
    if (!unit) {
      ctx.fail(path, unit.error().message);
      return false;
    }
    factor = *unit;
  }
  *out = {xyz[0] * factor, xyz[1] * factor, xyz[2] * factor};
  return true;
}

// A choice among named values ("svk", "linear", ...).
template <class E>
struct Choice {
  const char* name;
  E value;
};

// ---------------------------------------------------------------------------------------------
// Reader of one JSON object. Unknown keys are reported when the reader is made, before any
// value is read, so that a misspelt key reads "unknown key" rather than "required key missing".

class Reader {
 public:
  Reader(Context& ctx, const json* node, std::string path,
         std::initializer_list<std::string_view> allowed)
      : ctx_(ctx), node_(node), path_(std::move(path)) {
    if (!node_ || ctx_.failed()) return;
    if (!node_->is_object()) {
      ctx_.fail(path_, std::string("expected an object, got ") + node_->type_name());
      node_ = nullptr;
      return;
    }
    for (const auto& [key, value] : node_->items()) {
      if (key == "note") {
        // "note" is the comment key of every object (JSON has no comments).
        if (!value.is_string()) ctx_.fail(join_path(path_, key), "a note must be a string");
        continue;
      }
      if (std::find(allowed.begin(), allowed.end(), key) != allowed.end()) continue;
      std::string message = "unknown key";
      std::string_view best;
      size_t best_distance = 3;
      for (std::string_view candidate : allowed) {
        const size_t distance = edit_distance(key, candidate);
        if (distance < best_distance) {
          best_distance = distance;
          best = candidate;
        }
      }
      if (!best.empty()) message += " (did you mean '" + std::string(best) + "'?)";
      ctx_.fail(join_path(path_, key), message);
      return;
    }
  }

  bool present() const { return node_ != nullptr && !ctx_.failed(); }
  Context& ctx() { return ctx_; }
  const std::string& path() const { return path_; }
  std::string key_path(std::string_view key) const { return join_path(path_, key); }

  const json* find(std::string_view key) const {
    if (!present()) return nullptr;
    const auto it = node_->find(std::string(key));
    return it == node_->end() ? nullptr : &*it;
  }
  bool has(std::string_view key) const { return find(key) != nullptr; }

  /// Fails unless the key is present.
  bool require(std::string_view key) {
    if (!present()) return false;
    if (has(key)) return true;
    ctx_.fail(key_path(key), "required key missing");
    return false;
  }

  Reader object(std::string_view key, std::initializer_list<std::string_view> allowed) {
    return Reader(ctx_, find(key), key_path(key), allowed);
  }

  bool quantity(std::string_view key, Dimension d, double* out, Range range = Range::any()) {
    const json* v = find(key);
    if (!v) return false;
    double x = 0.0;
    if (!read_quantity(ctx_, *v, key_path(key), d, &x)) return false;
    if (!check_range(key, *v, x, d, range)) return false;
    *out = x;
    return true;
  }

  /// "auto" (nullopt) or a quantity.
  bool auto_or_quantity(std::string_view key, Dimension d, std::optional<double>* out,
                        Range range) {
    const json* v = find(key);
    if (!v) return false;
    if (v->is_string() && v->get<std::string>() == "auto") {
      out->reset();
      return true;
    }
    if (!v->is_string() && !v->is_number()) {
      ctx_.fail(key_path(key), "expected \"auto\" or " + dimension_name(d) + " with its unit, got " +
                                   v->type_name());
      return false;
    }
    double x = 0.0;
    if (!quantity(key, d, &x, range)) return false;
    *out = x;
    return true;
  }

  bool number(std::string_view key, double* out, Range range = Range::any()) {
    return quantity(key, dim::kNone, out, range);
  }

  bool integer(std::string_view key, int64_t* out, int64_t lo, int64_t hi) {
    const json* v = find(key);
    if (!v) return false;
    bool ok = false;
    int64_t x = 0;
    if (v->is_number_unsigned()) {
      const uint64_t u = v->get<uint64_t>();
      ok = u <= static_cast<uint64_t>(hi);
      x = ok ? static_cast<int64_t>(u) : hi;
    } else if (v->is_number_integer()) {
      x = v->get<int64_t>();
      ok = true;
    } else if (v->is_number_float()) {
      const double f = v->get<double>();
      ok = std::floor(f) == f && std::fabs(f) < 9e15;
      x = ok ? static_cast<int64_t>(f) : 0;
      if (!ok) {
        ctx_.fail(key_path(key), v->dump() + ": expected an integer");
        return false;
      }
    } else {
      ctx_.fail(key_path(key), std::string("expected an integer, got ") + v->type_name());
      return false;
    }
    if (!ok || x < lo || x > hi) {
      ctx_.fail(key_path(key), v->dump() + " is out of range: must be in [" + std::to_string(lo) +
                                   ", " + std::to_string(hi) + "]");
      return false;
    }
    *out = x;
    return true;
  }

  bool boolean(std::string_view key, bool* out) {
    const json* v = find(key);
    if (!v) return false;
    if (!v->is_boolean()) {
      ctx_.fail(key_path(key), std::string("expected true or false, got ") + v->type_name());
      return false;
    }
    *out = v->get<bool>();
    return true;
  }

  bool string(std::string_view key, std::string* out) {
    const json* v = find(key);
    if (!v) return false;
    if (!v->is_string()) {
      ctx_.fail(key_path(key), std::string("expected a string, got ") + v->type_name());
      return false;
    }
    *out = v->get<std::string>();
    return true;
  }

  template <class E>
  bool choice(std::string_view key, std::initializer_list<Choice<E>> choices, E* out) {
    std::string s;
    if (!string(key, &s)) return false;
    std::string names;
    for (const Choice<E>& c : choices) {
      if (s == c.name) {
        *out = c.value;
        return true;
      }
      names += names.empty() ? "" : ", ";
      names += c.name;
    }
    ctx_.fail(key_path(key), "\"" + s + "\" is not one of: " + names);
    return false;
  }

  /// A point or vector with units: ["0 um", "0 um", "-30 um"] or "0 0 -30 um".
  bool vec3(std::string_view key, Dimension d, Vec3d* out) {
    const json* v = find(key);
    if (!v) return false;
    const std::string path = key_path(key);
    if (v->is_string()) return read_vec3_string(ctx_, v->get<std::string>(), path, d, out);
    if (!v->is_array() || v->size() != 3) {
      ctx_.fail(path, "expected three values with units, like [\"0 um\", \"0 um\", \"-30 um\"] or "
                      "\"0 0 -30 um\"");
      return false;
    }
    Vec3d r{};
    for (int i = 0; i < 3; ++i) {
      if (!read_quantity(ctx_, (*v)[static_cast<size_t>(i)], join_path(path, std::to_string(i)), d,
                         &r[i])) {
        return false;
      }
    }
    *out = r;
    return true;
  }

  /// A unit direction: [x, y, z] (normalised here) or "+x", "-z", "y".
  bool direction(std::string_view key, Vec3d* out) {
    const json* v = find(key);
    if (!v) return false;
    const std::string path = key_path(key);
    Vec3d d{};
    if (v->is_string()) {
      std::string s = v->get<std::string>();
      double sign = 1.0;
      if (!s.empty() && (s[0] == '+' || s[0] == '-')) {
        sign = s[0] == '-' ? -1.0 : 1.0;
        s = s.substr(1);
      }
      if (s == "x") {
        d = {sign, 0.0, 0.0};
      } else if (s == "y") {
        d = {0.0, sign, 0.0};
      } else if (s == "z") {
        d = {0.0, 0.0, sign};
      } else {
        ctx_.fail(path, written(*v) + ": expected an axis (\"+x\", \"-z\", ...) or [x, y, z]");
        return false;
      }
    } else {
      if (!vec3(key, dim::kNone, &d)) return false;
    }
    const double length = norm(d);
    if (!(length > 0.0)) {
      ctx_.fail(path, "direction must not be zero");
      return false;
    }
    *out = d / length;
    return true;
  }

  /// A file path relative to the scene's folder; the file must exist and be a regular file
  /// (a directory, device or FIFO gets its own message: it exists, but cannot be read).
  bool file_path(std::string_view key, std::string* out) {
    std::string s;
    if (!string(key, &s)) return false;
    if (s.empty()) {
      ctx_.fail(key_path(key), "empty path");
      return false;
    }
    std::filesystem::path p(s);
    if (p.is_relative()) p = ctx_.base_dir / p;
    const std::string kind = file_kind(p.string());
    if (kind.empty()) {
      ctx_.fail(key_path(key), "file not found: " + p.string());
      return false;
    }
    if (kind != "regular file") {
      ctx_.fail(key_path(key), "'" + p.string() + "' is not a regular file (" + kind + ")");
      return false;
    }
    *out = p.lexically_normal().string();
    return true;
  }

  void fail(std::string_view key, const std::string& message) {
    ctx_.fail(key.empty() ? path_ : key_path(key), message);
  }

 private:
  bool check_range(std::string_view key, const json& v, double x, Dimension d, const Range& r) {
    if (r.contains(x)) return true;
    ctx_.fail(key_path(key), written(v) + " is out of range: " + r.describe(d));
    return false;
  }

  Context& ctx_;
  const json* node_;
  std::string path_;
};

}  // namespace zona::scene_detail
