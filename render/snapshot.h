// Hand-over of frames from the simulation thread to the render thread without either ever
// waiting: a triple buffer. The writer fills its private slot and publishes it with one atomic
// exchange; the reader takes the newest published slot with one exchange. Neither side blocks,
// the reader always sees a complete snapshot, and frames the reader missed are simply skipped
// (the render thread wants the newest state, not every state).
//
// Slots are allocated up front (make them with the right sizes once): publish and acquire
// never allocate, so the writer may be the simulation's step path.
#pragma once

#include <atomic>
#include <cstdint>
#include <vector>

#include "engine/simulation.h"
#include "engine/vec.h"

namespace zona {

/// A triple buffer of T. One writer thread and one reader thread.
template <class T>
class TripleBuffer {
 public:
  /// All three slots start as copies of `initial` (give vectors their final sizes here).
  explicit TripleBuffer(const T& initial = T()) : slots_{initial, initial, initial} {}
  TripleBuffer(const TripleBuffer&) = delete;
  TripleBuffer& operator=(const TripleBuffer&) = delete;

  /// Writer: the slot to fill (private to the writer until publish()).
  T& write_slot() { return slots_[back_]; }
  /// Writer: makes the filled slot the newest; the writer gets a free slot in exchange.
  void publish() {
    const uint8_t previous =
        middle_.exchange(static_cast<uint8_t>(back_ | kFresh), std::memory_order_acq_rel);
    back_ = previous & kIndex;
  }

  /// Reader: takes the newest published slot when there is one; returns true when it is new.
  bool acquire() {
    if (!(middle_.load(std::memory_order_relaxed) & kFresh)) return false;
    const uint8_t previous = middle_.exchange(front_, std::memory_order_acq_rel);
    front_ = previous & kIndex;
    return true;
  }
  /// Reader: the slot taken by the last acquire() (the initial value before any).
  const T& read_slot() const { return slots_[front_]; }

 private:
  static constexpr uint8_t kIndex = 0x3, kFresh = 0x4;
  T slots_[3];
  uint8_t back_ = 0;                // writer's slot
  std::atomic<uint8_t> middle_{1};  // published slot (| kFresh when not yet taken)
  uint8_t front_ = 2;               // reader's slot
  static_assert(std::atomic<uint8_t>::is_always_lock_free);
};

/// What the render thread needs of one simulation state: everything that changes per step.
struct SceneSnapshot {
  std::vector<Vec3d> displacement;  ///< [m], (vertex_count)
  std::vector<float> scalar;        ///< colour-mapped field, SI unit, (vertex_count) or empty
  NeedleReport report;              ///< time, needle tip, force, puncture
  double steps_per_second = 0;      ///< simulation rate measured by the writer [1/s]
  uint64_t sequence = 0;            ///< publish count, for the reader's frame pacing
};

}  // namespace zona
