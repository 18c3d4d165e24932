// The particle model's (Asgari et al.) compute backends and the factory that picks one, as
// kernels/backend_factory.h does for the FEM: `--backend auto|cpu|cuda`.
#pragma once

#include <memory>
#include <string>

#include "engine/sim/backend.h"
#include "engine/particles/particle_model.h"

namespace zona {

/// Creates the CUDA backend of `model` (which must outlive it) on options.device. Implemented in
/// particle_backend.cu, or in particle_backend_stub.cpp (an error value) without CUDA. Errors
/// (one line): built without CUDA, no usable device, kernels not built for this device.
Result<std::unique_ptr<Backend>> make_particle_cuda_backend(const ParticleModel& model,
                                                            const BackendOptions& options);

/// Creates the backend `kind` asks for:
///  - kCpu: the CPU reference (engine/sim/backend_cpu.h's make_particle_cpu_backend);
///  - kCuda: the CUDA backend, or an error;
///  - kAuto: the CUDA backend when it can be created, else the CPU one with a one-line reason in
///    `notice`.
/// `notice` (optional) is cleared first and only written for kAuto's fallback.
Result<std::unique_ptr<Backend>> make_particle_backend(BackendKind kind, const ParticleModel& model,
                                                       const BackendOptions& options,
                                                       std::string* notice = nullptr);

}  // namespace zona
