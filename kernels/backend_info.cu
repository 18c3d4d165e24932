// CUDA device query: lists the devices the runtime sees, or says in one line why there are none.
#include <cuda_runtime.h>

#include "kernels/backend_info.h"

namespace zona {

bool cuda_compiled() { return true; }

std::vector<DeviceInfo> cuda_devices(std::string* notice) {
  std::vector<DeviceInfo> devices;
  int count = 0;
  const cudaError_t err = cudaGetDeviceCount(&count);
  if (err != cudaSuccess) {
    // No driver or no device: clear the sticky error so later calls start clean.
    (void)cudaGetLastError();
    if (notice)
      *notice = std::string("no usable CUDA device (") + cudaGetErrorString(err) +
                "): the CPU backend is used";
    return devices;
  }
  for (int i = 0; i < count; ++i) {
    cudaDeviceProp prop{};
    if (cudaGetDeviceProperties(&prop, i) != cudaSuccess) continue;
    DeviceInfo d;
    d.backend = "cuda";
    d.name = prop.name;
    d.memory_bytes = static_cast<int64_t>(prop.totalGlobalMem);
    d.compute_capability = std::to_string(prop.major) + std::to_string(prop.minor);
    d.ordinal = i;
    devices.push_back(d);
  }
  if (devices.empty() && notice) *notice = "no CUDA device found: the CPU backend is used";
  return devices;
}

}  // namespace zona
