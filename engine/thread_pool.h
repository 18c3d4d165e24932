// A fixed pool of worker threads for the CPU backend's step: static partition of a chunk range,
// no allocation and no std::function per call, a short spin before sleeping so that the two
// parallel phases of a 50-microsecond step do not pay a futex wake-up each.
#pragma once

#include <atomic>
#include <cstdint>
#include <thread>
#include <vector>

namespace zona {

/// Runs `fn(context, chunk_begin, chunk_end)` over a chunk range split into one contiguous
/// slice per thread (the caller's thread takes slice 0). The split depends on the thread count,
/// so callers that need bitwise-identical results across thread counts make every chunk's result
/// independent of which thread ran it and reduce per-chunk results in chunk order.
class ThreadPool {
 public:
  using ChunkFn = void (*)(void* context, int64_t chunk_begin, int64_t chunk_end);

  /// Starts `thread_count - 1` workers (thread_count >= 1; 0 means the hardware's count).
  explicit ThreadPool(int thread_count);
  ~ThreadPool();
  ThreadPool(const ThreadPool&) = delete;
  ThreadPool& operator=(const ThreadPool&) = delete;

  /// Number of threads that share the work, the caller included.
  int thread_count() const { return thread_count_; }

  /// Runs fn over chunks [0, chunk_count) and returns when every slice is done. Not reentrant:
  /// one caller at a time (the simulation thread).
  void run(int64_t chunk_count, ChunkFn fn, void* context);

 private:
  void worker_main(int index);
  void run_slice(int index);

  int thread_count_ = 1;
  std::vector<std::thread> workers_;
  // The job being run; written by the caller before `generation_` is bumped (release) and read
  // by the workers after they see the new generation (acquire).
  ChunkFn fn_ = nullptr;
  void* context_ = nullptr;
  int64_t chunk_count_ = 0;
  std::atomic<uint32_t> generation_{0};
  std::atomic<int32_t> pending_{0};
  std::atomic<bool> stop_{false};
};

}  // namespace zona
