// The prescribed boundary's host step (Simulation::step1 / step2 of a scene whose only load is an
// indentation patch) behind the JobRunner interface, so that one run driver (run_simulation)
// and one sample builder serve every scene: each step's NeedleReport becomes a JobRecord,
// sampled every output.sample_interval as the job's record stage samples.
#pragma once

#include <memory>

#include "engine/sim/job_runner.h"

namespace zona {

class Simulation;

/// The record of a host step: the report's measures, the puncture, the quasi-static state;
/// `halted` when the step failed its health check (or ran above the critical step unasked).
JobRecord boundary_record(const Simulation& sim);

/// A runner stepping `sim` on its host path, in place; `sample_capacity` samples kept
/// between take_samples calls.
std::unique_ptr<JobRunner> make_boundary_runner(Simulation& sim, size_t sample_capacity);

}  // namespace zona
