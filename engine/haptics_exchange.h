// Lock-free single-producer single-consumer exchange between the simulation and haptic threads.
//
// A triple buffer: the writer fills a private back slot and swaps it with the shared middle slot
// in one atomic exchange; the reader swaps its front slot with the middle only when the middle
// holds something new. Neither side ever waits, spins or allocates, and no slot is read while it
// is written (so the thread sanitizer sees no race, unlike a seqlock's racy copy).
#pragma once

#include <atomic>
#include <cstdint>
#include <type_traits>

#include "engine/vec.h"

namespace zona {

/// What the simulation publishes for the haptic thread after each step (cell units, SI).
struct HapticSample {
  int64_t sequence = 0;     ///< 1, 2, ... per publication; 0: nothing published yet
  double sim_time = 0;      ///< simulated time of the sample [s]
  int64_t wall_ns = 0;      ///< steady-clock time of publication [ns]
  Vec3d force{0, 0, 0};     ///< force the cell applies to the needle (resistance) [N]
  double stiffness = 0;     ///< local d|force| / d travel along `axis` [N/m]
  Vec3d axis{1, 0, 0};      ///< unit needle axis the stiffness acts along [-]
  Vec3d tool{0, 0, 0};      ///< needle tip the force was measured at [m]
  bool punctured = false;   ///< the membrane has given way
};

/// What the haptic thread publishes for the simulation: the commanded tool pose (cell units).
struct ToolCommand {
  int64_t sequence = 0;     ///< 1, 2, ... per haptic tick; 0: nothing commanded yet
  int64_t wall_ns = 0;      ///< steady-clock time of the tick [ns]
  Vec3d tool{0, 0, 0};      ///< commanded needle tip [m]
};

/// Triple buffer for one trivially copyable value: exactly one writer thread and one reader
/// thread. write() and read() are wait-free.
template <class T>
class TripleBuffer {
  static_assert(std::is_trivially_copyable_v<T>, "TripleBuffer holds plain values");

 public:
  /// Writer side: publishes `value`; a reader sees it (or a later one) at its next read().
  void write(const T& value) {
    slots_[back_] = value;
    // Release publishes the slot's bytes; acquire takes ownership of the old middle, which the
    // reader may just have finished reading.
    const uint8_t old = middle_.exchange(static_cast<uint8_t>(back_ | kFresh),
                                         std::memory_order_acq_rel);
    back_ = static_cast<uint8_t>(old & kIndex);
  }

  /// Reader side: copies the newest published value into `out`; returns true when it is newer
  /// than the previous read() (false: `out` gets the same value again, or T{} before any write).
  bool read(T& out) {
    bool fresh = false;
    if (middle_.load(std::memory_order_relaxed) & kFresh) {
      const uint8_t old = middle_.exchange(front_, std::memory_order_acq_rel);
      front_ = static_cast<uint8_t>(old & kIndex);
      fresh = true;
    }
    out = slots_[front_];
    return fresh;
  }

 private:
  static constexpr uint8_t kIndex = 3;
  static constexpr uint8_t kFresh = 4;
  T slots_[3]{};
  // Each side's private index on its own cache line, away from the shared one.
  alignas(64) uint8_t back_ = 0;          // writer only
  alignas(64) std::atomic<uint8_t> middle_{1};
  alignas(64) uint8_t front_ = 2;         // reader only
};

/// The two directions of the simulation <-> haptic channel.
struct HapticChannel {
  TripleBuffer<HapticSample> samples;  ///< simulation -> haptic
  TripleBuffer<ToolCommand> commands;  ///< haptic -> simulation
};

}  // namespace zona
