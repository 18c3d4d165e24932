// The CPU backend: the reference integrator (engine/sim/integrator.h) behind the Backend interface.
#pragma once

#include <memory>

#include "engine/sim/backend.h"

namespace zona {

/// Creates the CPU backend (never fails: the CPU is always there).
std::unique_ptr<Backend> make_cpu_backend(const BackendOptions& options);

/// Copies the simulation fields of `from` into `to` (same model): displacements, loads,
/// prescribed set and targets, time, step count, diagnostics. Scratch and threads stay.
void copy_state_fields(const State& from, State& to);

}  // namespace zona
