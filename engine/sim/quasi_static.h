// Whether an injection run was quasi-static: the measure the explicit step takes every step (the
// job's record stage on either backend), the verdict that keeps a dynamic state from being
// reported as a puncture, and the run's worst values.
//
// A quasi-static injection is an equilibrium at every needle position: what the needle pushes,
// the holding pipette (rim contact plus suction) holds. Explicit dynamics reaches it only with
// the cell's mass scaled far up, and where the scaled mass's inertia or its damping carries the
// load instead (a fast needle on a heavily scaled cell), the "force" is not the cell's. Two
// measures, taken while the needle loads the cell (before puncture):
//
//   imbalance      |F_n + F_h| / F_n, F_n the needle's axial force (resistance positive, through
//                  the load cell's filter), F_h the holding pipette's axial force on the cell
//                  through the same filter: 0 in equilibrium, about 1 when the holder feels
//                  nothing of the needle's push;
//   kinetic share  E_k / (E_k + E_el): how much of the cell's energy is motion.
//
// The imbalance is taken over max(F_n, force_floor), and both are judged only once F_n has
// reached `force_floor`: at the first touch F_n is near 0 and any disturbance (the swing that the
// suction's start leaves on a mass-scaled cell) would read as a huge ratio. docs/outputs.md gives
// the thresholds and why.
#pragma once

#include <cstdint>
#include <string>

#include "engine/core/base.h"

namespace zona {

/// Thresholds of the quasi-static check (plain data: a member of JobParams on the GPU).
/// Something is judged only where `has_holder` (the imbalance) or `max_kinetic_share` < 1.
struct QuasiStaticLimits {
  int32_t enforce = 0;             ///< experiment "quasi_static": a failed check blocks puncture
  int32_t has_holder = 0;          ///< a holding pipette's force is measured (the imbalance)
  double max_imbalance = 0.2;      ///< [-]
  double max_kinetic_share = 1.0;  ///< [-]; 1: recorded, never failed
  double force_floor = 0;          ///< needle force from which both are judged [N]
  double energy_floor = 0;         ///< energies below this are noise [J]
};

/// The check's state over a run: this step's measures, the worst before puncture, and the
/// first step that failed it.
struct QuasiStaticState {
  double imbalance = 0;      ///< this step's [-] (0 without a needle load or after puncture)
  double kinetic_share = 0;  ///< this step's [-] (0 without a needle load or after puncture)
  double worst_imbalance = 0, worst_imbalance_time = 0, worst_imbalance_deformation = 0;
  double worst_kinetic_share = 0, worst_kinetic_time = 0, worst_kinetic_deformation = 0;
  int64_t failed_steps = 0;       ///< steps that failed the check
  int64_t first_failed_step = -1;
  double first_failed_time = 0, first_failed_deformation = 0, first_failed_force = 0;
  double first_failed_imbalance = 0, first_failed_kinetic_share = 0;
};

/// One step of the check, before the puncture test. `force`: the needle's filtered axial force
/// [N]; `holding`: the holder's filtered axial force on the cell [N]; energies [J]; `judged`:
/// the needle is loading the cell (not punctured). Returns true when the step fails the check
/// of an experiment that enforces it (its state must then not be taken as a puncture).
ZONA_HOST_DEVICE ZONA_INLINE bool quasi_static_step(const QuasiStaticLimits& lim,
                                                   QuasiStaticState& q, bool judged, double force,
                                                   double holding, double kinetic,
                                                   double elastic, int64_t step, double time,
                                                   double deformation) {
  q.imbalance = 0;
  q.kinetic_share = 0;
  const double scale = force > lim.force_floor ? force : lim.force_floor;
  if (!judged || !(scale > 0)) return false;
  // Measured on every loading step (force.csv shows them), over max(force, floor) so that the
  // first touch does not read as a huge ratio; judged only from the floor on.
  if (lim.has_holder) {
    const double sum = force + holding;
    q.imbalance = (sum < 0 ? -sum : sum) / scale;
  }
  const double energy = kinetic + elastic;
  if (energy > lim.energy_floor && energy > 0) q.kinetic_share = kinetic / energy;
  if (!(force >= lim.force_floor)) return false;
  if (q.imbalance > q.worst_imbalance) {
    q.worst_imbalance = q.imbalance;
    q.worst_imbalance_time = time;
    q.worst_imbalance_deformation = deformation;
  }
  if (q.kinetic_share > q.worst_kinetic_share) {
    q.worst_kinetic_share = q.kinetic_share;
    q.worst_kinetic_time = time;
    q.worst_kinetic_deformation = deformation;
  }
  // A NaN fails too (it is the health check's to report, but it is never a puncture).
  const bool failed = !(q.imbalance <= lim.max_imbalance) ||
                      (lim.max_kinetic_share < 1 && !(q.kinetic_share <= lim.max_kinetic_share));
  if (!failed) return false;
  if (q.failed_steps == 0) {
    q.first_failed_step = step;
    q.first_failed_time = time;
    q.first_failed_deformation = deformation;
    q.first_failed_force = force;
    q.first_failed_imbalance = q.imbalance;
    q.first_failed_kinetic_share = q.kinetic_share;
  }
  ++q.failed_steps;
  return lim.enforce != 0;
}

/// The warning line of a run's first failed step (host only): where, what it measured, and
/// what follows.
std::string quasi_static_warning(const QuasiStaticState& q, const QuasiStaticLimits& lim);

/// Whether the check judges anything: the holder's force is measured, or a kinetic-share
/// limit is set. Without either a run's verdict is "not measured", not "quasi-static".
inline bool quasi_static_measured(const QuasiStaticLimits& lim) {
  return lim.has_holder != 0 || lim.max_kinetic_share < 1;
}

}  // namespace zona
