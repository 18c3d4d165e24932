// Thread pool: every chunk runs exactly once, for any thread and chunk count, many times over.
#include "engine/core/thread_pool.h"

#include <gtest/gtest.h>

#include <atomic>
#include <vector>

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

TEST(ThreadPool, DefaultUsesTheHardware) {
  ThreadPool pool(0);
  EXPECT_GE(pool.thread_count(), 1);
}

}  // namespace
}  // namespace zona
