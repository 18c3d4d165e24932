// The allocation counter of tests/engine/allocation_counter.h: this test binary's global
// operator new and delete, counting every allocation (sanitizer builds keep their own).
#include "tests/engine/allocation_counter.h"

#include <atomic>
#include <cstdlib>
#include <new>

namespace {
std::atomic<long long> g_allocations{0};
}  // namespace

#if !defined(__SANITIZE_ADDRESS__) && !defined(__SANITIZE_THREAD__)
#define ZONA_COUNTS_ALLOCATIONS 1
// malloc and free behind new and delete: GCC cannot see that they pair up.
#pragma GCC diagnostic ignored "-Wmismatched-new-delete"
void* operator new(std::size_t n) {
  g_allocations.fetch_add(1, std::memory_order_relaxed);
  if (void* p = std::malloc(n ? n : 1)) return p;
  throw std::bad_alloc();
}
void operator delete(void* p) noexcept { std::free(p); }
void operator delete(void* p, std::size_t) noexcept { std::free(p); }
#endif

namespace zona::test {
long long allocation_count() {
#ifdef ZONA_COUNTS_ALLOCATIONS
  return g_allocations.load();
#else
  return -1;
#endif
}
}  // namespace zona::test
