// Lock-free single-producer single-consumer exchange between the simulation and haptic threads.
//
// A triple buffer (engine/core/triple_buffer.h): the writer fills a private back slot and swaps it with the shared middle slot
// in one atomic exchange; the reader swaps its front slot with the middle only when the middle
// holds something new. Neither side ever waits, spins or allocates, and no slot is read while it
// is written (so the thread sanitizer sees no race, unlike a seqlock's racy copy).
#pragma once

#include <atomic>
#include <cstdint>
#include <type_traits>

#include "engine/core/triple_buffer.h"
#include "engine/core/vec.h"

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

/// The two directions of the simulation <-> haptic channel.
struct HapticChannel {
  TripleBuffer<HapticSample> samples;  ///< simulation -> haptic
  TripleBuffer<ToolCommand> commands;  ///< haptic -> simulation
};

}  // namespace zona
