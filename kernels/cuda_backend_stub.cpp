// The CUDA backend's constructor when zona is built without CUDA: a clear error value.
#include "kernels/cuda_backend.h"

namespace zona {

Result<std::unique_ptr<Backend>> make_cuda_backend(const BackendOptions&) {
  return make_error(
      "the CUDA backend is not available: zona was built without CUDA "
      "(configure with nvcc on the PATH and -DZONA_CUDA=ON)");
}

}  // namespace zona
