// What this build contains and which compute devices the machine has: `zona info`, the backend
// factory and the benchmarks read it.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

namespace zona {

/// One compute device found at run time.
struct DeviceInfo {
  std::string backend;             ///< "cuda"
  std::string name;                ///< e.g. "NVIDIA H100 80GB HBM3"
  int64_t memory_bytes = 0;        ///< total device memory [bytes]
  std::string compute_capability;  ///< e.g. "90"
  int ordinal = 0;                 ///< device index for the backend
};

/// Build options and devices.
struct BuildInfo {
  std::string version;
  std::string build_type;
  std::string compiler;
  std::vector<std::string> backends_compiled;  ///< "cpu" always; "cuda" when built with it
  bool renderer_compiled = false;
  std::vector<DeviceInfo> devices;  ///< devices usable by a compiled backend
  std::string device_notice;        ///< why no device is usable, when none is (one line)
};

/// True when the CUDA backend was compiled into this binary.
bool cuda_compiled();

/// CUDA devices found; on none, `notice` (when given) says why in one line
/// ("built without CUDA", "no NVIDIA driver", "no CUDA device").
std::vector<DeviceInfo> cuda_devices(std::string* notice);

/// Everything above, for `zona info`.
BuildInfo build_info();

}  // namespace zona
