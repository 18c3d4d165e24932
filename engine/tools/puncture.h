// The moment of the membrane's puncture, as a run reports it. The criterion (needle force, the
// zona's stretch around the tip, stored energy), the release of the tip's load over drop_time
// and the shaft's drag after it are stages of the injection step (engine/sim/job.h:
// job_puncture_test, job_follow_release, job_set_pose; docs/injection.md, "Puncture").
#pragma once

#include <cstdint>

#include "engine/core/vec.h"

namespace zona {

/// The moment of puncture.
struct PunctureRecord {
  bool punctured = false;
  int64_t step = 0;             ///< step count at puncture
  double time = 0;              ///< [s]
  double needle_travel = 0;     ///< tip travel from its start [m]
  double deformation = 0;       ///< membrane indentation at the tip [m]
  double force = 0;             ///< axial needle force [N]
  double max_strain = 0;        ///< the zona's stretch around the tip (strain criterion) [-]
  double energy = 0;            ///< stored elastic energy [J]
  Vec3d force_vector{0, 0, 0};  ///< force the needle applied to the cell [N]
};

}  // namespace zona
