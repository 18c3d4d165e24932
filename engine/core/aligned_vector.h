// std::vector with cache-line aligned storage, for the arrays that the CPU's SIMD loops read with
// full-width loads (a 512-bit load from an unaligned start straddles two cache lines every time).
#pragma once

#include <cstddef>
#include <new>
#include <vector>

namespace zona {

/// Allocator of 64-byte (cache-line) aligned storage.
template <class T>
struct CacheAlignedAllocator {
  using value_type = T;
  static constexpr std::align_val_t kAlignment{64};

  CacheAlignedAllocator() = default;
  template <class U>
  CacheAlignedAllocator(const CacheAlignedAllocator<U>&) noexcept {}  // NOLINT: rebinding

  T* allocate(std::size_t n) { return static_cast<T*>(::operator new(n * sizeof(T), kAlignment)); }
  void deallocate(T* p, std::size_t n) noexcept { ::operator delete(p, n * sizeof(T), kAlignment); }
  template <class U>
  bool operator==(const CacheAlignedAllocator<U>&) const noexcept {
    return true;
  }
};

/// A vector whose data() is 64-byte aligned.
template <class T>
using CacheAlignedVector = std::vector<T, CacheAlignedAllocator<T>>;

}  // namespace zona
