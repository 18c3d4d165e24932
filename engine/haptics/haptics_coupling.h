// Virtual coupling between the haptic device and the simulated needle: gains from Llewellyn's
// absolute-stability condition (Ladjal et al., eqs. 8-10) and a Hannaford-Ryu passivity observer and
// controller as the run-time guard.
#pragma once

#include <string>

#include "engine/core/base.h"
#include "engine/core/vec.h"

namespace zona {

/// The device's own mechanical impedance Z_d(s) = mass s + damping, as seen at the handle.
struct DeviceImpedance {
  double mass = 0.045;   ///< effective moving mass [kg]
  double damping = 0.4;  ///< physical (viscous) damping of the mechanism [N*s/m]
};

/// Spring-damper between the device and the tool, in device units.
struct CouplingGains {
  double stiffness = 0;  ///< k_c [N/m]
  double damping = 0;    ///< b_c [N*s/m]
};

/// Llewellyn's absolute-stability margin of the impedance display with virtual coupling, closed
/// form: Re Z_d - k_c T / 2 - b_c = damping - k_c T / 2 - b_c [N*s/m]; stable when >= 0.
/// Derivation (docs/haptics.md): with a zero-order hold and a backward-difference coupling
/// damper, eq. (10) of Ladjal et al. reduces for every frequency 0 < w <= pi/T to
///   b >= T/2 * Re{(1 - e^{-jwT}) H(e^{jwT})} / (1 - cos wT),  H(z) = k_c + b_c (1 - z^-1) / T,
/// whose right side is k_c T/2 - b_c cos wT, largest at the Nyquist frequency.
double llewellyn_margin(const CouplingGains& gains, const DeviceImpedance& device,
                        double period);

/// The same margin evaluated numerically on `points` frequencies in (0, pi/T] from the complex
/// expression above (a check of the closed form, and of other discretisations) [N*s/m].
double llewellyn_margin_sweep(const CouplingGains& gains, const DeviceImpedance& device,
                              double period, int points = 512);

/// Options of the automatic gain choice.
struct CouplingDesign {
  double safety = 1.25;   ///< the gains use damping / safety of the device's damping [-]
  double spring_share = 0.5;  ///< share of that budget given to the spring term k_c T / 2 [-]
  double damping_ratio = 0.7; ///< b_c at most this ratio of critical for the device mass [-]
};

/// Gains from the device impedance and the haptic period [s]: k_c = min(max_stiffness,
/// spring_share * 2 (b / safety) / T), then b_c = min(2 zeta sqrt(k_c m), b / safety - k_c T/2).
/// The result satisfies llewellyn_margin >= b (1 - 1 / safety) > 0.
CouplingGains auto_coupling_gains(const DeviceImpedance& device, double period,
                                  double max_stiffness, const CouplingDesign& design = {});

/// Gains from a scene's optional overrides (nullopt: the automatic value for that gain). Error
/// (one line, naming the scene key) when the result violates the condition or the device's
/// stiffness limit, or a gain is negative or not finite.
Result<CouplingGains> choose_coupling_gains(const double* stiffness_override,
                                            const double* damping_override,
                                            const DeviceImpedance& device, double period,
                                            double max_stiffness);

/// Hannaford-Ryu passivity observer and controller, one per axis (3 DOF). The observed port is
/// the device handle: energy flowing from the hand into the controller is positive, so a
/// passive controller keeps every axis' energy >= 0. The controller first bounds the energy the
/// next period may return to what the axis holds (an energy-bounding step before the fact),
/// then damps any deficit the observer still sees (Hannaford and Ryu's variable damper).
class PassivityGuard {
 public:
  /// `max_damping`: the largest damping the controller may add [N*s/m].
  explicit PassivityGuard(double max_damping = 10.0) : max_damping_(max_damping) {}

  /// Observer: the force held on the device over the last period [N] and the device motion over
  /// that period [m] (exact for a zero-order-held force).
  void observe(Vec3d held_force, Vec3d displacement);

  /// Controller, per axis: scales the force towards zero where, held for the next `period` [s]
  /// over twice the displacement `velocity` [m/s] predicts (a margin for acceleration), it
  /// would return more energy than the axis holds; then adds a damping
  /// force against the velocity where the energy is negative, dissipating the deficit over the
  /// next period (at most the damping limit). Returns the corrected force [N].
  Vec3d control(Vec3d force, Vec3d velocity, double period);

  /// Observed energy, summed over axes [J].
  double energy() const { return energy_.x + energy_.y + energy_.z; }
  /// Observed energy per axis [J].
  Vec3d axis_energy() const { return energy_; }
  /// Lowest summed energy seen [J] (negative: the controller had work to do).
  double min_energy() const { return min_energy_; }
  /// Ticks on which the controller added damping.
  int64_t active_ticks() const { return active_ticks_; }
  /// Energy the controller dissipated so far (predicted from the velocity) [J].
  double dissipated() const { return dissipated_; }
  /// Energy the bound kept from being returned to the hand (predicted from the velocity) [J].
  double clipped() const { return clipped_; }

 private:
  double max_damping_;
  Vec3d energy_{0, 0, 0};
  double min_energy_ = 0;
  double dissipated_ = 0;
  double clipped_ = 0;
  int64_t active_ticks_ = 0;
};

}  // namespace zona
