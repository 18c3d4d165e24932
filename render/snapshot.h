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

#include "engine/sim/simulation.h"
#include "engine/core/triple_buffer.h"
#include "engine/core/vec.h"

namespace zona {

/// What the render thread needs of one simulation state: everything that changes per step.
struct SceneSnapshot {
  std::vector<Vec3d> displacement;  ///< [m], (vertex_count)
  std::vector<float> scalar;        ///< colour-mapped field, SI unit, (vertex_count) or empty
  NeedleReport report;              ///< time, needle tip, force, puncture
  double steps_per_second = 0;      ///< simulation rate measured by the writer [1/s]
  uint64_t sequence = 0;            ///< publish count, for the reader's frame pacing
};

}  // namespace zona
