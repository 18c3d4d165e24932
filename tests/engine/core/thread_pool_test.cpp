// Thread pool: every chunk runs exactly once, for any thread and chunk count, many times over.
#include "engine/core/thread_pool.h"

#include <gtest/gtest.h>

#include <atomic>
#include <vector>

#if defined(__linux__)
#include <sched.h>
#endif

namespace zona {
namespace {

struct Counts {
  std::vector<std::atomic<int>> hits;
  explicit Counts(size_t n) : hits(n) {}
};

void count_chunks(void* context, int64_t begin, int64_t end) {
  auto* c = static_cast<Counts*>(context);
  for (int64_t i = begin; i < end; ++i) c->hits[static_cast<size_t>(i)].fetch_add(1);
}

TEST(ThreadPool, EveryChunkRunsOnce) {
  for (int threads : {1, 2, 3, 5}) {
    ThreadPool pool(threads);
    EXPECT_EQ(pool.thread_count(), threads);
    for (int64_t chunks : {1, 2, 3, 7, 64}) {
      Counts c(static_cast<size_t>(chunks));
      for (int round = 0; round < 50; ++round) pool.run(chunks, &count_chunks, &c);
      for (auto& h : c.hits) EXPECT_EQ(h.load(), 50) << threads << " threads, " << chunks;
    }
    pool.run(0, &count_chunks, nullptr);  // nothing to do: returns at once
  }
}

TEST(ThreadPool, DefaultUsesTheCoresThisProcessMayRunOn) {
  ThreadPool pool(0);
  EXPECT_EQ(pool.thread_count(), available_cores());
  EXPECT_GE(pool.thread_count(), 1);
}

#if defined(__linux__)
// A job given one core (taskset, a SLURM task's --cpus-per-task) counts one, whatever the machine
// has: std::thread::hardware_concurrency would count them all.
TEST(ThreadPool, AvailableCoresFollowTheAffinityMask) {
  cpu_set_t all;
  ASSERT_EQ(sched_getaffinity(0, sizeof(all), &all), 0);
  EXPECT_EQ(available_cores(), CPU_COUNT(&all));
  int first = 0;
  while (!CPU_ISSET(first, &all)) ++first;
  cpu_set_t one;
  CPU_ZERO(&one);
  CPU_SET(first, &one);
  ASSERT_EQ(sched_setaffinity(0, sizeof(one), &one), 0);
  const int cores = available_cores();
  ASSERT_EQ(sched_setaffinity(0, sizeof(all), &all), 0);
  EXPECT_EQ(cores, 1);
}
#endif

TEST(ThreadPool, TheSharedPoolTakesTheSetThreadCount) {
  for (int threads : {3, 1, 0}) {
    set_shared_pool_threads(threads);
    ThreadPool* pool = try_acquire_shared_pool();
    ASSERT_NE(pool, nullptr);
    EXPECT_EQ(pool->thread_count(), threads > 0 ? threads : available_cores());
    EXPECT_EQ(shared_pool_threads(), pool->thread_count());
    Counts c(7);
    pool->run(7, &count_chunks, &c);
    for (auto& h : c.hits) EXPECT_EQ(h.load(), 1) << threads << " threads";
    release_shared_pool();
  }
}

}  // namespace
}  // namespace zona
