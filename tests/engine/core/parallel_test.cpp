// parallel_ranges covers its range once in fixed ranges, and pooled_ranges in the same ranges
// on the shared pool or, while another caller holds it, on threads of its own; parallel_sort
// gives the sorted sequence for any thread count.
#include "engine/core/parallel.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <atomic>
#include <cstdint>
#include <random>
#include <vector>

namespace zona {
namespace {

TEST(Parallel, RangesCoverEveryIndexOnceInTheirFixedSplit) {
  for (int threads : {1, 3, 8})
    for (size_t n : {size_t{0}, size_t{5}, size_t{1000}}) {
      std::vector<int> hits(n, 0);
      std::vector<size_t> first(parallel_range_count(n, threads, 10), n);
      const size_t ranges =
          parallel_ranges(n, threads, 10, [&](size_t r, size_t begin, size_t end) {
            first[r] = begin;
            for (size_t i = begin; i < end; ++i) ++hits[i];
          });
      EXPECT_EQ(ranges, first.size());
      EXPECT_LE(ranges, static_cast<size_t>(threads));
      for (size_t r = 0; r < ranges; ++r) EXPECT_EQ(first[r], n * r / ranges);
      EXPECT_TRUE(std::all_of(hits.begin(), hits.end(), [](int h) { return h == 1; }));
    }
}

TEST(Parallel, PooledRangesAreParallelRangesOnTheSharedPool) {
  const int threads = setup_thread_count(0);
  for (bool held : {false, true}) {
    // Held: another caller has the pool, and the ranges run on threads of their own.
    ThreadPool* other = held ? try_acquire_shared_pool() : nullptr;
    ASSERT_EQ(held, other != nullptr);
    for (size_t n : {size_t{0}, size_t{5}, size_t{100000}}) {
      std::vector<std::atomic<int>> hits(n);
      std::vector<size_t> first(parallel_range_count(n, threads, 10), n);
      const size_t ranges = pooled_ranges(n, 10, [&](size_t r, size_t begin, size_t end) {
        first[r] = begin;
        for (size_t i = begin; i < end; ++i) hits[i].fetch_add(1);
      });
      EXPECT_EQ(ranges, first.size()) << "held " << held;
      for (size_t r = 0; r < ranges; ++r) EXPECT_EQ(first[r], n * r / ranges);
      EXPECT_TRUE(std::all_of(hits.begin(), hits.end(), [](const std::atomic<int>& h) {
        return h.load() == 1;
      }));
    }
    if (other != nullptr) release_shared_pool();
  }
  // Given back: the next caller gets it.
  ThreadPool* pool = try_acquire_shared_pool();
  EXPECT_NE(pool, nullptr);
  if (pool != nullptr) release_shared_pool();
}

TEST(Parallel, SortEqualsTheSerialSortForAnyThreadCount) {
  std::mt19937_64 random(7);
  std::vector<std::pair<uint64_t, int32_t>> keys(10007);
  for (size_t i = 0; i < keys.size(); ++i)
    keys[i] = {random() % 512, static_cast<int32_t>(i)};  // repeated codes, unique pairs
  std::vector<std::pair<uint64_t, int32_t>> expected = keys;
  std::sort(expected.begin(), expected.end());
  for (int threads : {1, 2, 3, 5, 8, 13}) {
    std::vector<std::pair<uint64_t, int32_t>> sorted = keys;
    parallel_sort(sorted.begin(), sorted.end(), threads, 100, std::less<>());
    EXPECT_EQ(sorted, expected) << threads << " threads";
  }
}

}  // namespace
}  // namespace zona
