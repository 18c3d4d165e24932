// Hajiyavand et al. 2019's analytic models of zebrafish embryo injection, as library functions in SI units:
// the Maxwell-Wiechert force law (eq. 6, calibrated as eq. 8 with Table 2), the point-load
// membrane model of the chorion modulus (eq. 7, Sun et al. 2003) and its inverse, and the
// speed-dependent Young's modulus of the FE model (eq. 9).
//
// The seed states no units for eq. 8 and Table 2; the reading used here, and why, is written at
// seed002_eq8_force(). docs/validation.md (zebrafish) shows the numbers.
#pragma once

#include "engine/core/base.h"

namespace zona {

/// A Maxwell-Wiechert solid (Hajiyavand et al. 2019 Fig. 4): a spring k1 in parallel with two Maxwell arms
/// (spring k_i in series with dashpot c_i). Any consistent unit set works; SI: N/m and N*s/m.
struct MaxwellWiechertParams {
  double k1 = 0;               ///< parallel spring [N/m]
  double k[2] = {0, 0};        ///< springs of the Maxwell arms 2 and 3 [N/m]
  double c[2] = {0, 0};        ///< dashpots of the Maxwell arms 2 and 3 [N*s/m]
};

/// Hajiyavand et al. 2019 eq. 6 as printed: F = k1 X + sum_i c_i V exp(-k_i t / c_i), with X the deformation
/// [m], V the injection speed [m/s] and t the time [s]. Returns the force [N]. An arm with
/// c_i <= 0 contributes nothing.
double maxwell_wiechert_force(const MaxwellWiechertParams& params, double deformation,
                              double speed, double time);

/// The same solid's exact response to a ramp at constant speed V from t = 0 (X = V t):
/// F = k1 X + sum_i c_i V (1 - exp(-k_i t / c_i)), the textbook solution of eqs. 1-2 per arm
/// (eq. 6 writes the arms' relaxation factor instead of its complement). Force [N].
double maxwell_wiechert_ramp_force(const MaxwellWiechertParams& params, double speed, double time);

/// Hajiyavand et al. 2019 Table 2 as printed (K1, K2, K3, C2, C3 = 0.3, 0.356, 0.668, 0.125, 4.74), in the
/// units of eq. 8 (see seed002_eq8_force), not SI.
MaxwellWiechertParams seed002_table2();

/// Hajiyavand et al. 2019 eq. 8, the calibrated Maxwell-Wiechert law:
///   F = [0.3 X + 0.125 V exp(-0.356 t / 0.125) + 4.74 V exp(-0.668 t / 4.74)] / 100,
/// read with X in um, V in mm/s, t in s and F in mN (the seed states no units; this reading
/// gives 0.9 mN at 300 um, the scale of its Figs. 11-12, while V in um/s would make the speed
/// terms tens of mN at 1 mm/s). Takes and returns SI: deformation [m], speed [m/s], time [s],
/// force [N].
double seed002_eq8_force(double deformation, double speed, double time);

/// Geometry and material of Hajiyavand et al. 2019 eq. 7's point-load membrane (Sun et al. 2003): a membrane
/// of thickness h spanning radius a, loaded over radius c (the pipette tip), zeta = c / a.
struct PointLoadMembrane {
  double thickness = 0;     ///< membrane (chorion) thickness h [m]
  double radius = 0;        ///< membrane radius a (the cell's) [m]
  double load_radius = 0;   ///< radius of the loaded zone c (the pipette tip's) [m], (0, radius)
  double poisson = 0.5;     ///< Poisson's ratio (theta in the seed) [-], < 1
};

/// The geometric factor of eq. 7 in brackets:
/// (3 - 4 z^2 + z^4 + 2 ln z^2) / ((1 - z^2) (1 - z^2 + ln z^2)^3), z = zeta in (0, 1) [-].
/// Positive for every zeta in (0, 1); NaN outside.
double point_load_factor(double zeta);

/// Checks a membrane description: thickness, radius > 0, 0 < load_radius < radius, poisson < 1.
/// Errors name the field.
Status check_point_load_membrane(const PointLoadMembrane& membrane);

/// Hajiyavand et al. 2019 eq. 7: F = 2 pi E h w^3 / (a^2 (1 - nu)) * point_load_factor(c / a). Young's
/// modulus E [Pa], deformation depth w [m]; returns the force [N].
double point_load_force(const PointLoadMembrane& membrane, double young, double deformation);

/// Eq. 7 solved for E from a measured force [N] and deformation depth [m] > 0. Returns [Pa].
double point_load_modulus(const PointLoadMembrane& membrane, double force, double deformation);

/// Eq. 7 solved for the deformation depth [m] at a force [N] >= 0 and modulus [Pa] > 0.
double point_load_deformation(const PointLoadMembrane& membrane, double young, double force);

/// A Young's modulus linear in injection speed through two calibration points (Hajiyavand et al. 2019
/// eq. 9's form), extrapolated beyond them.
struct SpeedModulusLaw {
  double speed0 = 1e-4;   ///< first calibration speed [m/s] (Hajiyavand et al. 2019: 0.1 mm/s)
  double young0 = 300e6;  ///< modulus at speed0 [Pa] (Hajiyavand et al. 2019 Table 4: 300 MPa)
  double speed1 = 1e-3;   ///< second calibration speed [m/s] (Hajiyavand et al. 2019: 1 mm/s)
  double young1 = 500e6;  ///< modulus at speed1 [Pa] (Hajiyavand et al. 2019 Table 4: 500 MPa)
};

/// Hajiyavand et al. 2019 eq. 9, E_V = (V - 0.1) / 0.9 * 200 + 300 (V in mm/s, E in MPa), in its general
/// form: the law's modulus at `speed` [m/s], in [Pa]. The default law is the seed's.
double speed_dependent_modulus(double speed, const SpeedModulusLaw& law = {});

}  // namespace zona
