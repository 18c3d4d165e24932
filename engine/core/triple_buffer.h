// Lock-free single-producer single-consumer hand-over of the newest value: a triple buffer.
// Used between the simulation and the haptic thread (engine/haptics/haptics_exchange.h), the simulation
// and a render thread (Simulation's surface snapshots, render/snapshot.h).
//
// The writer fills a private back slot and swaps it with the shared middle slot in one atomic
// exchange; the reader swaps its front slot with the middle only when the middle holds something
// new. Neither side ever waits or spins, values the reader missed are skipped (it wants the
// newest), and no slot is read while it is written (the thread sanitizer sees no race, unlike a
// two-slot flip, where a writer that publishes twice during one read overwrites the slot being
// read). Slots are made once from `initial`: give vectors their final sizes there, and publishing
// never allocates.
#pragma once

#include <atomic>
#include <cstdint>

namespace zona {

/// A triple buffer of T: exactly one writer thread and one reader thread; every call is
/// wait-free.
template <class T>
class TripleBuffer {
 public:
  /// All three slots start as copies of `initial`.
  explicit TripleBuffer(const T& initial = T()) : slots_{initial, initial, initial} {}
  TripleBuffer(const TripleBuffer&) = delete;
  TripleBuffer& operator=(const TripleBuffer&) = delete;

  /// Writer: the slot to fill (private to the writer until publish()).
  T& write_slot() { return slots_[back_]; }
  /// Writer: makes the filled slot the newest; the writer gets a free slot in exchange. Release
  /// publishes the slot's bytes; acquire takes ownership of the old middle, which the reader may
  /// just have finished reading.
  void publish() {
    const uint8_t old =
        middle_.exchange(static_cast<uint8_t>(back_ | kFresh), std::memory_order_acq_rel);
    back_ = static_cast<uint8_t>(old & kIndex);
  }
  /// Writer: copies `value` into the write slot and publishes it.
  void write(const T& value) {
    write_slot() = value;
    publish();
  }

  /// Reader: takes the newest published slot when there is one; true when it is new.
  bool acquire() {
    if (!(middle_.load(std::memory_order_relaxed) & kFresh)) return false;
    const uint8_t old = middle_.exchange(front_, std::memory_order_acq_rel);
    front_ = static_cast<uint8_t>(old & kIndex);
    return true;
  }
  /// Reader: the slot taken by the last acquire() (the initial value before any).
  const T& read_slot() const { return slots_[front_]; }
  /// Reader: acquire() and a copy of the read slot into `out`; true when it is newer than the
  /// previous read (false: `out` gets the same value again, or the initial value before any
  /// write).
  bool read(T& out) {
    const bool fresh = acquire();
    out = read_slot();
    return fresh;
  }

 private:
  static constexpr uint8_t kIndex = 0x3, kFresh = 0x4;
  T slots_[3];
  // Each side's private index on its own cache line, away from the shared one.
  alignas(64) uint8_t back_ = 0;                // writer's slot
  alignas(64) std::atomic<uint8_t> middle_{1};  // published slot (| kFresh when not yet taken)
  alignas(64) uint8_t front_ = 2;               // reader's slot
  static_assert(std::atomic<uint8_t>::is_always_lock_free);
};

}  // namespace zona
