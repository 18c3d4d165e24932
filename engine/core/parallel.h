// A static split of an index range over short-lived threads, for setup (model build, mass
// scaling): each range is a fixed function of (n, threads), so work that writes only what its
// indices own, and reductions combined in range order, give the same bits for any thread count.
// The step's parallel passes use ThreadPool instead (long-lived workers, claimed chunks).
#pragma once

#include <algorithm>
#include <cstddef>
#include <thread>
#include <vector>

namespace zona {

/// Threads for setup work: `requested` when positive, else the hardware's count.
inline int setup_thread_count(int requested) {
  if (requested > 0) return requested;
  return std::max(1, static_cast<int>(std::thread::hardware_concurrency()));
}

/// The number of ranges parallel_ranges makes for these arguments.
inline size_t parallel_range_count(size_t n, int threads, size_t min_per_range) {
  return std::clamp<size_t>(static_cast<size_t>(std::max(threads, 1)), 1,
                            std::max<size_t>(n / std::max<size_t>(min_per_range, 1), 1));
}

/// Calls work(range, begin, end) for ranges r = 0 .. R-1 covering [0, n) in order, R =
/// min(threads, n / min_per_range) (at least 1), range r on its own thread (range 0 on the
/// caller's). Returns R, so that callers can size per-range results before or combine them after.
template <class F>
size_t parallel_ranges(size_t n, int threads, size_t min_per_range, const F& work) {
  const size_t ranges = parallel_range_count(n, threads, min_per_range);
  if (ranges == 1) {
    work(size_t{0}, size_t{0}, n);
    return 1;
  }
  std::vector<std::thread> pool;
  pool.reserve(ranges - 1);
  for (size_t r = 1; r < ranges; ++r)
    pool.emplace_back([&work, r, n, ranges] { work(r, n * r / ranges, n * (r + 1) / ranges); });
  work(size_t{0}, size_t{0}, n / ranges);
  for (std::thread& t : pool) t.join();
  return ranges;
}

}  // namespace zona
