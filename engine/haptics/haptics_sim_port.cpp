// SimulationHapticPort: one simulation step per call with the hand's tip handed in.
#include "engine/haptics/haptics_sim_port.h"

#include <cmath>
#include <cstdio>

#include "engine/sim/recorder.h"

namespace zona {

SimulationHapticPort::SimulationHapticPort(Simulation& sim, double max_tip_speed,
                                           bool lateral_force)
    : sim_(sim), max_tip_speed_(max_tip_speed), lateral_force_(lateral_force),
      tip_(sim.needle_script().start) {}

HapticPortStatus SimulationHapticPort::step(const ToolCommand* command, HapticSample& sample) {
  if (!failure_.empty()) return HapticPortStatus::kFailed;
  if (sim_.finished()) return HapticPortStatus::kFinished;
  sim_.step1();
  // The tip follows the command at most at max_tip_speed; with no command yet it stays where
  // the hand's home maps to (see the class comment).
  if (command) {
    const Vec3d delta = command->tool - tip_;
    const double len = norm(delta);
    const double max_step = max_tip_speed_ * sim_.model().dt;
    tip_ = len > max_step ? tip_ + (max_step / len) * delta : command->tool;
  }
  sim_.set_needle_tip(tip_);
  const StepStatus status = sim_.step2();
  const NeedleReport& r = sim_.report();
  if (status & kStepFailed) {
    // Never sent: the session ramps the force down and stops (run_haptic_session).
    std::string why;
    for (const std::string& name : step_flag_names(status & kStepFailed))
      why += (why.empty() ? "" : ", ") + name;
    char line[200];
    std::snprintf(line, sizeof line, "the simulation failed at step %lld (t %.6g s): %s",
                  static_cast<long long>(steps_ + 1), r.time, why.c_str());
    failure_ = line;
    return HapticPortStatus::kFailed;
  }
  const Vec3d axis = sim_.needle_script().direction;
  sample.sim_time = r.time;
  // The cell's force on the needle: resistance along -axis (haptic_axial_force is resistance
  // positive; filtered until the puncture, raw after it), plus the filtered lateral reaction
  // when asked for.
  sample.force = -haptic_axial_force(r) * axis;
  if (lateral_force_) {
    const Vec3d raw = -r.force_vector;
    const Vec3d lateral = raw - dot(raw, axis) * axis;
    const double tau = sim_.scene().needle.force_filter;
    const double h = r.time - lateral_time_;
    // The same first-order low-pass as the axial force (exact for a held input).
    const double w = tau > 0 && lateral_started_ ? 1.0 - std::exp(-h / tau) : 1.0;
    lateral_ = lateral_ + w * (lateral - lateral_);
    lateral_started_ = true;
    lateral_time_ = r.time;
    sample.force += lateral_;
  }
  sample.stiffness = r.stiffness;
  sample.axis = axis;
  sample.tool = r.tip;
  sample.punctured = r.punctured;
  if (r.punctured && puncture_wall_ns_ < 0) puncture_wall_ns_ = haptic_clock_ns();
  ++steps_;
  return HapticPortStatus::kStepped;
}

}  // namespace zona
