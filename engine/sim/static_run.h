// The static solver's run: the cell's equilibrium at each needle position (docs/static.md).
//
//   suction   the suction ramped in over solver.suction_steps load steps, the needle still
//   travel    load steps in needle travel, adaptive (halved where Newton fails, grown where it
//             converges fast), each one projected Newton on the total energy (newton.h):
//             elastic law with nodal pressure and the volume barrier, the needle's penalty on
//             the surface triangles' quadrature, the rim's penalty and friction (lagged, an
//             incremental potential), the suction as a dead load, the regulariser
//             (inertia_term.h)
//   rows      exactly at 10, 20, 30 and 40 um of deformation (a secant in travel), and at every
//             load step
//   puncture  the criterion's crossing bisected in travel to solver.puncture_tolerance; then
//             the tip load released (puncture.force_drop) and the travel continued
//   commit    after each accepted step: friction anchors, velocity, the sample
//
// A load step that does not converge at solver.min_travel_step, a needle through the surface
// before the puncture and a holder whose every contact slips end the run with the reason and
// no puncture (RunResult::stopped_early).
#pragma once

#include "engine/sim/simulation.h"

namespace zona {

/// Runs a simulation whose scene asks for solver.method "static"; called by run_simulation.
RunResult run_static(Simulation& sim, const RunOptions& options);

/// Why a scene cannot run static (its law, model, contact or backend), or ok.
Status check_static_scene(const Scene& scene);

}  // namespace zona
