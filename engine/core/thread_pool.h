// A fixed pool of worker threads for the CPU backend's step: chunks of a range are claimed one at
// a time by whichever thread is running, so a descheduled worker (two cores shared with the
// haptic and render threads, or with a compiler) delays nothing it has not started; no
// allocation and no std::function per call; a short spin before sleeping so that the two
// parallel phases of a 50-microsecond step do not pay a futex wake-up each.
#pragma once

#include <atomic>
#include <cstdint>
#include <memory>
#include <thread>
#include <vector>

namespace zona {

/// The cores this process may run on: its CPU affinity mask (what `taskset`, a SLURM job's
/// `--cpus-per-task` and a container's cpuset leave it), where std::thread::hardware_concurrency
/// counts every core of the machine; at least 1.
int available_cores();

/// Runs `fn(context, begin, end)` over claimed ranges covering every chunk of [0, chunk_count)
/// exactly once, on the caller's thread and the workers. Each thread has a home slice (slice i
/// of thread_count equal slices; the caller is thread 0), claims it in shrinking pieces from the
/// front and then helps with the others' slices: consecutive runs over the same data (the
/// element pass, then the vertex pass) mostly keep each slice on one core, yet a descheduled
/// thread's slice is taken over. Which thread runs which chunk still varies from run to run,
/// so callers that need bitwise-identical results make every chunk's result independent of the
/// thread that ran it and reduce per-chunk results in chunk order.
class ThreadPool {
 public:
  using ChunkFn = void (*)(void* context, int64_t chunk_begin, int64_t chunk_end);

  /// Starts `thread_count - 1` workers (thread_count >= 1; 0 means available_cores()).
  explicit ThreadPool(int thread_count);
  ~ThreadPool();
  ThreadPool(const ThreadPool&) = delete;
  ThreadPool& operator=(const ThreadPool&) = delete;

  /// Number of threads that share the work, the caller included.
  int thread_count() const { return thread_count_; }

  /// First chunk of thread `thread`'s home slice when `chunk_count` chunks are run on `threads`
  /// threads (slice i is [slice_begin(n, i, T), slice_begin(n, i + 1, T))). For callers that
  /// place data where a slice's thread will want it.
  static constexpr int64_t slice_begin(int64_t chunk_count, int64_t thread, int64_t threads) {
    return chunk_count * thread / threads;
  }
  /// The thread whose home slice holds `chunk`.
  static constexpr int64_t home_thread(int64_t chunk, int64_t chunk_count, int64_t threads) {
    int64_t i = 0;
    while (i + 1 < threads && slice_begin(chunk_count, i + 1, threads) <= chunk) ++i;
    return i;
  }

  /// Runs fn over chunks [0, chunk_count) (at most 2^24 chunks) and returns when all are done.
  /// Not reentrant: one caller at a time (the simulation thread).
  void run(int64_t chunk_count, ChunkFn fn, void* context);

 private:
  void worker_main(int index);
  // Claims and runs ranges of chunks of the current job, home slice first, until none is left.
  // Returns the number of chunks run.
  int64_t drain(int self);
  // Claims a piece of slice `r`; returns false when it is empty.
  bool claim(int r, int64_t* begin, int64_t* end);

  int thread_count_ = 1;
  std::vector<std::thread> workers_;
  // The current job. fn_ and context_ are written before the job's claim word is published
  // (release) and read only by a thread whose claim on that word succeeded (acquire); they are
  // rewritten only after every claimed chunk has finished (every Slice::active == 0).
  ChunkFn fn_ = nullptr;
  void* context_ = nullptr;
  // One claim word per slice, each on its own cache line: job (16 bits) | slice end (24 bits)
  // | next chunk (24 bits). The end lives in the word so that a late thread can never claim
  // past the end of a job it did not see start.
  struct alignas(64) Slice {
    std::atomic<uint64_t> word{0};
    // Thread i's count of "about to claim or running a claimed piece" (slice i's owner only
    // writes it): run() returns only when every one is zero, which keeps fn_ and context_
    // valid for every claimed chunk. One per thread, beside its own claim word, so that claims
    // do not bounce a shared counter between cores (two per claim).
    std::atomic<int32_t> active{0};
  };
  std::unique_ptr<Slice[]> slices_;
  std::atomic<uint32_t> generation_{0};  // wake-up signal for sleeping workers
  std::atomic<int32_t> sleepers_{0};          // workers asleep on generation_
  std::atomic<bool> caller_sleeping_{false};  // run() asleep on a Slice::active
  std::atomic<bool> stop_{false};
  uint32_t job_ = 0;
};

/// The process's shared pool, for passes that run many times a second outside a backend's step
/// (the static solver's: parallel.h's pooled_ranges), started on first use with
/// shared_pool_threads() threads; null while another caller holds it (two static runs on threads
/// of one process). Give it back with release_shared_pool.
ThreadPool* try_acquire_shared_pool();
void release_shared_pool();

/// Sets the shared pool's thread count (0: available_cores(), the default). A pool already
/// started with another count is replaced at its next acquisition.
void set_shared_pool_threads(int threads);
/// The thread count the shared pool has or will start with.
int shared_pool_threads();

}  // namespace zona
