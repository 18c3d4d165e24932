// Physical quantities written with their units ("17.9 kPa", "0.1 mm/s"), converted to SI once.
//
// Scene files and command-line options carry units in the value so that a reader never has to
// guess whether a number is in um or m. Everything past the parser is SI (kg, m, s) and the
// Dimension travels with the value until it is checked against what the key expects.
#pragma once

#include <string>

#include "engine/core/base.h"

namespace zona {

/// Physical dimension as exponents of the SI base units kg, m and s (temperature, current and
/// amount of substance never occur in zona). Pressure is {1, -1, -2}: kg m^-1 s^-2.
struct Dimension {
  int mass = 0;    ///< exponent of kg
  int length = 0;  ///< exponent of m
  int time = 0;    ///< exponent of s

  constexpr bool operator==(const Dimension&) const = default;
};

constexpr Dimension operator*(Dimension a, Dimension b) {
  return {a.mass + b.mass, a.length + b.length, a.time + b.time};
}
constexpr Dimension operator/(Dimension a, Dimension b) {
  return {a.mass - b.mass, a.length - b.length, a.time - b.time};
}
/// Dimension raised to an integer power (m^3 for a volume).
constexpr Dimension power(Dimension a, int exponent) {
  return {a.mass * exponent, a.length * exponent, a.time * exponent};
}

/// The dimensions zona's scene keys use.
namespace dim {
inline constexpr Dimension kNone{0, 0, 0};           ///< dimensionless (ratios, counts)
inline constexpr Dimension kMass{1, 0, 0};           ///< kg
inline constexpr Dimension kLength{0, 1, 0};         ///< m
inline constexpr Dimension kTime{0, 0, 1};           ///< s
inline constexpr Dimension kArea{0, 2, 0};           ///< m^2
inline constexpr Dimension kVolume{0, 3, 0};         ///< m^3
inline constexpr Dimension kSpeed{0, 1, -1};         ///< m/s
inline constexpr Dimension kAcceleration{0, 1, -2};  ///< m/s^2
inline constexpr Dimension kFrequency{0, 0, -1};     ///< 1/s (Hz, rates, mass-proportional damping)
inline constexpr Dimension kForce{1, 1, -2};         ///< N
inline constexpr Dimension kPressure{1, -1, -2};     ///< Pa (stress, elastic moduli)
inline constexpr Dimension kEnergy{1, 2, -2};        ///< J
inline constexpr Dimension kPower{1, 2, -3};         ///< W
inline constexpr Dimension kDensity{1, -3, 0};       ///< kg/m^3
inline constexpr Dimension kStiffness{1, 0, -2};     ///< N/m (also force per length)
inline constexpr Dimension kDamping{1, 0, -1};       ///< N*s/m (viscous damper coefficient)
inline constexpr Dimension kViscosity{1, -1, -1};    ///< Pa*s
}  // namespace dim

/// Human name and SI unit of a dimension for messages: "length (m)", "pressure (Pa)",
/// "dimensionless"; dimensions without a name print as their SI expression ("kg*m^-4").
std::string dimension_name(Dimension dimension);

/// SI unit of a dimension as written in scene files: "m", "Pa", "kg/m^3", "N*s/m", "" for none.
std::string si_unit(Dimension dimension);

/// A parsed quantity: its value in SI and its dimension.
struct Quantity {
  double value = 0.0;  ///< value in SI units (kg, m, s and their products)
  Dimension dimension;
};

/// Parses a unit expression ("um", "mm/s", "kg/m^3", "N*s/m", "1/s", "um/cm") into the factor
/// that converts it to SI and its dimension. Prefixes p, n, u, µ, m, c, k, M, G apply to the
/// base units m, s, g, N, Pa, Hz, J, W; '%' is 0.01. Units multiply with '*' (or '·') and
/// everything after a single '/' is the denominator; exponents are '^N' (or ² ³).
/// The returned Quantity has value = the SI factor (1e-6 for "um").
Result<Quantity> parse_unit(const std::string& text);

/// Parses a unit expression and checks its dimension; returns the factor to SI (1e-6 for "um").
Result<double> parse_unit(const std::string& text, Dimension expected);

/// Parses "number [unit]" ("17.9 kPa", "20kPa", "1e-7 s", "0.49") into SI without checking the
/// dimension. A bare number is dimensionless.
Result<Quantity> parse_quantity(const std::string& text);

/// Parses "number unit" and converts to SI, checking the dimension: "17.9 kPa" for a length is an
/// error naming both dimensions. A bare number is accepted only for dimensionless quantities
/// (and for zero, which is zero in every unit); otherwise it is a "missing unit" error.
Result<double> parse_quantity(const std::string& text, Dimension expected);

/// Formats an SI value with its SI unit ("17900 Pa", "5.6e-05 m") to `significant_digits`;
/// 0 gives the shortest text that round-trips exactly through parse_quantity.
std::string format_quantity(double value_si, Dimension dimension, int significant_digits = 6);

}  // namespace zona
