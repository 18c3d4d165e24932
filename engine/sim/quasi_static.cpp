// The quasi-static check's host side: the warning line.
#include "engine/sim/quasi_static.h"

#include <cstdio>

namespace zona {

std::string quasi_static_warning(const QuasiStaticState& q, const QuasiStaticLimits& lim) {
  char line[512];
  std::snprintf(line, sizeof line,
                "not quasi-static from step %lld (t %.6g s, %.3g um of deformation, needle force "
                "%.3g uN): imbalance %.3g (limit %.3g), kinetic share %.3g (limit %.3g); the "
                "holder does not carry the needle's load, so the force is the scaled mass's "
                "inertia or damping, not the cell's. No puncture is taken from such a state; "
                "slow the needle, lower integrator.target_dt, or set integrator."
                "quasi_static_travel",
                static_cast<long long>(q.first_failed_step), q.first_failed_time,
                q.first_failed_deformation * 1e6, q.first_failed_force * 1e6,
                q.first_failed_imbalance, lim.max_imbalance, q.first_failed_kinetic_share,
                lim.max_kinetic_share);
  return line;
}

}  // namespace zona
