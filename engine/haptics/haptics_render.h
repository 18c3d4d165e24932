// Haptic force rendering for one tick: hand <-> cell scaling, force interpolation between slow
// simulation samples, the virtual coupling solve, the passivity guard and the safety stage.
// Everything here is plain computation (no threads, no clock reads, no allocation), so the
// 1 kHz loop, the tests and the benchmark drive the same code.
#pragma once

#include <cstdint>

#include "engine/haptics/haptics_coupling.h"
#include "engine/haptics/haptics_exchange.h"
#include "engine/scene/scene.h"
#include "engine/core/vec.h"

namespace zona {

/// Hand <-> cell mapping. Device positions are relative to `device_origin`, cell positions to
/// `cell_origin` (the needle's start).
struct HapticScaling {
  double workspace_scale = 5e-3;   ///< cell displacement per device displacement [-]
  double force_scale = 1e5;        ///< device force per cell force [-]
  Vec3d device_origin{0, 0, 0};    ///< device position mapped to cell_origin [m]
  Vec3d cell_origin{0, 0, 0};      ///< [m]

  /// Device position [m] -> cell position [m].
  Vec3d to_cell(Vec3d device) const {
    return cell_origin + workspace_scale * (device - device_origin);
  }
  /// Cell position [m] -> device position [m].
  Vec3d to_device(Vec3d cell) const {
    return device_origin + (1.0 / workspace_scale) * (cell - cell_origin);
  }
  /// Cell force [N] -> device force [N].
  Vec3d force_to_device(Vec3d cell_force) const { return force_scale * cell_force; }
  /// Cell stiffness [N/m] -> device stiffness [N/m] (force scale times workspace scale).
  double stiffness_to_device(double cell_stiffness) const {
    return force_scale * workspace_scale * cell_stiffness;
  }
};

/// Settings of the renderer (device units unless said otherwise).
struct HapticRenderConfig {
  double period = 1e-3;            ///< haptic period T [s]
  HapticInterpolation interpolation = HapticInterpolation::kStiffness;
  CouplingGains coupling;          ///< virtual coupling [N/m], [N*s/m]
  double max_force = 3.3;          ///< device force limit [N]
  double max_stiffness = 400.0;    ///< device stiffness limit [N/m] (caps the local stiffness)
  double stall_timeout = 0.05;     ///< sample age after which the force fades out [s]
  double fade_time = 0.1;          ///< time for the fade from full to zero and back [s]
  double max_pc_damping = 10.0;    ///< passivity controller's damping limit [N*s/m]
  bool passivity_control = true;   ///< apply the passivity controller (the observer always runs)
  /// The stiffness model's axial force never changes sign (a needle contact pushes, it does not
  /// pull); off only to model a rigid, bilateral tool (the coupling criterion's worst case).
  bool unilateral_contact = true;
  HapticScaling scaling;
};

/// The force model between samples, in device units. Exposed for tests and the benchmark.
struct ForceInterpolator {
  HapticInterpolation mode = HapticInterpolation::kStiffness;
  /// Previous and newest samples: force [N], stiffness [N/m], axis, tool position [m], time [s].
  Vec3d force0{0, 0, 0}, force1{0, 0, 0};
  double time0 = 0, time1 = 0;
  double stiffness = 0;
  Vec3d axis{1, 0, 0};
  Vec3d tool1{0, 0, 0};
  int count = 0;  ///< samples taken (0, 1 or 2+)
  bool unilateral_contact = true;  ///< see HapticRenderConfig::unilateral_contact

  /// Takes a new sample (device units, time in seconds of the haptic clock).
  void push(Vec3d force, double stiffness_n_per_m, Vec3d axis_unit, Vec3d tool, double time);
  /// First-order hold: the force extrapolated to `time` [s] from the last two samples, the slope
  /// applied over at most one sample interval (then held, so a stalled simulation cannot ramp
  /// the force without bound); a component never changes sign by extrapolation [N].
  Vec3d first_order_hold(double time) const;
  /// Local stiffness model: force at tool position `tool` [m]: newest force minus stiffness
  /// times the displacement along the axis since the sample; with unilateral_contact the axial
  /// component stops at zero instead of changing sign (a contact never pulls) [N].
  Vec3d stiffness_model(Vec3d tool) const;
  /// The unilateral rule: axial force `fn` [N] limited to the sign of the sample's `f1n` [N].
  static double unilateral(double f1n, double fn);
};

/// Safety stage: NaN guard, stall fade, force clamp, emergency stop. Counts what it did.
class HapticSafety {
 public:
  /// Returns the force to send [N] given the rendered force [N], the sample age [s] (negative:
  /// no sample yet) and the period [s].
  Vec3d apply(Vec3d force, double sample_age, double period, double stall_timeout,
              double fade_time, double max_force);
  /// Latches the emergency stop: zero force from the next apply() on.
  void emergency_stop() { stopped_ = true; }
  /// Releases the emergency stop; the force then fades back in.
  void release() { stopped_ = false; gain_ = 0; }
  bool stopped() const { return stopped_; }
  /// Latches a shut-down: from the next apply() on the gain only falls, by period / fade_time
  /// a tick, to zero, and stays there (a failed simulation: no jolt, and nothing fades back).
  void shut_down() { shutting_down_ = true; }
  bool shutting_down() const { return shutting_down_; }
  /// Current fade gain in [0, 1].
  double gain() const { return gain_; }
  int64_t nan_ticks() const { return nan_ticks_; }
  int64_t clamped_ticks() const { return clamped_ticks_; }
  int64_t stalled_ticks() const { return stalled_ticks_; }

 private:
  Vec3d last_good_{0, 0, 0};
  double gain_ = 0;  // starts faded out: the force fades in with the first fresh samples
  bool stopped_ = false;
  bool shutting_down_ = false;
  int64_t nan_ticks_ = 0, clamped_ticks_ = 0, stalled_ticks_ = 0;
};

/// What one tick produced.
struct HapticOutput {
  Vec3d force{0, 0, 0};      ///< force sent to the device [N]
  Vec3d tool_device{0, 0, 0};  ///< coupled tool position, device units [m]
  Vec3d tool_cell{0, 0, 0};  ///< the same in cell units: the command for the simulation [m]
  double sample_age = -1;    ///< age of the newest sample [s]; negative: none yet
};

/// One haptic channel's rendering state: interpolation, coupling, passivity, safety.
class HapticRenderer {
 public:
  explicit HapticRenderer(const HapticRenderConfig& config);

  /// Takes a simulation sample (cell units) published at haptic-clock time `time` [s]; samples
  /// with a non-finite value are ignored (the stall fade then covers a broken simulation).
  void push_sample(const HapticSample& sample, double time);
  /// One tick at haptic-clock time `time` [s]: device position [m] and velocity [m/s] in.
  HapticOutput tick(Vec3d device_position, Vec3d device_velocity, double time);

  const HapticRenderConfig& config() const { return config_; }
  HapticSafety& safety() { return safety_; }
  const HapticSafety& safety() const { return safety_; }
  const PassivityGuard& passivity() const { return passivity_; }
  const ForceInterpolator& interpolator() const { return interp_; }

 private:
  HapticRenderConfig config_;
  ForceInterpolator interp_;
  PassivityGuard passivity_;
  HapticSafety safety_;
  Vec3d stretch_{0, 0, 0};      // coupling stretch e = device - tool [m]
  Vec3d last_force_{0, 0, 0};   // force sent on the previous tick [N]
  Vec3d last_position_{0, 0, 0};
  bool have_position_ = false;
  double last_sample_time_ = -1;
};

/// Renderer settings from a scene's haptics block, the device limits and coupling gains.
HapticRenderConfig make_render_config(const HapticsDef& haptics, const CouplingGains& gains,
                                      double device_max_force, double device_max_stiffness);

}  // namespace zona
