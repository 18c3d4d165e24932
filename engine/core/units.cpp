// Unit parser: "number unit-expression" to SI with a checked Dimension.
#include "engine/core/units.h"

#include <charconv>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <string_view>

namespace zona {
namespace {

struct NamedDimension {
  Dimension dimension;
  const char* name;
  const char* unit;
};

// Order matters only for readability; each dimension appears once.
constexpr NamedDimension kNamedDimensions[] = {
    {dim::kNone, "dimensionless", ""},
    {dim::kMass, "mass", "kg"},
    {dim::kLength, "length", "m"},
    {dim::kTime, "time", "s"},
    {dim::kArea, "area", "m^2"},
    {dim::kVolume, "volume", "m^3"},
    {dim::kSpeed, "speed", "m/s"},
    {dim::kAcceleration, "acceleration", "m/s^2"},
    {dim::kFrequency, "frequency or rate", "1/s"},
    {dim::kForce, "force", "N"},
    {dim::kPressure, "pressure", "Pa"},
    {dim::kEnergy, "energy", "J"},
    {dim::kPower, "power", "W"},
    {dim::kDensity, "density", "kg/m^3"},
    {dim::kStiffness, "stiffness", "N/m"},
    {dim::kDamping, "damping coefficient", "N*s/m"},
    {dim::kViscosity, "viscosity", "Pa*s"},
};

const NamedDimension* find_named(Dimension d) {
  for (const NamedDimension& n : kNamedDimensions) {
    if (n.dimension == d) return &n;
  }
  return nullptr;
}

// Generic SI expression for dimensions without a name: "kg*m^-4*s^-1".
std::string generic_unit(Dimension d) {
  std::string out;
  auto append = [&out](const char* symbol, int exponent) {
    if (exponent == 0) return;
    if (!out.empty()) out += '*';
    out += symbol;
    if (exponent != 1) {
      // Two appends: GCC 12 warns (-Wrestrict, a false positive) on "^" + std::to_string().
      out += '^';
      out += std::to_string(exponent);
    }
  };
  append("kg", d.mass);
  append("m", d.length);
  append("s", d.time);
  return out;
}

// Every unit zona accepts is a power of ten times an SI product, so a factor is kept as its
// decimal exponent: the conversion then shifts the number's exponent and rounds once ("56 um"
// becomes exactly the double 56e-6, as if written in C++).
struct UnitSymbol {
  const char* symbol;
  int exponent10;  // factor to SI = 10^exponent10
  Dimension dimension;
  bool prefixable;
};

// The base units a scene may use. "g" is the prefixable mass unit so that "kg" and "mg" both
// come out of the prefix rule.
constexpr UnitSymbol kUnits[] = {
    {"m", 0, dim::kLength, true},      {"s", 0, dim::kTime, true},
    {"g", -3, dim::kMass, true},       {"N", 0, dim::kForce, true},
    {"Pa", 0, dim::kPressure, true},   {"Hz", 0, dim::kFrequency, true},
    {"J", 0, dim::kEnergy, true},      {"W", 0, dim::kPower, true},
    {"%", -2, dim::kNone, false},
};

struct Prefix {
  const char* text;  // UTF-8
  int exponent10;
};

// Both the micro sign U+00B5 and the Greek mu U+03BC are accepted: keyboards produce either.
constexpr Prefix kPrefixes[] = {
    {"p", -12}, {"n", -9}, {"u", -6}, {"\xC2\xB5", -6}, {"\xCE\xBC", -6},
    {"m", -3},  {"c", -2}, {"k", 3},  {"M", 6},         {"G", 9},
};

// A parsed unit expression: 10^exponent10 times SI, of the given dimension.
struct UnitFactor {
  int exponent10 = 0;
  Dimension dimension;
};

const UnitSymbol* find_unit(std::string_view symbol) {
  for (const UnitSymbol& u : kUnits) {
    if (symbol == u.symbol) return &u;
  }
  return nullptr;
}

// Resolves one symbol ("kPa", "um", "m"). An exact base-unit match wins over prefix + unit,
// so "m" is metre and "mm" is millimetre.
bool resolve_symbol(std::string_view symbol, UnitFactor* out) {
  if (const UnitSymbol* u = find_unit(symbol)) {
    *out = {u->exponent10, u->dimension};
    return true;
  }
  for (const Prefix& p : kPrefixes) {
    const size_t n = std::strlen(p.text);
    if (symbol.size() > n && symbol.substr(0, n) == p.text) {
      const UnitSymbol* u = find_unit(symbol.substr(n));
      if (u && u->prefixable) {
        *out = {p.exponent10 + u->exponent10, u->dimension};
        return true;
      }
    }
  }
  return false;
}

bool is_symbol_byte(std::string_view s, size_t i, size_t* length) {
  const unsigned char c = static_cast<unsigned char>(s[i]);
  if ((c >= 'a' && c <= 'z') || (c >= 'A' && c <= 'Z') || c == '%') {
    *length = 1;
    return true;
  }
  // The two-byte micro signs.
  if (i + 1 < s.size()) {
    const unsigned char d = static_cast<unsigned char>(s[i + 1]);
    if ((c == 0xC2 && d == 0xB5) || (c == 0xCE && d == 0xBC)) {
      *length = 2;
      return true;
    }
  }
  return false;
}

void skip_spaces(std::string_view s, size_t* i) {
  while (*i < s.size() && (s[*i] == ' ' || s[*i] == '\t')) ++*i;
}

bool starts_with_at(std::string_view s, size_t i, const char* text) {
  return s.substr(i, std::strlen(text)) == text;
}

constexpr const char* kKnownUnits =
    "known: m s g N Pa Hz J W with prefixes p n u µ m c k M G, and %; write products as N*s";

}  // namespace

std::string dimension_name(Dimension dimension) {
  if (const NamedDimension* n = find_named(dimension)) {
    if (dimension == dim::kNone) return n->name;
    return std::string(n->name) + " (" + n->unit + ")";
  }
  return "dimension " + generic_unit(dimension);
}

std::string si_unit(Dimension dimension) {
  if (const NamedDimension* n = find_named(dimension)) return n->unit;
  return generic_unit(dimension);
}

namespace {

// 10^exponent10 as the nearest double (correctly rounded by from_chars).
double power_of_ten(int exponent10) {
  const std::string text = "1e" + std::to_string(exponent10);
  double value = 0.0;
  std::from_chars(text.data(), text.data() + text.size(), value);
  return value;
}

Result<UnitFactor> parse_unit_factor(const std::string& text) {
  const std::string_view s(text);
  UnitFactor total;
  size_t i = 0;
  bool denominator = false;
  bool expect_factor = true;
  skip_spaces(s, &i);
  if (i == s.size()) return make_error("empty unit");
  // "1/s": a numerator of one.
  if (s[i] == '1') {
    size_t j = i + 1;
    skip_spaces(s, &j);
    if (j < s.size() && s[j] == '/') {
      denominator = true;
      i = j + 1;
    }
  }
  while (true) {
    skip_spaces(s, &i);
    if (i == s.size()) break;
    if (expect_factor) {
      const size_t start = i;
      size_t len = 0;
      while (i < s.size() && is_symbol_byte(s, i, &len)) i += len;
      if (i == start) {
        return make_error("unit \"%s\": expected a unit symbol at '%s' (%s)", text.c_str(),
                          std::string(s.substr(start)).c_str(), kKnownUnits);
      }
      const std::string_view symbol = s.substr(start, i - start);
      UnitFactor unit;
      if (!resolve_symbol(symbol, &unit)) {
        return make_error("unknown unit '%s' in \"%s\" (%s)", std::string(symbol).c_str(),
                          text.c_str(), kKnownUnits);
      }
      // Exponent: ^N, ^-N, or the superscripts ² and ³.
      int exponent = 1;
      if (i < s.size() && s[i] == '^') {
        ++i;
        int sign = 1;
        if (i < s.size() && (s[i] == '-' || s[i] == '+')) {
          sign = s[i] == '-' ? -1 : 1;
          ++i;
        }
        const size_t digits_start = i;
        int value = 0;
        while (i < s.size() && s[i] >= '0' && s[i] <= '9' && i - digits_start < 2) {
          value = value * 10 + (s[i] - '0');
          ++i;
        }
        if (i == digits_start || (i < s.size() && s[i] >= '0' && s[i] <= '9')) {
          return make_error("unit \"%s\": expected a small integer exponent after '^'",
                            text.c_str());
        }
        exponent = sign * value;
      } else if (starts_with_at(s, i, "\xC2\xB2")) {
        exponent = 2;
        i += 2;
      } else if (starts_with_at(s, i, "\xC2\xB3")) {
        exponent = 3;
        i += 2;
      }
      if (denominator) exponent = -exponent;
      total.exponent10 += unit.exponent10 * exponent;
      total.dimension = total.dimension * power(unit.dimension, exponent);
      expect_factor = false;
    } else {
      if (s[i] == '*') {
        ++i;
      } else if (starts_with_at(s, i, "\xC2\xB7")) {
        i += 2;
      } else if (s[i] == '/') {
        // Everything after one '/' is the denominator ("W/m^2*K" is W/(m^2 K)); a second '/'
        // would be ambiguous, so it is refused rather than guessed.
        if (denominator) {
          return make_error("unit \"%s\": more than one '/' is ambiguous; write a/b*c for a/(b*c)",
                            text.c_str());
        }
        denominator = true;
        ++i;
      } else {
        return make_error("unit \"%s\": unexpected '%s' (join units with '*' or '/')",
                          text.c_str(), std::string(s.substr(i)).c_str());
      }
      expect_factor = true;
    }
  }
  if (expect_factor) return make_error("unit \"%s\": ends with an operator", text.c_str());
  return total;
}

}  // namespace

Result<Quantity> parse_unit(const std::string& text) {
  Result<UnitFactor> unit = parse_unit_factor(text);
  if (!unit) return unit.error();
  return Quantity{power_of_ten(unit->exponent10), unit->dimension};
}

Result<double> parse_unit(const std::string& text, Dimension expected) {
  Result<Quantity> unit = parse_unit(text);
  if (!unit) return unit.error();
  if (unit->dimension != expected) {
    return make_error("unit \"%s\" is %s, expected %s", text.c_str(),
                      dimension_name(unit->dimension).c_str(), dimension_name(expected).c_str());
  }
  return unit->value;
}

Result<Quantity> parse_quantity(const std::string& text) {
  const std::string_view s(text);
  size_t i = 0;
  skip_spaces(s, &i);
  // from_chars takes no leading '+'; accept it for symmetry with '-'.
  if (i < s.size() && s[i] == '+') ++i;
  double number = 0.0;
  const char* first = s.data() + i;
  const char* last = s.data() + s.size();
  const auto [end, ec] = std::from_chars(first, last, number);
  if (ec == std::errc::result_out_of_range) {
    return make_error("\"%s\": number out of range", text.c_str());
  }
  if (ec != std::errc() || end == first) {
    return make_error("\"%s\": expected a number followed by a unit, like \"56 um\"",
                      text.c_str());
  }
  if (!std::isfinite(number)) return make_error("\"%s\": number must be finite", text.c_str());
  size_t rest = static_cast<size_t>(end - s.data());
  skip_spaces(s, &rest);
  if (rest == s.size()) return Quantity{number, dim::kNone};
  Result<UnitFactor> unit = parse_unit_factor(std::string(s.substr(rest)));
  if (!unit) return unit.error();
  if (unit->exponent10 == 0) return Quantity{number, unit->dimension};
  // Shift the decimal exponent in the text and convert once: "9.1952e-5 mg" reads as
  // "9.1952e-11", so the result is the double nearest to the decimal value.
  const std::string_view digits(first, static_cast<size_t>(end - first));
  const size_t e = digits.find_first_of("eE");
  long exponent = 0;
  if (e != std::string_view::npos) {
    std::string_view exp_text = digits.substr(e + 1);
    if (!exp_text.empty() && exp_text[0] == '+') exp_text.remove_prefix(1);
    std::from_chars(exp_text.data(), exp_text.data() + exp_text.size(), exponent);
  }
  const std::string shifted =
      std::string(digits.substr(0, e)) + "e" + std::to_string(exponent + unit->exponent10);
  double value = 0.0;
  const auto [shifted_end, shifted_ec] =
      std::from_chars(shifted.data(), shifted.data() + shifted.size(), value);
  if (shifted_ec != std::errc() || !std::isfinite(value)) {
    return make_error("\"%s\": value out of range", text.c_str());
  }
  return Quantity{value, unit->dimension};
}

Result<double> parse_quantity(const std::string& text, Dimension expected) {
  Result<Quantity> q = parse_quantity(text);
  if (!q) return q.error();
  if (q->dimension == expected) return q->value;
  // A bare number: fine for zero (zero in every unit), otherwise the unit was forgotten.
  if (q->dimension == dim::kNone && text.find_first_not_of(" \t+-.0123456789eE") ==
                                        std::string::npos) {
    if (q->value == 0.0) return 0.0;
    return make_error("\"%s\": missing unit, expected %s", text.c_str(),
                      dimension_name(expected).c_str());
  }
  return make_error("\"%s\" is %s, expected %s", text.c_str(),
                    dimension_name(q->dimension).c_str(), dimension_name(expected).c_str());
}

std::string format_quantity(double value_si, Dimension dimension, int significant_digits) {
  char number[64] = {};
  if (significant_digits <= 0) {
    // Shortest text that reads back to the same double.
    const auto result = std::to_chars(number, number + sizeof(number) - 1, value_si);
    *result.ptr = '\0';
  } else {
    std::snprintf(number, sizeof(number), "%.*g", significant_digits, value_si);
  }
  const std::string unit = si_unit(dimension);
  if (unit.empty()) return number;
  return std::string(number) + " " + unit;
}

}  // namespace zona
