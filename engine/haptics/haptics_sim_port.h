// The Simulation behind a haptic session's port: the hand's commanded tip goes in between step1
// and step2 (rate-limited), the needle report comes out as the haptic sample, and a failed step
// ends the session with its step and reason.
#pragma once

#include <cstdint>
#include <string>

#include "engine/haptics/haptics_loop.h"
#include "engine/sim/simulation.h"

namespace zona {

/// Adapts a Simulation to HapticSimulationPort.
///
/// The tip is handed in on every step, from the first: until the haptic thread has commanded a
/// pose it is held at the needle's start, where the device's home maps to. (A tip that followed
/// the scene's script until the first command arrived was then pulled back to the hand in one
/// jump; when the first command came after the script had pressed the membrane, about one start
/// in ten to twenty on a loaded machine, the jump blew the cell up. Holding it makes the steps
/// independent of when the first command arrives.)
///
/// The published force is the needle's load-cell reading until the puncture: the axial force
/// low-passed by needle.force_filter (the report's force), along the axis; from the puncture on,
/// the raw released load (haptic_axial_force says why). The lateral part is rendered only on
/// request, through the same filter: it is numerical noise on the axisymmetric injection, and
/// across the axis there is no local stiffness to render it with.
class SimulationHapticPort final : public HapticSimulationPort {
 public:
  /// `max_tip_speed` [m/s]: the tip follows the command at most this fast in simulated time
  /// (the coupling spring renders the lag rather than the solver taking a jump it cannot
  /// resolve).
  SimulationHapticPort(Simulation& sim, double max_tip_speed, bool lateral_force);

  HapticPortStatus step(const ToolCommand* command, HapticSample& sample) override;

  /// Steps taken (successful ones).
  int64_t steps() const { return steps_; }
  /// Steady-clock time [ns] of the first punctured sample; -1: none.
  int64_t puncture_wall_ns() const { return puncture_wall_ns_; }
  /// Why the simulation stopped (the step's flags, one line); empty while it runs.
  const std::string& failure() const { return failure_; }

 private:
  Simulation& sim_;
  double max_tip_speed_;
  bool lateral_force_;
  Vec3d tip_;
  Vec3d lateral_{0, 0, 0};  // low-passed lateral force [N]
  double lateral_time_ = 0;
  bool lateral_started_ = false;
  int64_t steps_ = 0;
  int64_t puncture_wall_ns_ = -1;
  std::string failure_;
};

}  // namespace zona
