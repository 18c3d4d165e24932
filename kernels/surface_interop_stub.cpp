// The CUDA-Vulkan surface writer when zona is built without CUDA: a clear error value.
#include "kernels/surface_interop.h"

#include <unistd.h>

namespace zona {

Result<std::unique_ptr<SurfaceWriter>> make_surface_writer(const Backend&, const Model&,
                                                           const SharedSurfaceTarget& target) {
  if (target.memory_fd >= 0) ::close(target.memory_fd);
  return make_error(
      "CUDA-Vulkan interop is not available: zona was built without CUDA (the copy path is "
      "used)");
}

}  // namespace zona
