// The particle backend factory: the one place besides kernels/ stubs that decides CPU or CUDA
// for the particle model.
#include "engine/sim/backend_cpu.h"
#include "kernels/particle_backend.h"

namespace zona {

Result<std::unique_ptr<Backend>> make_particle_backend(BackendKind kind, const ParticleModel& model,
                                                       const BackendOptions& options,
                                                       std::string* notice) {
  if (notice) notice->clear();
  switch (kind) {
    case BackendKind::kCpu:
      return make_particle_cpu_backend(model);
    case BackendKind::kCuda:
      return make_particle_cuda_backend(model, options);
    case BackendKind::kAuto: {
      Result<std::unique_ptr<Backend>> cuda = make_particle_cuda_backend(model, options);
      if (cuda) return cuda;
      if (notice) *notice = cuda.error().message + "; using the particle model's CPU reference";
      return make_particle_cpu_backend(model);
    }
  }
  return make_error("backend kind %d is unknown", static_cast<int>(kind));
}

}  // namespace zona
