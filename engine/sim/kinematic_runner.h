// The kinematic-contact step (Simulation::step1 / step2: contact sets held on the tools as
// prescribed vertices, the particle model) behind the JobRunner interface, so that one run
// driver (run_simulation) and one sample builder serve every scene: each step's NeedleReport
// becomes a JobRecord, sampled every output.sample_interval as the job's record stage samples.
#pragma once

#include <memory>

#include "engine/sim/job_runner.h"

namespace zona {

class Simulation;

/// The record of a kinematic step: the report's measures, the puncture, the quasi-static state;
/// `halted` when the step failed its health check (or ran above the critical step unasked).
JobRecord kinematic_record(const Simulation& sim);

/// A runner stepping `sim` on its kinematic path, in place; `sample_capacity` samples kept
/// between take_samples calls.
std::unique_ptr<JobRunner> make_kinematic_runner(Simulation& sim, size_t sample_capacity);

}  // namespace zona
