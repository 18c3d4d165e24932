// Checking every CUDA call: setup paths turn a failure into a one-line zona::Error, the step
// path into a status bit plus a message kept in a fixed buffer (no allocation, no exception).
// Included by .cu files only (it needs cuda_runtime.h).
#pragma once

#include <cuda_runtime.h>

#include <cstdio>

#include "engine/core/base.h"

namespace zona::cuda {

/// One line naming the call, the source position and CUDA's own words, e.g.
/// "CUDA error: cudaMalloc(&p, bytes) at kernels/device_buffer.h:40: out of memory
/// (cudaErrorMemoryAllocation)".
inline Error cuda_error(cudaError_t err, const char* call, const char* file, int line) {
  return make_error("CUDA error: %s at %s:%d: %s (%s)", call, file, line, cudaGetErrorString(err),
                    cudaGetErrorName(err));
}

/// Makes CUDA device `ordinal` current for the calling thread and reads its properties (what
/// every backend's constructor does first). Errors (one line): no usable device (with the
/// driver's reason), none found, the ordinal out of range, a failed call.
inline Status open_device(int ordinal, cudaDeviceProp* prop) {
  int count = 0;
  if (const cudaError_t err = cudaGetDeviceCount(&count); err != cudaSuccess) {
    (void)cudaGetLastError();  // clear the sticky error so later calls start clean
    return make_error("no usable CUDA device (%s)", cudaGetErrorString(err));
  }
  if (count == 0) return make_error("no CUDA device found");
  if (ordinal < 0 || ordinal >= count)
    return make_error("CUDA device %d does not exist (%d found)", ordinal, count);
  if (const cudaError_t e = cudaGetDeviceProperties(prop, ordinal); e != cudaSuccess) {
    (void)cudaGetLastError();
    return cuda_error(e, "cudaGetDeviceProperties", __FILE__, __LINE__);
  }
  if (const cudaError_t e = cudaSetDevice(ordinal); e != cudaSuccess) {
    (void)cudaGetLastError();
    return cuda_error(e, "cudaSetDevice", __FILE__, __LINE__);
  }
  return {};
}

/// Where the step path records its first CUDA failure: fixed storage, written once per failure,
/// read by the host after the step returns its flags.
struct StepErrorLog {
  char message[256] = {0};
  bool failed = false;

  /// Records the first failure only: later ones are usually consequences of it.
  void record(cudaError_t err, const char* call, const char* file, int line) {
    if (failed) return;
    failed = true;
    std::snprintf(message, sizeof(message), "CUDA error: %s at %s:%d: %s (%s)", call, file, line,
                  cudaGetErrorString(err), cudaGetErrorName(err));
  }
  void clear() {
    failed = false;
    message[0] = 0;
  }
};

}  // namespace zona::cuda

/// Setup paths: evaluates a CUDA call and returns zona::Error from the enclosing function
/// (which returns Status or Result<T>) when it fails.
/// A failed call also leaves CUDA's per-thread "last error" set; it is read (and so cleared)
/// here, or a later cudaGetLastError check on the step path would report this old failure.
#define ZONA_CUDA_TRY(call)                                                         \
  do {                                                                              \
    const cudaError_t zona_cuda_err_ = (call);                                      \
    if (zona_cuda_err_ != cudaSuccess) {                                            \
      (void)cudaGetLastError();                                                     \
      return ::zona::cuda::cuda_error(zona_cuda_err_, #call, __FILE__, __LINE__);   \
    }                                                                               \
  } while (0)

/// Setup paths: checks the kernel launch just made (a bad launch configuration surfaces through
/// cudaGetLastError, not at the launch statement).
#define ZONA_CUDA_TRY_LAUNCH() ZONA_CUDA_TRY(cudaGetLastError())

/// Step path: evaluates a CUDA call; on failure records it in `log` (a StepErrorLog) and
/// evaluates to false, so the caller can set its status bit and stop the step.
#define ZONA_CUDA_STEP(log, call)                            \
  ([&]() -> bool {                                           \
    const cudaError_t zona_cuda_err_ = (call);               \
    if (zona_cuda_err_ == cudaSuccess) return true;          \
    (log).record(zona_cuda_err_, #call, __FILE__, __LINE__); \
    return false;                                            \
  }())
