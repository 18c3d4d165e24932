// Tests for engine/units: unit expressions and quantities against hand-computed SI values.
#include "engine/core/units.h"

#include <gtest/gtest.h>

#include <cmath>

namespace zona {
namespace {

// Value in SI of `text`, which must parse with dimension `d`.
double si(const std::string& text, Dimension d) {
  Result<double> r = parse_quantity(text, d);
  EXPECT_TRUE(r.ok()) << text << ": " << (r.ok() ? "" : r.error().message);
  return r.ok() ? *r : std::nan("");
}

// Error message of a parse that must fail.
std::string error_of(const std::string& text, Dimension d) {
  Result<double> r = parse_quantity(text, d);
  EXPECT_FALSE(r.ok()) << text << " parsed as " << (r.ok() ? *r : 0.0);
  return r.ok() ? std::string() : r.error().message;
}

void expect_rel(double actual, double expected) {
  EXPECT_NEAR(actual, expected, std::fabs(expected) * 1e-12) << "expected " << expected;
}

TEST(Units, ScenesQuantitiesConvertToSi) {
  expect_rel(si("17.9 kPa", dim::kPressure), 17.9e3);
  expect_rel(si("56 um", dim::kLength), 56e-6);
  expect_rel(si("0.1 mm/s", dim::kSpeed), 1e-4);
  expect_rel(si("2.5 kPa", dim::kPressure), 2500.0);
  // mg = 1e-3 g = 1e-6 kg: the seed's cell mass is 9.1952e-11 kg.
  expect_rel(si("9.1952e-5 mg", dim::kMass), 9.1952e-11);
  expect_rel(si("30 um", dim::kLength), 30e-6);
  expect_rel(si("1e-7 s", dim::kTime), 1e-7);
  expect_rel(si("7.5 uN", dim::kForce), 7.5e-6);
  expect_rel(si("1000 kg/m^3", dim::kDensity), 1000.0);
  expect_rel(si("1 ms", dim::kTime), 1e-3);
  expect_rel(si("1 kHz", dim::kFrequency), 1000.0);
  expect_rel(si("400 N/m", dim::kStiffness), 400.0);
}

TEST(Units, ConversionRoundsOnceLikeACppLiteral) {
  // The unit's power of ten shifts the number's exponent before conversion, so the result is
  // the double nearest to the decimal value: exactly the C++ literal.
  EXPECT_EQ(si("56 um", dim::kLength), 56e-6);
  EXPECT_EQ(si("100 um", dim::kLength), 100e-6);
  EXPECT_EQ(si("9.1952e-5 mg", dim::kMass), 9.1952e-11);
  EXPECT_EQ(si("9.1952E+1 mg", dim::kMass), 9.1952e-5);
  EXPECT_EQ(si("17.9 kPa", dim::kPressure), 17.9e3);
  EXPECT_EQ(si("0.1 mm/s", dim::kSpeed), 0.1e-3);
  EXPECT_EQ(si("3.3 uN", dim::kForce), 3.3e-6);
  EXPECT_EQ(si("1 g/cm^3", dim::kDensity), 1000.0);
  EXPECT_EQ(si("5. um", dim::kLength), 5e-6);
  EXPECT_EQ(parse_unit("um", dim::kLength).value(), 1e-6);
}

TEST(Units, PrefixesAndSpelling) {
  expect_rel(si("20kPa", dim::kPressure), 20e3);  // no space, as typed on a command line
  expect_rel(si("5 \xC2\xB5m", dim::kLength), 5e-6);  // micro sign U+00B5
  expect_rel(si("5 \xCE\xBCm", dim::kLength), 5e-6);  // Greek mu U+03BC
  expect_rel(si("3 cm", dim::kLength), 0.03);
  expect_rel(si("2 nm", dim::kLength), 2e-9);
  expect_rel(si("300 MPa", dim::kPressure), 300e6);
  expect_rel(si("1.5 GPa", dim::kPressure), 1.5e9);
  expect_rel(si("4 pN", dim::kForce), 4e-12);
  expect_rel(si("2 mJ", dim::kEnergy), 2e-3);
  expect_rel(si("3 kW", dim::kPower), 3e3);
  expect_rel(si("-20 um", dim::kLength), -20e-6);
  expect_rel(si("+3 m", dim::kLength), 3.0);
  expect_rel(si("  .5 s  ", dim::kTime), 0.5);
  // An exact base unit wins over prefix + unit: "m" is the metre, "mm" and "ms" are milli.
  expect_rel(si("2 m", dim::kLength), 2.0);
  expect_rel(si("2 mm", dim::kLength), 2e-3);
  expect_rel(si("2 ms", dim::kTime), 2e-3);
  expect_rel(si("2 mg", dim::kMass), 2e-6);
  expect_rel(si("2 kg", dim::kMass), 2.0);
}

TEST(Units, CompoundUnits) {
  expect_rel(si("1 N*s/m", dim::kDamping), 1.0);
  expect_rel(si("3 mN*s/m", dim::kDamping), 3e-3);
  expect_rel(si("2 Pa*s", dim::kViscosity), 2.0);
  expect_rel(si("2 Pa\xC2\xB7s", dim::kViscosity), 2.0);  // middle dot
  expect_rel(si("1e4 1/s", dim::kFrequency), 1e4);
  expect_rel(si("1e4 s^-1", dim::kFrequency), 1e4);
  expect_rel(si("1 g/cm^3", dim::kDensity), 1000.0);
  expect_rel(si("1 um^3", dim::kVolume), 1e-18);
  expect_rel(si("91952 \xC2\xB5m\xC2\xB3", dim::kVolume), 91952e-18);  // µm³ as in Ladjal et al.
  expect_rel(si("2 m/s^2", dim::kAcceleration), 2.0);
  expect_rel(si("1 kPa*m^2", dim::kForce), 1000.0);
  // Everything after '/' is the denominator: W/m^2*s is W/(m^2 s) = kg s^-4.
  Result<Quantity> q = parse_quantity("1 W/m^2*s");
  ASSERT_TRUE(q.ok()) << q.error().message;
  EXPECT_EQ(q->dimension, (Dimension{1, 0, -4}));
  // Ratios of like units are dimensionless: haptic workspace and force scales.
  expect_rel(si("50 um/cm", dim::kNone), 5e-3);
  expect_rel(si("0.3 N/uN", dim::kNone), 3e5);
  expect_rel(si("90 %", dim::kNone), 0.9);
  expect_rel(si("0.49", dim::kNone), 0.49);
}

TEST(Units, UnitExpressionsGiveFactorAndDimension) {
  Result<Quantity> u = parse_unit("kg/m^3");
  ASSERT_TRUE(u.ok());
  EXPECT_EQ(u->dimension, dim::kDensity);
  EXPECT_DOUBLE_EQ(u->value, 1.0);
  Result<double> um = parse_unit("um", dim::kLength);
  ASSERT_TRUE(um.ok());
  EXPECT_DOUBLE_EQ(*um, 1e-6);
  // N = kg m s^-2 and Pa = N/m^2, checked through the exponent arithmetic.
  EXPECT_EQ(parse_unit("N")->dimension, dim::kMass * dim::kLength / power(dim::kTime, 2));
  EXPECT_EQ(parse_unit("N/m^2")->dimension, parse_unit("Pa")->dimension);
  EXPECT_EQ(parse_unit("J/s")->dimension, dim::kPower);
  EXPECT_EQ(parse_unit("Hz")->dimension, dim::kFrequency);
  Result<double> wrong = parse_unit("kPa", dim::kLength);
  ASSERT_FALSE(wrong.ok());
  EXPECT_NE(wrong.error().message.find("expected length (m)"), std::string::npos)
      << wrong.error().message;
}

TEST(Units, DimensionMismatchNamesBothDimensions) {
  const std::string e = error_of("17.9 kPa", dim::kLength);
  EXPECT_NE(e.find("\"17.9 kPa\""), std::string::npos) << e;
  EXPECT_NE(e.find("pressure (Pa)"), std::string::npos) << e;
  EXPECT_NE(e.find("expected length (m)"), std::string::npos) << e;
  EXPECT_NE(error_of("1 mm/s", dim::kTime).find("speed (m/s)"), std::string::npos);
  EXPECT_NE(error_of("50 um/cm", dim::kLength).find("dimensionless"), std::string::npos);
  EXPECT_NE(error_of("90 %", dim::kLength).find("expected length"), std::string::npos);
}

TEST(Units, MissingUnitIsAnErrorExceptForZero) {
  const std::string e = error_of("56", dim::kLength);
  EXPECT_NE(e.find("missing unit"), std::string::npos) << e;
  EXPECT_NE(e.find("length (m)"), std::string::npos) << e;
  EXPECT_DOUBLE_EQ(si("0", dim::kLength), 0.0);  // zero is zero in every unit
  EXPECT_DOUBLE_EQ(si("-0.0", dim::kPressure), 0.0);
}

TEST(Units, MalformedInputGivesOneLineErrors) {
  const std::string unknown = error_of("56 furlongs", dim::kLength);
  EXPECT_NE(unknown.find("unknown unit 'furlongs'"), std::string::npos) << unknown;
  // A product written without '*' is not guessed.
  EXPECT_NE(error_of("1 Ns", dim::kDamping).find("unknown unit 'Ns'"), std::string::npos);
  EXPECT_NE(error_of("1 N s", dim::kDamping).find("join units"), std::string::npos);
  EXPECT_NE(error_of("1 m/s/s", dim::kAcceleration).find("more than one '/'"), std::string::npos);
  EXPECT_NE(error_of("1 m^", dim::kLength).find("exponent"), std::string::npos);
  EXPECT_NE(error_of("1 m^123", dim::kLength).find("exponent"), std::string::npos);
  EXPECT_NE(error_of("1 m*", dim::kLength).find("ends with an operator"), std::string::npos);
  EXPECT_NE(error_of("abc", dim::kLength).find("expected a number"), std::string::npos);
  EXPECT_NE(error_of("", dim::kLength).find("expected a number"), std::string::npos);
  EXPECT_NE(error_of("inf m", dim::kLength).find("finite"), std::string::npos);
  EXPECT_NE(error_of("1e999 m", dim::kLength).find("out of range"), std::string::npos);
  EXPECT_NE(error_of("1e300 Gm^3", dim::kVolume).find("out of range"), std::string::npos);
  EXPECT_NE(error_of("1 %m", dim::kLength).find("unknown unit"), std::string::npos);
  for (const char* text : {"1 m/s/s", "56 furlongs", "1 m^", "", "1 N s"}) {
    Result<Quantity> q = parse_quantity(text);
    ASSERT_FALSE(q.ok()) << text;
    EXPECT_EQ(q.error().message.find('\n'), std::string::npos) << text;
  }
}

TEST(Units, NamesAndFormatting) {
  EXPECT_EQ(dimension_name(dim::kPressure), "pressure (Pa)");
  EXPECT_EQ(dimension_name(dim::kNone), "dimensionless");
  EXPECT_EQ(si_unit(dim::kDensity), "kg/m^3");
  EXPECT_EQ(si_unit(dim::kDamping), "N*s/m");
  // Unnamed dimensions print as an SI expression that parses back to the same dimension.
  const Dimension odd{1, -4, 0};
  EXPECT_EQ(si_unit(odd), "kg*m^-4");
  EXPECT_EQ(parse_unit(si_unit(odd))->dimension, odd);
  // The shortest form (0) and 17 significant digits both round-trip exactly.
  for (Dimension d : {dim::kLength, dim::kPressure, dim::kDensity, dim::kFrequency,
                      dim::kDamping, dim::kStiffness, dim::kNone, odd}) {
    const double value = 1.0 / 3.0 * 17.9e3;
    for (int digits : {0, 17}) {
      Result<double> back = parse_quantity(format_quantity(value, d, digits), d);
      ASSERT_TRUE(back.ok()) << format_quantity(value, d, digits) << ": " << back.error().message;
      EXPECT_EQ(*back, value) << si_unit(d);
    }
  }
  EXPECT_EQ(format_quantity(17.9e3, dim::kPressure), "17900 Pa");
  EXPECT_EQ(format_quantity(3.3, dim::kForce, 0), "3.3 N");
  EXPECT_EQ(format_quantity(1e-5, dim::kLength, 0), "1e-05 m");
}

}  // namespace
}  // namespace zona
