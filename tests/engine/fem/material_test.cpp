// Materials: Lame coefficients, wave speed, validation messages.
#include "engine/fem/material.h"

#include <gtest/gtest.h>

#include <cmath>

namespace zona {
namespace {

TEST(Material, LameCoefficientsOfTheMouseZona) {
  // Ladjal et al. Table I: E = 17.9 kPa, nu = 0.49.
  const Lame l = lame_from_young_poisson(17.9e3, 0.49);
  EXPECT_NEAR(l.mu, 17.9e3 / 2.98, 1e-9);
  EXPECT_NEAR(l.lambda, 17.9e3 * 0.49 / (1.49 * 0.02), 1e-7);
  // Back to E and nu: E = mu (3 lambda + 2 mu) / (lambda + mu), nu = lambda / (2 (lambda + mu)).
  EXPECT_NEAR(l.mu * (3 * l.lambda + 2 * l.mu) / (l.lambda + l.mu), 17.9e3, 1e-8);
  EXPECT_NEAR(l.lambda / (2 * (l.lambda + l.mu)), 0.49, 1e-14);
}

TEST(Material, DilatationalWaveSpeed) {
  const Lame l = lame_from_young_poisson(17.9e3, 0.49);
  const double c = dilatational_wave_speed(l, 1000.0);
  EXPECT_NEAR(c, std::sqrt((l.lambda + 2 * l.mu) / 1000.0), 1e-12);
  EXPECT_NEAR(c, 17.5, 0.1);  // m/s: a 1 um element then needs dt below ~6e-8 s
  // Near incompressibility the speed explodes: nu 0.499 is ~3.2x faster than 0.49.
  const double c999 = dilatational_wave_speed(lame_from_young_poisson(17.9e3, 0.499), 1000.0);
  EXPECT_GT(c999 / c, 3.0);
}

TEST(Material, BadMaterialsAreRefusedWithOneLine) {
  Material m;
  EXPECT_TRUE(validate_material(m, "zona").ok());
  m.poisson = 0.5;
  Status s = validate_material(m, "region 2 (zona)");
  ASSERT_FALSE(s.ok());
  EXPECT_NE(s.error().message.find("region 2 (zona)"), std::string::npos);
  EXPECT_NE(s.error().message.find("0.5"), std::string::npos);
  EXPECT_NE(s.error().message.find("incompressible"), std::string::npos);
  EXPECT_EQ(s.error().message.find('\n'), std::string::npos);
  m.poisson = -0.1;
  EXPECT_FALSE(validate_material(m, "m").ok());
  m.poisson = 0.3;
  for (double e : {0.0, -1.0, std::nan(""), HUGE_VAL}) {
    m.young = e;
    s = validate_material(m, "m");
    ASSERT_FALSE(s.ok()) << e;
    EXPECT_NE(s.error().message.find("Young"), std::string::npos);
  }
  m.young = 1e3;
  m.density = 0;
  EXPECT_FALSE(validate_material(m, "m").ok());
  m.density = 1000;
  m.damping = -1;
  EXPECT_FALSE(validate_material(m, "m").ok());
}

}  // namespace
}  // namespace zona
