// Isotropic elastic materials: Young's modulus and Poisson's ratio to Lame coefficients, with
// validation, and the dilatational wave speed that sets the explicit stable time step.
#pragma once

#include <cmath>
#include <string>

#include "engine/core/base.h"

namespace zona {

/// An isotropic elastic material as a scene or a user gives it (SI units).
struct Material {
  double young = 17.9e3;  ///< Young's modulus E [Pa] (Ladjal et al. Table I, mouse zona pellucida)
  double poisson = 0.49;  ///< Poisson's ratio nu [-], in [0, 0.5)
  double density = 1000;  ///< mass density rho [kg/m^3] (water-like cytoplasm)
  /// Mass-proportional damping coefficient alpha [1/s]: the damping force on a vertex is
  /// -alpha M v (Ladjal et al. eq. 7 with gamma = alpha M). 0 is undamped.
  double damping = 0;
};

/// Lame coefficients [Pa].
struct Lame {
  double lambda = 0;  ///< first Lame coefficient [Pa]
  double mu = 0;      ///< shear modulus [Pa]
};

/// Lame coefficients of (E, nu) with no checks; use validate_material first for user input.
/// lambda = E nu / ((1 + nu)(1 - 2 nu)), mu = E / (2 (1 + nu)).
ZONA_HOST_DEVICE ZONA_INLINE Lame lame_from_young_poisson(double young, double poisson) {
  return {young * poisson / ((1.0 + poisson) * (1.0 - 2.0 * poisson)),
          young / (2.0 * (1.0 + poisson))};
}

/// P-wave modulus lambda + 2 mu [Pa]: the stiffness that governs dilatational waves.
ZONA_HOST_DEVICE ZONA_INLINE double p_wave_modulus(Lame lame) { return lame.lambda + 2.0 * lame.mu; }

/// Dilatational (P) wave speed c_d = sqrt((lambda + 2 mu) / rho) [m/s]. It grows without
/// bound as nu -> 0.5 (lambda -> infinity), which is why the stable step shrinks for nearly
/// incompressible cells: nu = 0.49 gives c_d = 4.1 sqrt(E / rho), nu = 0.499 gives 13 sqrt(E/rho).
ZONA_HOST_DEVICE ZONA_INLINE double dilatational_wave_speed(Lame lame, double density) {
  return std::sqrt(p_wave_modulus(lame) / density);
}

/// Checks a material given by a user or a scene; `what` names it in the message (e.g.
/// "region 2 (zona)"). Rejects: E <= 0 or non-finite, nu outside [0, 0.5) (nu = 0.5 is
/// incompressible: lambda is infinite and no explicit step is stable), density <= 0 or
/// non-finite, damping < 0 or non-finite.
inline Status validate_material(const Material& m, const std::string& what) {
  if (!(std::isfinite(m.young) && m.young > 0))
    return make_error("%s: Young's modulus must be > 0 Pa, got %g", what.c_str(), m.young);
  if (!(std::isfinite(m.poisson) && m.poisson >= 0 && m.poisson < 0.5)) {
    if (m.poisson == 0.5)
      return make_error(
          "%s: Poisson's ratio 0.5 (incompressible) is not supported: lambda is infinite and no "
          "explicit step is stable; use e.g. 0.49 or 0.499",
          what.c_str());
    return make_error("%s: Poisson's ratio must be in [0, 0.5), got %g", what.c_str(), m.poisson);
  }
  if (!(std::isfinite(m.density) && m.density > 0))
    return make_error("%s: density must be > 0 kg/m^3, got %g", what.c_str(), m.density);
  if (!(std::isfinite(m.damping) && m.damping >= 0))
    return make_error("%s: damping must be >= 0 1/s, got %g", what.c_str(), m.damping);
  return Status::ok_status();
}

}  // namespace zona
