// A static split of an index range over short-lived threads, for setup (model build, mass
// scaling): each range is a fixed function of (n, threads), so work that writes only what its
// indices own, and reductions combined in range order, give the same bits for any thread count.
// The step's parallel passes use ThreadPool instead (long-lived workers, claimed chunks);
// passes that run many times a second outside a step take pooled_ranges (the same ranges on the
// shared ThreadPool).
#pragma once

#include <algorithm>
#include <cstddef>
#include <thread>
#include <vector>

#include "engine/core/thread_pool.h"

namespace zona {

/// Threads for setup work: `requested` when positive, else available_cores().
inline int setup_thread_count(int requested) {
  if (requested > 0) return requested;
  return available_cores();
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

/// parallel_ranges on the process's shared ThreadPool (try_acquire_shared_pool) instead of
/// threads started per call, with the ranges parallel_ranges makes for the pool's thread count
/// (so the same bits); on threads of its own while another caller holds the pool.
template <class F>
size_t pooled_ranges(size_t n, size_t min_per_range, const F& work) {
  ThreadPool* pool = try_acquire_shared_pool();
  if (pool == nullptr) return parallel_ranges(n, setup_thread_count(0), min_per_range, work);
  struct Job {
    const F* work;
    size_t n, ranges;
  } job{&work, n, parallel_range_count(n, pool->thread_count(), min_per_range)};
  if (job.ranges == 1) {
    work(size_t{0}, size_t{0}, n);
  } else {
    pool->run(static_cast<int64_t>(job.ranges), [](void* context, int64_t begin, int64_t end) {
      const Job& j = *static_cast<const Job*>(context);
      for (size_t r = static_cast<size_t>(begin); r < static_cast<size_t>(end); ++r)
        (*j.work)(r, j.n * r / j.ranges, j.n * (r + 1) / j.ranges);
    }, &job);
  }
  release_shared_pool();
  return job.ranges;
}

/// Fixed chunks of `chunk` indices over [0, n) on the shared pool (pooled_ranges over the
/// chunks): work(c, begin, end) for chunk c = [c chunk, min(n, (c + 1) chunk)). The chunks do not
/// depend on the thread count, so results kept per chunk and combined in chunk order are the same
/// bits on any machine. Returns the chunk count.
template <class F>
size_t pooled_chunks(size_t n, size_t chunk, const F& work) {
  const size_t count = (n + chunk - 1) / chunk;
  pooled_ranges(count, 1, [&](size_t, size_t begin, size_t end) {
    for (size_t c = begin; c < end; ++c) work(c, c * chunk, std::min(n, (c + 1) * chunk));
  });
  return count;
}

/// pooled_chunks where work(begin, end) returns each chunk's value: the values kept in `partial`
/// (sized here; no allocation once it has the chunk count) and added in chunk order, so the sum
/// is the same bits on any thread count.
template <class F>
double pooled_chunk_sum(size_t n, size_t chunk, std::vector<double>& partial, const F& work) {
  partial.resize((n + chunk - 1) / chunk);
  pooled_chunks(n, chunk, [&](size_t c, size_t begin, size_t end) { partial[c] = work(begin, end); });
  double total = 0;
  for (double x : partial) total += x;
  return total;
}

/// Sorts [first, last) by `comp`: ranges sorted side by side, then merged pairwise, the pairs
/// of each level side by side. With a strict total order on the elements (no two equivalent),
/// the result is the one sorted sequence, whatever the thread count.
template <class It, class Compare>
void parallel_sort(It first, It last, int threads, size_t min_per_range, Compare comp) {
  const size_t n = static_cast<size_t>(last - first);
  const size_t ranges = parallel_range_count(n, threads, min_per_range);
  parallel_ranges(n, threads, min_per_range, [&](size_t, size_t begin, size_t end) {
    std::sort(first + static_cast<std::ptrdiff_t>(begin), first + static_cast<std::ptrdiff_t>(end),
              comp);
  });
  auto bound = [&](size_t r) { return first + static_cast<std::ptrdiff_t>(n * r / ranges); };
  for (size_t width = 1; width < ranges; width *= 2) {
    const size_t pairs = (ranges + 2 * width - 1) / (2 * width);
    parallel_ranges(pairs, threads, 1, [&](size_t, size_t begin, size_t end) {
      for (size_t p = begin; p < end; ++p) {
        const size_t i = 2 * width * p;
        if (i + width < ranges)
          std::inplace_merge(bound(i), bound(i + width), bound(std::min(i + 2 * width, ranges)),
                             comp);
      }
    });
  }
}

}  // namespace zona
