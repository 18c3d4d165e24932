// The backend factory: the one place besides kernels/ stubs that decides CPU or CUDA.
#include "kernels/backend_factory.h"

#include "engine/sim/backend_cpu.h"
#include "kernels/cuda_backend.h"

namespace zona {

Result<std::unique_ptr<Backend>> make_backend(BackendKind kind, const BackendOptions& options,
                                              std::string* notice) {
  if (notice) notice->clear();
  switch (kind) {
    case BackendKind::kCpu:
      return make_cpu_backend(options);
    case BackendKind::kCuda:
      return make_cuda_backend(options);
    case BackendKind::kAuto: {
      Result<std::unique_ptr<Backend>> cuda = make_cuda_backend(options);
      if (cuda) return cuda;
      if (notice) *notice = cuda.error().message + "; using the CPU backend";
      return make_cpu_backend(options);
    }
  }
  return make_error("backend kind %d is unknown", static_cast<int>(kind));
}

}  // namespace zona
