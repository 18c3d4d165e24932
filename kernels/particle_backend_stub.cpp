// The particle model's CUDA backend when zona is built without CUDA: a clear error value.
#include "kernels/particle_backend.h"

namespace zona {

Result<std::unique_ptr<Backend>> make_particle_cuda_backend(const ParticleModel&, const BackendOptions&) {
  return make_error(
      "the CUDA backend is not available: zona was built without CUDA "
      "(configure with nvcc on the PATH and -DZONA_CUDA=ON)");
}

}  // namespace zona
