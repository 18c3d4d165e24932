// A step's status flags (health, refusals, the quasi-static check), shared by every model's
// step (the FEM integrator, the particle model, the injection job) and by the layers above
// them: kept here, below engine/sim/ and engine/particles/, so that dependencies go one way.
#pragma once

#include <cstdint>

namespace zona {

/// Bits of a step's status; 0 is a healthy step.
enum StepStatusBits : uint32_t {
  kStepOk = 0,
  /// A displacement update or the energy was not finite. The state was NOT advanced: it still
  /// holds u_n and u_{n-1}; diag.first_nonfinite names a vertex.
  kStepNonFinite = 1u << 0,
  /// Kinetic + elastic energy exceeded Model::energy_blowup_factor times the energy budget
  /// (initial energy + work in): the scheme is unstable (dt too large for the current
  /// stiffness). The state was advanced and is finite.
  kStepEnergyBlowUp = 1u << 1,
  /// Some element has det F <= 0 at u_n (diag.inverted_count, diag.first_inverted).
  kStepInvertedElement = 1u << 2,
  /// Some SVK element has a principal stretch below 1/sqrt(3) at u_n: it resists less the more
  /// it is squeezed and may invert (diag.collapsing_count, diag.first_collapsing).
  kStepCollapsingElement = 1u << 3,
  /// The inversion-safe SVK clamped some element's stretches (diag.clamped_count).
  kStepClampedElement = 1u << 4,
  /// Model::dt is above Model::dt_critical. Without the model's unsafe override the step is
  /// refused and the state not advanced; with it the step runs and carries this flag.
  kStepDtAboveCritical = 1u << 5,
  /// The injection job (engine/sim/job.h) found a surface point deeper inside the needle than
  /// JobParams::needle_breach_depth before puncture: the surface let the tool through. The
  /// state was advanced and is finite; the job halts.
  kStepToolBreach = 1u << 6,
  /// A quasi-static experiment's state failed the quasi-static check (engine/sim/quasi_static.h:
  /// the holder does not carry the needle's load, or the cell's energy is motion): no puncture
  /// is taken from it, and the run ends with an error. The state is healthy; the run goes on.
  kStepNotQuasiStatic = 1u << 7,
};

/// OR of StepStatusBits.
using StepStatus = uint32_t;

/// Flags after which the state was not advanced.
inline constexpr StepStatus kStepNotAdvanced = kStepNonFinite;

/// Flags of a state that failed its health check: nothing from it is a result (no puncture, no
/// frame, no haptic sample).
inline constexpr StepStatus kStepFailed = kStepNonFinite | kStepEnergyBlowUp | kStepToolBreach;

}  // namespace zona
