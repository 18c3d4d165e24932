// Selective mass scaling: add mass only where small elements limit the explicit step.
//
// Uniform mass scaling (ModelDesc::mass_scaling / target_dt) multiplies every mass, so the
// slowest modes of the cell slow down as much as the fastest: a cell mesh refined at the
// puncture site (1.5 um elements, slivers of 0.5 um altitude where the surface cuts the
// lattice) next to 5 um bulk elements needs a scaling that makes the whole cell sluggish, and
// a quasi-static insertion then takes ~10^5 steps. Selective scaling (the per-element mass
// scaling of explicit FE codes, e.g. LS-DYNA's DT2MS < 0) raises each vertex's mass just enough
// for every element around it to reach the target step: the bulk, which carries the cell's
// low modes, is scaled least, the few small elements most. docs/injection.md has the numbers.
#pragma once

#include <vector>

#include "engine/core/base.h"
#include "engine/fem/model.h"

namespace zona {

/// Element stiffness measure of the eigenvalue bound: lambda sum_j |g_j|^2 + 2 mu
/// lambda_max(sum_j g_j g_j^T) [Pa/m^2]; the element is stable for dt <= sqrt(rho_e / S_e), rho_e
/// its corners' smallest mass per lumped volume (build_model's critical step, the scaling here).
double element_stiffness_measure(const TetShape<double>& shape, const Lame& lame);

/// What selective scaling did.
struct SelectiveScalingReport {
  double mass_before = 0;      ///< total mass before [kg]
  double mass_after = 0;       ///< total mass after [kg]
  double max_vertex_factor = 1;  ///< largest per-vertex mass factor [-]
  double scaled_fraction = 0;  ///< fraction of vertices whose mass was raised [-]
};

/// Raises vertex masses so that the element-bound critical step reaches target_dt / dt_safety
/// (element e is stable for dt <= sqrt(rho_e / (lambda sum|g|^2 + 2 mu lambda_max(G G^T))), with
/// rho_e its corners' smallest mass per lumped volume; the vertex masses are raised until every
/// element around them meets the target), then recomputes damping (the same rate per vertex),
/// the critical step, dt = dt_safety * dt_critical and the update coefficients. The model's
/// mass_scaling becomes the total mass ratio. A model already faster than the target is left
/// as it is. Errors: target_dt <= 0, dt_safety outside (0, 1]. Call right after build_model.
/// `threads`: the element measures in ranges side by side (the same result for any count).
Result<SelectiveScalingReport> apply_selective_mass_scaling(Model& model, double target_dt,
                                                            double dt_safety, int threads = 1);

/// The total mass [kg] apply_selective_mass_scaling would give at target_dt (the model is not
/// changed): each vertex max(m, (target_dt / dt_safety)^2 q) with q its elements' largest
/// stiffness measure times its lumped volume. `need` caches q per vertex between calls (filled
/// when empty).
double selective_scaling_total_mass(const Model& model, double target_dt, double dt_safety,
                                    std::vector<double>* need, int threads = 1);

/// Each vertex's lumped volume [m^3]: a quarter of every tetrahedron around it, (vertex_count).
std::vector<double> vertex_lumped_volumes(const Model& model);

/// Centred-difference update coefficients of a vertex of mass M [kg] and damping gamma [kg/s] at
/// step dt [s]: a = 2M / (M + gamma dt/2), b = (M - gamma dt/2) / (M + gamma dt/2),
/// c = dt^2 / (M + gamma dt/2); a massless vertex (no tetrahedron uses it) stays where it is.
VertexCoefficients vertex_coefficients(double mass, double gamma, double dt);

/// Sets vertex v's mass [kg], keeping its damping rate gamma / M, and its update coefficients
/// at the model's step.
void set_vertex_mass(Model& model, size_t v, double mass);

}  // namespace zona
