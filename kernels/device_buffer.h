// Owning handles for CUDA resources: device buffers (plain cudaMalloc, never managed memory),
// pinned host buffers, streams, events and executable graphs. Move-only; every call checked.
// Included by .cu files only.
#pragma once

#include <cuda_runtime.h>

#include <cstddef>
#include <utility>
#include <vector>

#include "engine/core/base.h"
#include "kernels/cuda_check.h"

namespace zona::cuda {

/// A typed device array. Allocated once at setup; the step path only reads its pointer.
template <class T>
class DeviceBuffer {
 public:
  DeviceBuffer() = default;
  DeviceBuffer(const DeviceBuffer&) = delete;
  DeviceBuffer& operator=(const DeviceBuffer&) = delete;
  DeviceBuffer(DeviceBuffer&& o) noexcept
      : ptr_(std::exchange(o.ptr_, nullptr)), count_(std::exchange(o.count_, 0)) {}
  DeviceBuffer& operator=(DeviceBuffer&& o) noexcept {
    if (this != &o) {
      release();
      ptr_ = std::exchange(o.ptr_, nullptr);
      count_ = std::exchange(o.count_, 0);
    }
    return *this;
  }
  ~DeviceBuffer() { release(); }

  /// (Re)allocates `count` elements, contents undefined. `what` names the buffer in errors.
  Status allocate(size_t count, const char* what) {
    release();
    if (count == 0) return {};
    void* p = nullptr;
    const cudaError_t err = cudaMalloc(&p, count * sizeof(T));
    if (err != cudaSuccess) {
      (void)cudaGetLastError();
      return make_error("CUDA: cannot allocate %s (%zu bytes): %s", what, count * sizeof(T),
                        cudaGetErrorString(err));
    }
    ptr_ = static_cast<T*>(p);
    count_ = count;
    return {};
  }
  /// Allocates and copies `host` (synchronous: setup only).
  Status upload(const std::vector<T>& host, const char* what) {
    if (Status s = allocate(host.size(), what); !s) return s;
    if (!host.empty())
      ZONA_CUDA_TRY(cudaMemcpy(ptr_, host.data(), bytes(), cudaMemcpyHostToDevice));
    return {};
  }
  /// Allocates `count` elements and copies them from `host` (synchronous: setup only); for
  /// host arrays of a layout-compatible type (std::array<float, 4> into float4).
  Status upload_raw(const void* host, size_t count, const char* what) {
    if (Status s = allocate(count, what); !s) return s;
    if (count) ZONA_CUDA_TRY(cudaMemcpy(ptr_, host, bytes(), cudaMemcpyHostToDevice));
    return {};
  }
  /// Copies the whole buffer into `host`, resized (synchronous: setup and tests only).
  Status download(std::vector<T>& host) const {
    host.resize(count_);
    if (count_) ZONA_CUDA_TRY(cudaMemcpy(host.data(), ptr_, bytes(), cudaMemcpyDeviceToHost));
    return {};
  }
  /// Sets every byte to `byte` (0 clears; 0xFF makes float and double NaN: the poison).
  Status fill_bytes(int byte) {
    if (count_) ZONA_CUDA_TRY(cudaMemset(ptr_, byte, bytes()));
    return {};
  }

  /// The same, ordered on stream s.
  Status fill_bytes_async(int byte, cudaStream_t s) {
    if (count_) ZONA_CUDA_TRY(cudaMemsetAsync(ptr_, byte, bytes(), s));
    return {};
  }

  T* data() { return ptr_; }
  const T* data() const { return ptr_; }
  size_t size() const { return count_; }
  size_t bytes() const { return count_ * sizeof(T); }

 private:
  void release() {
    // cudaFree cannot fail on a pointer cudaMalloc returned unless the context is already gone
    // (process exit); nothing useful can be done about it in a destructor.
    if (ptr_) (void)cudaFree(ptr_);
    ptr_ = nullptr;
    count_ = 0;
  }
  T* ptr_ = nullptr;
  size_t count_ = 0;
};

/// A typed page-locked host array: asynchronous copies to and from it overlap the device.
template <class T>
class PinnedBuffer {
 public:
  PinnedBuffer() = default;
  PinnedBuffer(const PinnedBuffer&) = delete;
  PinnedBuffer& operator=(const PinnedBuffer&) = delete;
  PinnedBuffer(PinnedBuffer&& o) noexcept
      : ptr_(std::exchange(o.ptr_, nullptr)), count_(std::exchange(o.count_, 0)) {}
  PinnedBuffer& operator=(PinnedBuffer&& o) noexcept {
    if (this != &o) {
      release();
      ptr_ = std::exchange(o.ptr_, nullptr);
      count_ = std::exchange(o.count_, 0);
    }
    return *this;
  }
  ~PinnedBuffer() { release(); }

  /// Allocates `count` zero-initialised elements.
  Status allocate(size_t count, const char* what) {
    release();
    void* p = nullptr;
    const cudaError_t err = cudaMallocHost(&p, count * sizeof(T));
    if (err != cudaSuccess) {
      (void)cudaGetLastError();
      return make_error("CUDA: cannot allocate pinned %s (%zu bytes): %s", what, count * sizeof(T),
                        cudaGetErrorString(err));
    }
    ptr_ = static_cast<T*>(p);
    count_ = count;
    for (size_t i = 0; i < count_; ++i) ptr_[i] = T{};
    return {};
  }
  T* data() { return ptr_; }
  const T* data() const { return ptr_; }
  T& operator[](size_t i) { return ptr_[i]; }
  size_t size() const { return count_; }
  size_t bytes() const { return count_ * sizeof(T); }

 private:
  void release() {
    if (ptr_) (void)cudaFreeHost(ptr_);
    ptr_ = nullptr;
    count_ = 0;
  }
  T* ptr_ = nullptr;
  size_t count_ = 0;
};

/// A non-blocking stream (it does not synchronise with the legacy default stream).
class Stream {
 public:
  Stream() = default;
  Stream(const Stream&) = delete;
  Stream& operator=(const Stream&) = delete;
  Stream(Stream&& o) noexcept : s_(std::exchange(o.s_, nullptr)) {}
  Stream& operator=(Stream&& o) noexcept {
    if (this != &o) {
      release();
      s_ = std::exchange(o.s_, nullptr);
    }
    return *this;
  }
  ~Stream() { release(); }
  Status create() {
    release();
    ZONA_CUDA_TRY(cudaStreamCreateWithFlags(&s_, cudaStreamNonBlocking));
    return {};
  }
  cudaStream_t get() const { return s_; }

 private:
  void release() {
    if (s_) (void)cudaStreamDestroy(s_);
    s_ = nullptr;
  }
  cudaStream_t s_ = nullptr;
};

/// A CUDA event; `timing` events measure elapsed device time, the others only order work.
class Event {
 public:
  Event() = default;
  Event(const Event&) = delete;
  Event& operator=(const Event&) = delete;
  Event(Event&& o) noexcept : e_(std::exchange(o.e_, nullptr)) {}
  Event& operator=(Event&& o) noexcept {
    if (this != &o) {
      release();
      e_ = std::exchange(o.e_, nullptr);
    }
    return *this;
  }
  ~Event() { release(); }
  Status create(bool timing) {
    release();
    ZONA_CUDA_TRY(
        cudaEventCreateWithFlags(&e_, timing ? cudaEventDefault : cudaEventDisableTiming));
    return {};
  }
  cudaEvent_t get() const { return e_; }

 private:
  void release() {
    if (e_) (void)cudaEventDestroy(e_);
    e_ = nullptr;
  }
  cudaEvent_t e_ = nullptr;
};

/// An instantiated CUDA graph (and the graph it came from).
class GraphExec {
 public:
  GraphExec() = default;
  GraphExec(const GraphExec&) = delete;
  GraphExec& operator=(const GraphExec&) = delete;
  GraphExec(GraphExec&& o) noexcept
      : g_(std::exchange(o.g_, nullptr)), x_(std::exchange(o.x_, nullptr)) {}
  GraphExec& operator=(GraphExec&& o) noexcept {
    if (this != &o) {
      release();
      g_ = std::exchange(o.g_, nullptr);
      x_ = std::exchange(o.x_, nullptr);
    }
    return *this;
  }
  ~GraphExec() { release(); }
  /// Takes ownership of a captured graph and instantiates it.
  Status instantiate(cudaGraph_t graph) {
    release();
    g_ = graph;
    ZONA_CUDA_TRY(cudaGraphInstantiate(&x_, g_, 0));
    return {};
  }
  bool valid() const { return x_ != nullptr; }
  cudaGraphExec_t get() const { return x_; }
  void reset() { release(); }

 private:
  void release() {
    if (x_) (void)cudaGraphExecDestroy(x_);
    if (g_) (void)cudaGraphDestroy(g_);
    x_ = nullptr;
    g_ = nullptr;
  }
  cudaGraph_t g_ = nullptr;
  cudaGraphExec_t x_ = nullptr;
};

/// Elapsed device time between two timing events [ms]; negative when the query fails.
inline float elapsed_ms(const Event& start, const Event& stop) {
  float ms = -1.0f;
  if (cudaEventElapsedTime(&ms, start.get(), stop.get()) != cudaSuccess) {
    (void)cudaGetLastError();
    return -1.0f;
  }
  return ms;
}

}  // namespace zona::cuda
