// Hajiyavand et al. 2019's analytic models: Maxwell-Wiechert force, point-load membrane, speed-dependent modulus.
#include "engine/analysis/analytic.h"

#include <cmath>
#include <limits>
#include <numbers>

namespace zona {

double maxwell_wiechert_force(const MaxwellWiechertParams& p, double deformation, double speed,
                              double time) {
  double force = p.k1 * deformation;
  for (int i = 0; i < 2; ++i)
    if (p.c[i] > 0) force += p.c[i] * speed * std::exp(-p.k[i] * time / p.c[i]);
  return force;
}

double maxwell_wiechert_ramp_force(const MaxwellWiechertParams& p, double speed, double time) {
  double force = p.k1 * speed * time;
  // -expm1 keeps 1 - exp(-x) exact for the small x of a short ramp.
  for (int i = 0; i < 2; ++i)
    if (p.c[i] > 0) force += p.c[i] * speed * -std::expm1(-p.k[i] * time / p.c[i]);
  return force;
}

MaxwellWiechertParams seed002_table2() {
  MaxwellWiechertParams p;
  p.k1 = 0.3;
  p.k[0] = 0.356;
  p.k[1] = 0.668;
  p.c[0] = 0.125;
  p.c[1] = 4.74;
  return p;
}

double seed002_eq8_force(double deformation, double speed, double time) {
  // Eq. 8 is eq. 6 with Table 2's numbers and a factor 1/100, in the units of its reading:
  // X [um], V [mm/s], t [s] -> F [mN].
  const double x_um = deformation * 1e6;
  const double v_mm_s = speed * 1e3;
  const double f_mn = maxwell_wiechert_force(seed002_table2(), x_um, v_mm_s, time) / 100.0;
  return f_mn * 1e-3;
}

double point_load_factor(double zeta) {
  if (!(zeta > 0 && zeta < 1)) return std::numeric_limits<double>::quiet_NaN();
  const double z2 = zeta * zeta;
  const double ln_z2 = std::log(z2);
  const double bracket = 1.0 - z2 + ln_z2;  // < 0 for every zeta in (0, 1)
  return (3.0 - 4.0 * z2 + z2 * z2 + 2.0 * ln_z2) / ((1.0 - z2) * bracket * bracket * bracket);
}

Status check_point_load_membrane(const PointLoadMembrane& m) {
  if (!(m.thickness > 0)) return make_error("point-load membrane: thickness must be > 0 m, got %g", m.thickness);
  if (!(m.radius > 0)) return make_error("point-load membrane: radius must be > 0 m, got %g", m.radius);
  if (!(m.load_radius > 0 && m.load_radius < m.radius))
    return make_error("point-load membrane: load_radius must be in (0, radius = %g m), got %g",
                      m.radius, m.load_radius);
  if (!(m.poisson < 1 && m.poisson > -1))
    return make_error("point-load membrane: poisson must be in (-1, 1), got %g", m.poisson);
  return Status::ok_status();
}

namespace {
// F / (E w^3) of eq. 7 [1/m^2].
double force_per_modulus_cubed(const PointLoadMembrane& m) {
  return 2.0 * std::numbers::pi * m.thickness / (m.radius * m.radius * (1.0 - m.poisson)) *
         point_load_factor(m.load_radius / m.radius);
}
}  // namespace

double point_load_force(const PointLoadMembrane& m, double young, double deformation) {
  return force_per_modulus_cubed(m) * young * deformation * deformation * deformation;
}

double point_load_modulus(const PointLoadMembrane& m, double force, double deformation) {
  return force / (force_per_modulus_cubed(m) * deformation * deformation * deformation);
}

double point_load_deformation(const PointLoadMembrane& m, double young, double force) {
  return std::cbrt(force / (force_per_modulus_cubed(m) * young));
}

double speed_dependent_modulus(double speed, const SpeedModulusLaw& law) {
  return law.young0 + (speed - law.speed0) * (law.young1 - law.young0) / (law.speed1 - law.speed0);
}

}  // namespace zona
