// Worker threads with chunk claiming and spin-then-sleep hand-off (C++20 atomic wait/notify,
// a futex on Linux).
#include "engine/core/thread_pool.h"

#include <algorithm>
#include <mutex>

#if defined(__linux__)
#include <sched.h>
#endif

#include "engine/core/base.h"

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

constexpr uint64_t kField = (uint64_t{1} << 24) - 1;

constexpr uint64_t pack_claim(uint64_t job, uint64_t end, uint64_t next) {
  return (job & 0xFFFF) << 48 | (end & kField) << 24 | (next & kField);
}

}  // namespace

int available_cores() {
#if defined(__linux__)
  cpu_set_t set;
  CPU_ZERO(&set);
  if (sched_getaffinity(0, sizeof(set), &set) == 0) {
    const int n = CPU_COUNT(&set);
    if (n > 0) return n;
  }
#endif
  return std::max(1, static_cast<int>(std::thread::hardware_concurrency()));
}

ThreadPool::ThreadPool(int thread_count) {
  if (thread_count <= 0) thread_count = available_cores();
  thread_count_ = thread_count;
  slices_ = std::make_unique<Slice[]>(static_cast<size_t>(thread_count_));
  workers_.reserve(static_cast<size_t>(thread_count_ - 1));
  for (int i = 1; i < thread_count_; ++i) workers_.emplace_back([this, i] { worker_main(i); });
}

ThreadPool::~ThreadPool() {
  stop_.store(true, std::memory_order_release);
  generation_.fetch_add(1, std::memory_order_acq_rel);
  generation_.notify_all();
  for (std::thread& t : workers_) t.join();
}

bool ThreadPool::claim(int r, int64_t* begin, int64_t* end) {
  std::atomic<uint64_t>& slot = slices_[static_cast<size_t>(r)].word;
  uint64_t word = slot.load(std::memory_order_acquire);
  while ((word & kField) < ((word >> 24) & kField)) {
    // Shrinking pieces (a quarter of what is left): few atomic hand-offs per run, and a tail
    // that another thread can still take over.
    const uint64_t left = ((word >> 24) & kField) - (word & kField);
    const uint64_t take = std::max<uint64_t>(1, left / 4);
    if (slot.compare_exchange_weak(word, word + take, std::memory_order_acq_rel,
                                   std::memory_order_acquire)) {
      *begin = static_cast<int64_t>(word & kField);
      *end = *begin + static_cast<int64_t>(take);
      return true;
    }
  }
  return false;
}

int64_t ThreadPool::drain(int self) {
  int64_t done = 0;
  for (int k = 0; k < thread_count_; ++k) {
    const int r = (self + k) % thread_count_;
    for (;;) {
      // Announce the claim first: once it succeeds, run() cannot return (and the job's fn_ and
      // context_ cannot change) until this thread's count drops again. (A thread that sees the
      // claimed word, acquire, sees this count too: the claim's CAS releases it.)
      std::atomic<int32_t>& active = slices_[static_cast<size_t>(self)].active;
      active.fetch_add(1, std::memory_order_acq_rel);
      int64_t begin = 0, end = 0;
      const bool claimed = claim(r, &begin, &end);
      if (claimed) {
        fn_(context_, begin, end);
        done += end - begin;
      }
      // Wake run() only when it sleeps: notify_all is a futex system call, and a step's two
      // runs make dozens of claims (seq_cst pairs with run()'s store of caller_sleeping_, so
      // one of the two sides always sees the other).
      if (active.fetch_sub(1, std::memory_order_seq_cst) == 1 &&
          caller_sleeping_.load(std::memory_order_seq_cst))
        active.notify_all();
      if (!claimed) break;
    }
  }
  return done;
}

void ThreadPool::run(int64_t chunk_count, ChunkFn fn, void* context) {
  if (chunk_count <= 0) return;
  ZONA_ASSERT(static_cast<uint64_t>(chunk_count) <= kField);
  if (thread_count_ == 1) {
    fn(context, 0, chunk_count);
    return;
  }
  fn_ = fn;
  context_ = context;
  ++job_;
  for (int i = 0; i < thread_count_; ++i)
    slices_[static_cast<size_t>(i)].word.store(
        pack_claim(job_, static_cast<uint64_t>(slice_begin(chunk_count, i + 1, thread_count_)),
                   static_cast<uint64_t>(slice_begin(chunk_count, i, thread_count_))),
        std::memory_order_release);
  generation_.fetch_add(1, std::memory_order_seq_cst);
  // Only sleeping workers need the system call; spinning ones see the new generation.
  if (sleepers_.load(std::memory_order_seq_cst) > 0) generation_.notify_all();
  drain(0);
  // Every chunk is claimed; wait for the ones other threads are still running. A thread whose
  // count reads zero now has finished its pieces and can claim no more (none is left).
  int spin = 0;
  for (int i = 1; i < thread_count_; ++i) {
    std::atomic<int32_t>& active = slices_[static_cast<size_t>(i)].active;
    while (spin < kSpinIterations && active.load(std::memory_order_acquire) != 0) {
      ZONA_CPU_RELAX();
      ++spin;
    }
    if (active.load(std::memory_order_acquire) == 0) continue;
    caller_sleeping_.store(true, std::memory_order_seq_cst);
    for (int32_t a = active.load(std::memory_order_seq_cst); a != 0;
         a = active.load(std::memory_order_seq_cst))
      active.wait(a, std::memory_order_acquire);
    caller_sleeping_.store(false, std::memory_order_relaxed);
  }
}

void ThreadPool::worker_main(int index) {
  uint32_t seen = 0;
  for (;;) {
    // Wait for a new job: spin, then sleep.
    uint32_t g = generation_.load(std::memory_order_acquire);
    for (int spin = 0; g == seen && spin < kSpinIterations; ++spin) {
      ZONA_CPU_RELAX();
      g = generation_.load(std::memory_order_acquire);
    }
    if (g == seen) {
      sleepers_.fetch_add(1, std::memory_order_seq_cst);
      for (g = generation_.load(std::memory_order_seq_cst); g == seen;
           g = generation_.load(std::memory_order_seq_cst))
        generation_.wait(seen, std::memory_order_acquire);
      sleepers_.fetch_sub(1, std::memory_order_relaxed);
    }
    seen = g;
    if (stop_.load(std::memory_order_acquire)) return;
    drain(index);
  }
}

namespace {
std::mutex shared_pool_mutex;
std::atomic<int> shared_pool_requested{0};  // 0: available_cores()
}  // namespace

ThreadPool* try_acquire_shared_pool() {
  if (!shared_pool_mutex.try_lock()) return nullptr;
  static std::unique_ptr<ThreadPool> pool;  // started under the lock, on first use
  const int threads = shared_pool_threads();
  if (!pool || pool->thread_count() != threads) {
    pool.reset();
    pool = std::make_unique<ThreadPool>(threads);
  }
  return pool.get();
}

void set_shared_pool_threads(int threads) {
  shared_pool_requested.store(std::max(threads, 0), std::memory_order_relaxed);
}

int shared_pool_threads() {
  static const int cores = available_cores();  // read once: acquisitions run many times a second
  const int requested = shared_pool_requested.load(std::memory_order_relaxed);
  return requested > 0 ? requested : cores;
}

void release_shared_pool() { shared_pool_mutex.unlock(); }

}  // namespace zona
