// Device ceilings the benchmarks divide by: the device-to-device copy bandwidth (the roofline's
// memory ceiling, docs/performance.md). The stub answers "built without CUDA".
#pragma once

#include <cstddef>

#include "engine/core/base.h"

namespace zona {

/// Measured device-to-device copy bandwidth.
struct CopyBandwidth {
  double gb_per_s = 0;      ///< median, counting bytes read plus bytes written [GB/s]
  double min_gb_per_s = 0;  ///< slowest repeat [GB/s]
  double max_gb_per_s = 0;  ///< fastest repeat [GB/s]
  size_t bytes = 0;         ///< bytes copied per repeat
};

/// Copies `bytes` between two device buffers `repeats` times (cudaMemcpyAsync, timed with CUDA
/// events after one warm-up) on device `device`. Errors: built without CUDA, no device, out of
/// memory.
Result<CopyBandwidth> measure_copy_bandwidth(size_t bytes, int repeats, int device = 0);

}  // namespace zona
