// Device-to-device copy bandwidth, timed with CUDA events: the memory ceiling of the roofline.
#include <algorithm>
#include <vector>

#include "kernels/cuda_check.h"
#include "kernels/cuda_probe.h"
#include "kernels/device_buffer.h"

namespace zona {

Result<CopyBandwidth> measure_copy_bandwidth(size_t bytes, int repeats, int device) {
  using namespace cuda;
  if (repeats < 1) repeats = 1;
  ZONA_CUDA_TRY(cudaSetDevice(device));
  DeviceBuffer<unsigned char> a, b;
  if (Status s = a.allocate(bytes, "copy source"); !s) return s.error();
  if (Status s = b.allocate(bytes, "copy destination"); !s) return s.error();
  // Non-zero contents: never time on zeros (METHOD.md).
  if (Status s = a.fill_bytes(0x5A); !s) return s.error();
  Stream stream;
  Event start, stop;
  if (Status s = stream.create(); !s) return s.error();
  if (Status s = start.create(true); !s) return s.error();
  if (Status s = stop.create(true); !s) return s.error();
  std::vector<double> rates;
  for (int i = 0; i <= repeats; ++i) {
    ZONA_CUDA_TRY(cudaEventRecord(start.get(), stream.get()));
    ZONA_CUDA_TRY(
        cudaMemcpyAsync(b.data(), a.data(), bytes, cudaMemcpyDeviceToDevice, stream.get()));
    ZONA_CUDA_TRY(cudaEventRecord(stop.get(), stream.get()));
    ZONA_CUDA_TRY(cudaEventSynchronize(stop.get()));
    const float ms = elapsed_ms(start, stop);
    if (i > 0 && ms > 0) rates.push_back(2.0 * static_cast<double>(bytes) / (ms * 1e-3) * 1e-9);
  }
  if (rates.empty()) return make_error("copy bandwidth: no valid timing");
  std::sort(rates.begin(), rates.end());
  CopyBandwidth r;
  r.gb_per_s = rates[rates.size() / 2];
  r.min_gb_per_s = rates.front();
  r.max_gb_per_s = rates.back();
  r.bytes = bytes;
  return r;
}

}  // namespace zona
