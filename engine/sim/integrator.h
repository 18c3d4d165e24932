// Explicit dynamics (Ladjal et al. eq. 7): the centred-difference step with lumped mass and
// mass-proportional damping, its health flags, sub-stepping over a frame, and dynamic
// relaxation (kinetic damping) for quasi-static answers.
#pragma once

#include <cstdint>
#include <string>

#include "engine/fem/model.h"
#include "engine/fem/state.h"
#include "engine/fem/step_status.h"

namespace zona {

/// One explicit step of length model.dt: internal forces at u_n, the centred-difference update
/// of free vertices, fixed vertices at zero, prescribed vertices at their targets
/// (state.prescribed_displacement, to be reached at t_{n+1}), loads from state.external_force.
/// Fills state.diag. Never allocates, never throws.
StepStatus step(const Model& model, State& state);

/// One line describing a status with the numbers from state.diag ("ok" for 0).
std::string describe_step_status(StepStatus status, const Model& model, const State& state);

/// Result of advance().
struct AdvanceResult {
  StepStatus status = kStepOk;  ///< OR of the statuses of the steps taken
  int64_t steps = 0;            ///< sub-steps taken
  double time_advanced = 0;     ///< steps * dt [s] (>= the duration asked, < duration + dt)
};

/// Advances by `duration` [s] in sub-steps of model.dt (the model's step is never exceeded:
/// a frame longer than dt is split, and the count is reported). Stops early at a step that
/// was not advanced (non-finite or refused).
AdvanceResult advance(const Model& model, State& state, double duration);

/// How relax_to_equilibrium removes kinetic energy.
enum class RelaxMethod : int32_t {
  /// Adaptive dynamic relaxation (Underwood 1983): a global damping rate c = 2 omega_1, with
  /// omega_1^2 the Rayleigh quotient of the last increment, -du.df / du.M du; the slowest mode
  /// is damped critically. Default: ~20x fewer steps than kinetic damping (docs/physics.md).
  kAdaptiveDamping = 0,
  /// Kinetic damping (Cundall): undamped steps, every velocity zeroed at each kinetic-energy peak.
  kKineticDamping = 1,
};

/// Options of relax_to_equilibrium.
struct RelaxOptions {
  RelaxMethod method = RelaxMethod::kAdaptiveDamping;
  /// Converged when |f_el + f_ext| over free vertices <= relative_tolerance * the reference
  /// force norm (loads and constraint forces) ...
  double relative_tolerance = 1e-8;
  /// ... or <= absolute_tolerance [N].
  double absolute_tolerance = 0;
  int64_t max_steps = 1000000;  ///< give up after this many steps
};

/// Result of relax_to_equilibrium.
struct RelaxResult {
  StepStatus status = kStepOk;     ///< OR of the step statuses
  bool converged = false;
  int64_t steps = 0;
  int64_t kinetic_resets = 0;      ///< times the velocity was zeroed at a kinetic-energy peak
  double residual_norm = 0;        ///< [N]
  double reference_force_norm = 0; ///< [N]
};

/// Dynamic relaxation to the static equilibrium f_el(u) + f_ext = 0 of the free vertices, by
/// explicit pseudo-time steps of model.dt with the damping of `options.method` (the model's own
/// damping is not used); stops when the force residual is small. The static answer does not
/// depend on masses, mass scaling or dt. Loads and prescribed targets are held at their current
/// values; prescribed vertices are first moved to their targets. On return state.diag holds the
/// residual, the element health and the constraint force of the final configuration.
/// Allocates one scratch array per call (not a step path).
RelaxResult relax_to_equilibrium(const Model& model, State& state, const RelaxOptions& options);

}  // namespace zona
