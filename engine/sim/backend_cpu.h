// The CPU backends: the reference integrator (engine/sim/integrator.h) and the particle model
// (engine/particles/) behind the Backend interface.
#pragma once

#include <memory>

#include "engine/particles/particle_model.h"
#include "engine/sim/backend.h"

namespace zona {

/// Creates the CPU backend (never fails: the CPU is always there).
std::unique_ptr<Backend> make_cpu_backend(const BackendOptions& options);

/// The particle model's CPU reference behind the Backend interface (own copy of the state;
/// upload/step/download as the FEM backends; engine/sim/backend_particles_cpu.cpp). `model`
/// must outlive it. Used by `--backend cpu` paths that need the interface and as the GPU parity
/// tests' reference.
std::unique_ptr<Backend> make_particle_cpu_backend(const ParticleModel& model);

/// Copies the simulation fields of `from` into `to` (same model): displacements, loads,
/// prescribed set and targets, time, step count, diagnostics. Scratch and threads stay.
void copy_state_fields(const State& from, State& to);

}  // namespace zona
