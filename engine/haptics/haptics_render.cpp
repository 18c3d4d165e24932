// One haptic tick: interpolation, virtual coupling, passivity guard, safety (no allocation).
#include "engine/haptics/haptics_render.h"

#include <algorithm>
#include <cmath>

namespace zona {
namespace {

bool finite(Vec3d v) { return std::isfinite(v.x) && std::isfinite(v.y) && std::isfinite(v.z); }

}  // namespace

void ForceInterpolator::push(Vec3d force, double stiffness_n_per_m, Vec3d axis_unit, Vec3d tool,
                             double time) {
  force0 = count > 0 ? force1 : force;
  time0 = count > 0 ? time1 : time;
  force1 = force;
  time1 = time;
  stiffness = stiffness_n_per_m;
  const double len = norm(axis_unit);
  axis = len > 0 ? axis_unit / len : Vec3d{1, 0, 0};
  tool1 = tool;
  ++count;
}

Vec3d ForceInterpolator::first_order_hold(double time) const {
  if (count < 2 || !(time1 > time0)) return force1;
  // Slope over at most one sample interval: beyond it the newest force is held.
  const double s = std::clamp((time - time1) / (time1 - time0), 0.0, 1.0);
  Vec3d f = force1 + s * (force1 - force0);
  // A contact force pushes, it does not pull: extrapolating a drop (the puncture) past zero
  // would reverse it and drive the hand forward, so a component whose sign differs from
  // either sample's stops at zero.
  for (int a = 0; a < 3; ++a)
    if (f[a] * force1[a] < 0 || f[a] * force0[a] < 0) f[a] = 0;
  return f;
}

double ForceInterpolator::unilateral(double f1n, double fn) {
  // A contact pushes: a resistance (f1n <= 0 along the insertion axis) extrapolated backwards
  // past zero would pull the hand forward, an energy source. The spring releases at zero.
  return f1n <= 0 ? std::min(fn, 0.0) : std::max(fn, 0.0);
}

Vec3d ForceInterpolator::stiffness_model(Vec3d tool) const {
  if (count == 0) return {0, 0, 0};
  const double f1n = dot(force1, axis);
  double fn = f1n - stiffness * dot(axis, tool - tool1);
  if (unilateral_contact) fn = unilateral(f1n, fn);
  return force1 + (fn - f1n) * axis;
}

Vec3d HapticSafety::apply(Vec3d force, double sample_age, double period, double stall_timeout,
                          double fade_time, double max_force) {
  if (stopped_) {
    last_good_ = {0, 0, 0};
    gain_ = 0;
    return {0, 0, 0};
  }
  // NaN guard first: everything after it works on finite numbers.
  if (!finite(force)) {
    ++nan_ticks_;
    force = last_good_;
  }
  // Fade out when the simulation has stalled (or never published), back in when it recovers.
  const bool stalled = sample_age < 0 || sample_age > stall_timeout;
  if (stalled) ++stalled_ticks_;
  const double step = fade_time > 0 ? period / fade_time : 1.0;
  gain_ = std::clamp(gain_ + (stalled || shutting_down_ ? -step : step), 0.0, 1.0);
  force = gain_ * force;
  // Clamp the magnitude to the device limit, keeping the direction.
  const double magnitude = norm(force);
  if (magnitude > max_force) {
    ++clamped_ticks_;
    force = (max_force / magnitude) * force;
  }
  last_good_ = force;
  return force;
}

HapticRenderer::HapticRenderer(const HapticRenderConfig& config)
    : config_(config), passivity_(config.max_pc_damping) {
  interp_.mode = config.interpolation;
  interp_.unilateral_contact = config.unilateral_contact;
}

void HapticRenderer::push_sample(const HapticSample& sample, double time) {
  if (!finite(sample.force) || !std::isfinite(sample.stiffness) || !finite(sample.tool) ||
      !finite(sample.axis) || !std::isfinite(time))
    return;
  const HapticScaling& sc = config_.scaling;
  // A negative slope (the membrane giving way) is not rendered as a spring: the drop arrives
  // with the next force sample. The positive slope is capped at the device's limit.
  const double k = std::clamp(sc.stiffness_to_device(sample.stiffness), 0.0,
                              config_.max_stiffness);
  interp_.push(sc.force_to_device(sample.force), k, sample.axis, sc.to_device(sample.tool), time);
  last_sample_time_ = time;
}

HapticOutput HapticRenderer::tick(Vec3d device_position, Vec3d device_velocity, double time) {
  const double T = config_.period;
  HapticOutput out;
  // 1. Observe the energy of the last period: the held force against the motion it saw.
  if (have_position_ && finite(device_position))
    passivity_.observe(last_force_, device_position - last_position_);

  // 2. Environment force at the tool and the massless tool's balance with the coupling:
  //    k_c e + b_c (e - e_prev) / T = -f_env(x_d - e), solved implicitly for the stretch e.
  const double kc = config_.coupling.stiffness, bc = config_.coupling.damping;
  const double a = kc + bc / T;
  Vec3d force{0, 0, 0};
  if (a > 0 && finite(device_position)) {
    const Vec3d memory = (bc / T) * stretch_;
    Vec3d e;
    if (interp_.mode == HapticInterpolation::kFirstOrderHold || interp_.count == 0) {
      const Vec3d env = interp_.count ? interp_.first_order_hold(time) : Vec3d{0, 0, 0};
      e = (1.0 / a) * (memory - env);
    } else {
      // f_env(x_t) = f1 - K n n.(x_d - e - x1): the stiffness acts only along the axis.
      const Vec3d n = interp_.axis;
      const double K = interp_.stiffness;
      const Vec3d r = memory - interp_.force1 +
                      (K * dot(n, device_position - interp_.tool1)) * n;
      const double rn = dot(r, n);
      double en = rn / (a + K);
      // The contact released (the tool behind the point where the extrapolated resistance
      // reaches zero): the axial balance is the coupling alone, k_c e + b_c (e - e_prev)/T = 0.
      const double f1n = dot(interp_.force1, n);
      const double fn = f1n - K * dot(n, device_position - en * n - interp_.tool1);
      if (interp_.unilateral_contact && ForceInterpolator::unilateral(f1n, fn) != fn)
        en = dot(memory, n) / a;
      e = (1.0 / a) * (r - rn * n) + en * n;
    }
    if (!finite(e)) e = {0, 0, 0};
    // The device feels the coupling's reaction, which equals f_env at the balanced tool.
    force = -(kc * e + (bc / T) * (e - stretch_));
    stretch_ = e;
    out.tool_device = device_position - e;
  } else if (finite(device_position)) {
    out.tool_device = device_position;
  } else {
    // A non-finite reading: keep commanding the last coupled tool pose.
    out.tool_device = have_position_ ? last_position_ - stretch_ : config_.scaling.device_origin;
  }

  // 3. Passivity controller: damp axes whose observed energy went negative.
  if (config_.passivity_control && finite(device_velocity))
    force = passivity_.control(force, device_velocity, T);

  // 4. Safety: NaN guard, stall fade, clamp, emergency stop.
  out.sample_age = last_sample_time_ < 0 ? -1.0 : time - last_sample_time_;
  force = safety_.apply(force, out.sample_age, T, config_.stall_timeout, config_.fade_time,
                        config_.max_force);

  out.force = force;
  out.tool_cell = config_.scaling.to_cell(out.tool_device);
  last_force_ = force;
  if (finite(device_position)) {
    last_position_ = device_position;
    have_position_ = true;
  }
  return out;
}

HapticRenderConfig make_render_config(const HapticsDef& haptics, const CouplingGains& gains,
                                      double device_max_force, double device_max_stiffness) {
  HapticRenderConfig c;
  c.period = haptics.rate > 0 ? 1.0 / haptics.rate : 1e-3;
  c.interpolation = haptics.interpolation;
  c.coupling = gains;
  // The tighter of the scene's and the device's limits.
  c.max_force = std::min(haptics.max_force, device_max_force);
  c.max_stiffness = std::min(haptics.max_stiffness, device_max_stiffness);
  c.stall_timeout = haptics.stall_timeout;
  c.scaling.workspace_scale = haptics.workspace_scale;
  c.scaling.force_scale = haptics.force_scale;
  return c;
}

}  // namespace zona
