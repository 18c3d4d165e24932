// Virtual coupling gains (Llewellyn's condition) and the passivity observer/controller.
#include "engine/haptics/haptics_coupling.h"

#include <algorithm>
#include <cmath>
#include <complex>
#include <limits>
#include <numbers>

namespace zona {

double llewellyn_margin(const CouplingGains& gains, const DeviceImpedance& device,
                        double period) {
  // The right side k_c T/2 - b_c cos(wT) peaks at wT = pi for b_c >= 0 (at wT -> 0 for a
  // negative damper, which Colgate's |B| covers).
  return device.damping - gains.stiffness * period / 2 - std::abs(gains.damping);
}

double llewellyn_margin_sweep(const CouplingGains& gains, const DeviceImpedance& device,
                              double period, int points) {
  using C = std::complex<double>;
  double margin = std::numeric_limits<double>::infinity();
  for (int i = 1; i <= points; ++i) {
    const double theta = std::numbers::pi * i / points;  // w T in (0, pi]
    const C zinv = std::exp(C(0, -theta));
    const C h = gains.stiffness + gains.damping * (1.0 - zinv) / period;
    const double rhs = period / 2 * ((1.0 - zinv) * h).real() / (1 - std::cos(theta));
    margin = std::min(margin, device.damping - rhs);
  }
  return margin;
}

CouplingGains auto_coupling_gains(const DeviceImpedance& device, double period,
                                  double max_stiffness, const CouplingDesign& design) {
  CouplingGains g;
  if (!(period > 0) || !(device.damping > 0)) return g;  // nothing can be rendered stably
  const double budget = device.damping / design.safety;  // [N*s/m]
  g.stiffness = std::min(max_stiffness, design.spring_share * 2 * budget / period);
  g.stiffness = std::max(g.stiffness, 0.0);
  // Damping for the device mass on the coupling spring, limited to what the budget leaves.
  const double critical = 2 * design.damping_ratio * std::sqrt(g.stiffness * device.mass);
  g.damping = std::max(0.0, std::min(critical, budget - g.stiffness * period / 2));
  return g;
}

Result<CouplingGains> choose_coupling_gains(const double* stiffness_override,
                                            const double* damping_override,
                                            const DeviceImpedance& device, double period,
                                            double max_stiffness) {
  CouplingGains g = auto_coupling_gains(device, period, max_stiffness);
  if (stiffness_override) {
    if (!std::isfinite(*stiffness_override) || *stiffness_override < 0)
      return make_error("haptics.coupling_stiffness: %g N/m must be finite and >= 0",
                        *stiffness_override);
    if (*stiffness_override > max_stiffness)
      return make_error("haptics.coupling_stiffness: %g N/m exceeds the device limit %g N/m",
                        *stiffness_override, max_stiffness);
    g.stiffness = *stiffness_override;
    if (!damping_override) {
      // Re-spend what the spring leaves on the damper.
      const double budget = device.damping / CouplingDesign{}.safety;
      g.damping = std::max(0.0, std::min(g.damping, budget - g.stiffness * period / 2));
    }
  }
  if (damping_override) {
    if (!std::isfinite(*damping_override) || *damping_override < 0)
      return make_error("haptics.coupling_damping: %g N*s/m must be finite and >= 0",
                        *damping_override);
    g.damping = *damping_override;
  }
  const double margin = llewellyn_margin(g, device, period);
  if (margin < 0)
    return make_error(
        "haptics.coupling_stiffness/coupling_damping: k_c %g N/m, b_c %g N*s/m violate "
        "Llewellyn's condition b >= k_c T/2 + b_c (device damping %g N*s/m, T %g s)",
        g.stiffness, g.damping, device.damping, period);
  return g;
}

void PassivityGuard::observe(Vec3d held_force, Vec3d displacement) {
  // Energy into the controller: the hand pushes the handle against the rendered force.
  for (int a = 0; a < 3; ++a) {
    const double work = -held_force[a] * displacement[a];
    if (std::isfinite(work)) energy_[a] += work;
  }
  min_energy_ = std::min(min_energy_, energy());
}

Vec3d PassivityGuard::control(Vec3d force, Vec3d velocity, double period) {
  constexpr double kPredictionFactor = 2.0;
  bool active = false;
  for (int a = 0; a < 3; ++a) {
    const double v = velocity[a];
    if (!(std::abs(v) > 1e-9) || !(period > 0) || !std::isfinite(force[a])) continue;
    // 1. Bound, before the fact: over the next period the force may give the hand back at most
    //    what the axis holds. A stale sample held while the hand yields (the simulation
    //    descheduled for 10 ms at first contact) would otherwise push the hand out with energy
    //    the environment never stored. The displacement is predicted as twice v T: a device
    //    that accelerates within the period moves further than v T (measured on the mouse
    //    scene: with v T alone the observer dipped to -4e-8 J). Scaling the force towards zero
    //    never reverses it, so this cannot kick.
    const double returned = force[a] * v * (kPredictionFactor * period);  // > 0: to the hand [J]
    const double budget = std::max(energy_[a], 0.0);
    if (returned > budget) {
      const double scaled = budget / (v * kPredictionFactor * period);
      clipped_ += (force[a] - scaled) * v * period;
      force[a] = scaled;
      active = true;
    }
    // 2. Hannaford-Ryu: damping that dissipates an observed deficit within one period at this
    //    velocity (the prediction above is inexact when the device accelerates).
    if (energy_[a] < 0) {
      const double alpha = std::min(-energy_[a] / (period * v * v), max_damping_);
      force[a] -= alpha * v;
      dissipated_ += alpha * v * v * period;
      active = true;
    }
  }
  if (active) ++active_ticks_;
  return force;
}

}  // namespace zona
