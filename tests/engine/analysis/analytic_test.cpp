// Hajiyavand et al. 2019's analytic models against values computed by hand from the printed formulas.
#include "engine/analysis/analytic.h"

#include <gtest/gtest.h>

#include <cmath>

namespace zona {
namespace {

// Hajiyavand et al. 2019's chorion: 3 um thick, Poisson 0.5 (section 3.2), cell radius 400 um and pipette
// radius 30 um (Table 5, section 2.3).
PointLoadMembrane seed002_chorion() {
  PointLoadMembrane m;
  m.thickness = 3e-6;
  m.radius = 400e-6;
  m.load_radius = 30e-6;
  m.poisson = 0.5;
  return m;
}

TEST(Analytic, MaxwellWiechertEq6AndRampByHand) {
  MaxwellWiechertParams p;
  p.k1 = 3.0;
  p.k[0] = 2.0;
  p.c[0] = 4.0;  // arm 3 absent (c = 0)
  // F = 3 * 2e-3 + 4 * 1e-3 * exp(-2 * 2 / 4) = 0.006 + 0.004 / e.
  EXPECT_NEAR(maxwell_wiechert_force(p, 2e-3, 1e-3, 2.0), 0.00747151776468577, 1e-15);
  // The ramp X = V t: 0.006 + 0.004 (1 - 1 / e).
  EXPECT_NEAR(maxwell_wiechert_ramp_force(p, 1e-3, 2.0), 0.00852848223531423, 1e-15);
  // At t = 0 eq. 6's arms carry c V each, the ramp's nothing; late, the ramp's carry c V.
  EXPECT_DOUBLE_EQ(maxwell_wiechert_force(p, 0.0, 1e-3, 0.0), 4e-3);
  EXPECT_DOUBLE_EQ(maxwell_wiechert_ramp_force(p, 1e-3, 0.0), 0.0);
  EXPECT_NEAR(maxwell_wiechert_ramp_force(p, 1e-3, 100.0) - 3.0 * 0.1, 4e-3, 1e-12);
}

TEST(Analytic, SeedEq8ByHand) {
  // [0.3 * 300 + 0.125 * 0.1 * exp(-0.356 * 3 / 0.125) + 4.74 * 0.1 * exp(-0.668 * 3 / 4.74)]
  // / 100 = 0.903105765 mN (X in um, V in mm/s, t in s).
  EXPECT_NEAR(seed002_eq8_force(300e-6, 1e-4, 3.0), 0.9031057653117864e-3, 1e-15);
  // Table 2's constants as printed.
  const MaxwellWiechertParams t = seed002_table2();
  EXPECT_DOUBLE_EQ(t.k1, 0.3);
  EXPECT_DOUBLE_EQ(t.k[0], 0.356);
  EXPECT_DOUBLE_EQ(t.k[1], 0.668);
  EXPECT_DOUBLE_EQ(t.c[0], 0.125);
  EXPECT_DOUBLE_EQ(t.c[1], 4.74);
  // Faster at the same deformation and time: more force (the dashpots).
  EXPECT_GT(seed002_eq8_force(300e-6, 1e-3, 0.3), seed002_eq8_force(300e-6, 1e-4, 0.3));
}

TEST(Analytic, PointLoadFactorByHand) {
  // zeta = 30 / 400: (3 - 4 z^2 + z^4 + 2 ln z^2) / ((1 - z^2)(1 - z^2 + ln z^2)^3).
  EXPECT_NEAR(point_load_factor(0.075), 0.10122015484024971, 1e-14);
  EXPECT_NEAR(point_load_factor(0.5), 3.675167422969298, 1e-12);
  EXPECT_TRUE(std::isnan(point_load_factor(0.0)));
  EXPECT_TRUE(std::isnan(point_load_factor(1.0)));
  // Positive over (0, 1) and growing with the loaded fraction (a wider tip is stiffer).
  double last = 0;
  for (double z = 0.01; z < 0.99; z += 0.01) {
    const double k = point_load_factor(z);
    EXPECT_GT(k, last) << z;
    last = k;
  }
}

TEST(Analytic, PointLoadForwardAndInverse) {
  const PointLoadMembrane m = seed002_chorion();
  ASSERT_TRUE(check_point_load_membrane(m).ok());
  // 2 pi * 1.32 MPa * 3 um * (300 um)^3 / ((400 um)^2 * 0.5) * 0.10122 = 0.84999 mN.
  EXPECT_NEAR(point_load_force(m, 1.32e6, 300e-6), 0.8499939387109278e-3, 1e-15);
  // Cubic in w, linear in E; the two inverses undo the forward model.
  EXPECT_NEAR(point_load_force(m, 1.32e6, 150e-6) * 8.0, point_load_force(m, 1.32e6, 300e-6), 1e-15);
  EXPECT_NEAR(point_load_modulus(m, 0.8499939387109278e-3, 300e-6), 1.32e6, 1e-6);
  EXPECT_NEAR(point_load_deformation(m, 1.32e6, 0.8499939387109278e-3), 300e-6, 1e-15);
}

TEST(Analytic, Seed002ChorionModulusFromItsNumbers) {
  // Hajiyavand et al. 2019's Table 1 is missing from the text; its numbers in words: deformation at puncture
  // falls by ~34 % from 0.05 to 0.6 mm/s, "almost 100 um" (section 3.1), so ~294 um at
  // 0.05 mm/s; eq. 8 gives the force there (t = X / V). Eq. 7 with the chorion (3 um, Poisson
  // 0.5, radius 400 um, tip 30 um) then gives E = 1.456 MPa by hand, within Table 3's
  // 1.32 +- 0.24 MPa.
  const double deformation = 100e-6 / 0.34;
  const double speed = 0.05e-3;
  const double force = seed002_eq8_force(deformation, speed, deformation / speed);
  EXPECT_NEAR(force, 0.8833874224691225e-3, 1e-15);
  const double young = point_load_modulus(seed002_chorion(), force, deformation);
  EXPECT_NEAR(young, 1.4558271999490198e6, 1.0);
  EXPECT_GT(young, 1.32e6 - 0.24e6);
  EXPECT_LT(young, 1.32e6 + 0.24e6);
}

TEST(Analytic, CheckPointLoadMembraneNamesTheField) {
  PointLoadMembrane m = seed002_chorion();
  m.load_radius = 500e-6;
  const Status s = check_point_load_membrane(m);
  ASSERT_FALSE(s.ok());
  EXPECT_NE(s.error().message.find("load_radius"), std::string::npos);
  m = seed002_chorion();
  m.thickness = 0;
  EXPECT_NE(check_point_load_membrane(m).error().message.find("thickness"), std::string::npos);
}

TEST(Analytic, SpeedDependentModulusEq9) {
  // E_V = (V - 0.1) / 0.9 * 200 + 300 [MPa], V in mm/s.
  EXPECT_NEAR(speed_dependent_modulus(0.1e-3), 300e6, 1e-3);
  EXPECT_NEAR(speed_dependent_modulus(1e-3), 500e6, 1e-3);
  EXPECT_NEAR(speed_dependent_modulus(0.6e-3), 411.1111111111111e6, 1e-3);  // Table 5: ~400
  EXPECT_NEAR(speed_dependent_modulus(0.05e-3), 288.8888888888889e6, 1e-3);
  SpeedModulusLaw law{1.0, 10.0, 3.0, 30.0};
  EXPECT_DOUBLE_EQ(speed_dependent_modulus(2.0, law), 20.0);
}

}  // namespace
}  // namespace zona
