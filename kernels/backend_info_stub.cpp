// CUDA device query when zona is built without CUDA.
#include "kernels/backend_info.h"

namespace zona {

bool cuda_compiled() { return false; }

std::vector<DeviceInfo> cuda_devices(std::string* notice) {
  if (notice) *notice = "built without CUDA: the CPU backend is used";
  return {};
}

}  // namespace zona
