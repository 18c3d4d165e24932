// The triple buffer between the simulation and render threads: newest wins, a snapshot is never
// torn, and neither side waits.
#include "render/snapshot.h"

#include <gtest/gtest.h>

#include <thread>

namespace zona {
namespace {

TEST(TripleBuffer, ReaderGetsTheNewestPublishedSlot) {
  TripleBuffer<int> buffer(-1);
  EXPECT_FALSE(buffer.acquire());  // nothing published yet
  EXPECT_EQ(buffer.read_slot(), -1);
  buffer.write_slot() = 1;
  buffer.publish();
  buffer.write_slot() = 2;
  buffer.publish();  // replaces 1 before the reader looked
  EXPECT_TRUE(buffer.acquire());
  EXPECT_EQ(buffer.read_slot(), 2);
  EXPECT_FALSE(buffer.acquire());  // nothing newer: keeps its slot
  EXPECT_EQ(buffer.read_slot(), 2);
  buffer.write_slot() = 3;
  buffer.publish();
  EXPECT_TRUE(buffer.acquire());
  EXPECT_EQ(buffer.read_slot(), 3);
}

TEST(TripleBuffer, SnapshotsAreNeverTornAcrossThreads) {
  // Each snapshot is a vector filled with one value; a torn read would mix two values.
  constexpr size_t kSize = 512;
  TripleBuffer<std::vector<int>> buffer(std::vector<int>(kSize, 0));
  constexpr int kWrites = 20000;
  std::thread writer([&] {
    for (int i = 1; i <= kWrites; ++i) {
      std::vector<int>& slot = buffer.write_slot();
      for (int& v : slot) v = i;
      buffer.publish();
    }
  });
  int last = 0, torn = 0, backwards = 0;
  while (last < kWrites) {
    if (!buffer.acquire()) continue;
    const std::vector<int>& s = buffer.read_slot();
    for (int v : s) torn += v != s[0];
    backwards += s[0] < last;
    last = s[0];
  }
  writer.join();
  EXPECT_EQ(torn, 0);
  EXPECT_EQ(backwards, 0);
  EXPECT_EQ(last, kWrites);
}

}  // namespace
}  // namespace zona
