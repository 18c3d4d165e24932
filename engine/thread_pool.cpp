// Worker threads with spin-then-sleep hand-off (C++20 atomic wait/notify, a futex on Linux).
#include "engine/thread_pool.h"

#if defined(__x86_64__) || defined(__i386__)
#include <immintrin.h>
#define ZONA_CPU_RELAX() _mm_pause()
#else
#define ZONA_CPU_RELAX() ((void)0)
#endif

namespace zona {
namespace {

// About 20-50 microseconds of spinning: long enough to bridge the gap between the two phases
// of one step and between consecutive steps, short enough not to starve other processes on a
// shared two-core machine.
constexpr int kSpinIterations = 20000;

}  // namespace

ThreadPool::ThreadPool(int thread_count) {
  if (thread_count <= 0) thread_count = static_cast<int>(std::thread::hardware_concurrency());
  if (thread_count <= 0) thread_count = 1;
  thread_count_ = thread_count;
  workers_.reserve(static_cast<size_t>(thread_count_ - 1));
  for (int i = 1; i < thread_count_; ++i) workers_.emplace_back([this, i] { worker_main(i); });
}

ThreadPool::~ThreadPool() {
  stop_.store(true, std::memory_order_release);
  generation_.fetch_add(1, std::memory_order_acq_rel);
  generation_.notify_all();
  for (std::thread& t : workers_) t.join();
}

void ThreadPool::run_slice(int index) {
  const int64_t begin = chunk_count_ * index / thread_count_;
  const int64_t end = chunk_count_ * (index + 1) / thread_count_;
  if (begin < end) fn_(context_, begin, end);
}

void ThreadPool::run(int64_t chunk_count, ChunkFn fn, void* context) {
  if (chunk_count <= 0) return;
  fn_ = fn;
  context_ = context;
  chunk_count_ = chunk_count;
  if (thread_count_ == 1) {
    fn(context, 0, chunk_count);
    return;
  }
  pending_.store(thread_count_ - 1, std::memory_order_relaxed);
  generation_.fetch_add(1, std::memory_order_acq_rel);
  generation_.notify_all();
  run_slice(0);
  // Wait for the workers: spin first, then sleep on the counter.
  for (int spin = 0; spin < kSpinIterations; ++spin) {
    if (pending_.load(std::memory_order_acquire) == 0) return;
    ZONA_CPU_RELAX();
  }
  for (int32_t left = pending_.load(std::memory_order_acquire); left != 0;
       left = pending_.load(std::memory_order_acquire))
    pending_.wait(left, std::memory_order_acquire);
}

void ThreadPool::worker_main(int index) {
  uint32_t seen = 0;
  for (;;) {
    // Wait for a new generation: spin, then sleep.
    uint32_t g = generation_.load(std::memory_order_acquire);
    for (int spin = 0; g == seen && spin < kSpinIterations; ++spin) {
      ZONA_CPU_RELAX();
      g = generation_.load(std::memory_order_acquire);
    }
    while (g == seen) {
      generation_.wait(seen, std::memory_order_acquire);
      g = generation_.load(std::memory_order_acquire);
    }
    seen = g;
    if (stop_.load(std::memory_order_acquire)) return;
    run_slice(index);
    if (pending_.fetch_sub(1, std::memory_order_acq_rel) == 1) pending_.notify_one();
  }
}

}  // namespace zona
