// Device ceilings when zona is built without CUDA.
#include "kernels/cuda_probe.h"

namespace zona {

Result<CopyBandwidth> measure_copy_bandwidth(size_t, int, int) {
  return make_error("cannot measure device bandwidth: zona was built without CUDA");
}

}  // namespace zona
