// Virtual coupling gains against Llewellyn's condition, in closed form, by frequency sweep and
// in closed loop with the emulated device; the passivity observer and controller.
#include "engine/haptics/haptics_coupling.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>

#include "engine/haptics/haptics_device.h"
#include "engine/haptics/haptics_render.h"

namespace zona {
namespace {

TEST(HapticsCoupling, ClosedFormMatchesFrequencySweep) {
  const DeviceImpedance d{0.045, 0.4};
  for (double k : {0.0, 100.0, 400.0, 1000.0})
    for (double b : {0.0, 0.05, 0.3}) {
      const CouplingGains g{k, b};
      // The sweep's last point is w T = pi exactly, where the bound is reached.
      EXPECT_NEAR(llewellyn_margin_sweep(g, d, 1e-3), llewellyn_margin(g, d, 1e-3), 1e-9)
          << k << " " << b;
    }
}

TEST(HapticsCoupling, AutoGainsSatisfyCriterionWithMarginAndDeviceLimits) {
  for (const char* name : {"touch", "falcon", "omega"}) {
    const DeviceInfo info = device_profile(name).value();
    for (double T : {1e-3, 5e-4, 2e-3}) {
      const CouplingGains g = auto_coupling_gains(info.impedance, T, info.max_stiffness);
      EXPECT_GT(g.stiffness, 0) << name;
      EXPECT_LE(g.stiffness, info.max_stiffness) << name;
      EXPECT_GE(g.damping, 0) << name;
      const double margin = llewellyn_margin_sweep(g, info.impedance, T);
      EXPECT_GE(margin, info.impedance.damping * (1 - 1 / 1.25) - 1e-12) << name << " " << T;
    }
  }
  // Touch at 1 kHz: budget 0.32 N*s/m, half to the spring -> 320 N/m, the rest 0.16 to b_c.
  const CouplingGains g = auto_coupling_gains({0.045, 0.4}, 1e-3, 400);
  EXPECT_NEAR(g.stiffness, 320, 1e-9);
  EXPECT_NEAR(g.damping, 0.16, 1e-12);
}

TEST(HapticsCoupling, OverridesAreCheckedAgainstCriterion) {
  const DeviceImpedance d{0.045, 0.4};
  const double good_k = 500, bad_k = 900, big_b = 0.5;
  EXPECT_TRUE(choose_coupling_gains(&good_k, nullptr, d, 1e-3, 1000).ok());
  EXPECT_FALSE(choose_coupling_gains(&bad_k, nullptr, d, 1e-3, 1000).ok());  // 0.45 > 0.4
  EXPECT_FALSE(choose_coupling_gains(nullptr, &big_b, d, 1e-3, 400).ok());
  EXPECT_FALSE(choose_coupling_gains(&good_k, nullptr, d, 1e-3, 400).ok());  // device limit
  const auto chosen = choose_coupling_gains(&good_k, nullptr, d, 1e-3, 1000);
  EXPECT_GE(llewellyn_margin(chosen.value(), d, 1e-3), 0);
}

struct LoopResult {
  double late_swing = 0;  // peak-to-peak device x over the last 0.3 s [m]
  double min_energy = 0;  // lowest observed energy [J]
  double final_energy = 0;
  int64_t pc_ticks = 0;
};

// The emulated hand pushes the device against a rigid anchor (the tool pinned at the origin by a
// huge environment stiffness): the hand feels only the coupling, Colgate's virtual wall.
LoopResult run_rigid_anchor(CouplingGains gains, bool passivity_control) {
  DeviceInfo info = device_profile("touch").value();
  EmulatedHandDef hand;
  hand.hand_mass = 0;
  hand.hand_stiffness = 50;
  hand.hand_damping = 0;
  hand.speed = 0.01;
  hand.max_travel = 0.002;
  auto device = make_emulated_device(info, hand);
  HapticRenderConfig c;
  c.period = 1e-3;
  c.coupling = gains;
  c.max_force = 1e3;  // no clamp: the linear loop is what the criterion speaks about
  c.max_stiffness = 1e9;
  c.fade_time = 1e-3;
  c.stall_timeout = 1e9;
  c.passivity_control = passivity_control;
  c.max_pc_damping = 5;
  c.scaling.workspace_scale = 1;
  c.scaling.force_scale = 1;
  // The criterion's worst case is a rigid tool that holds both ways; a needle contact only
  // pushes (and would release on every backswing), so the contact rule is off here.
  c.unilateral_contact = false;
  HapticRenderer r(c);
  HapticSample s;
  s.sequence = 1;
  s.stiffness = 1e9;
  r.push_sample(s, 0);
  LoopResult res;
  double lo = 1e300, hi = -1e300;
  const int ticks = 1500;
  for (int i = 0; i < ticks; ++i) {
    const double t = i * c.period;
    const DeviceState st = device->update(t);
    const HapticOutput out = r.tick(st.position, st.velocity, t);
    device->command(out.force, t);
    if (i >= ticks - 300) {
      lo = std::min(lo, st.position.x);
      hi = std::max(hi, st.position.x);
    }
  }
  res.late_swing = hi - lo;
  res.min_energy = r.passivity().min_energy();
  res.final_energy = r.passivity().energy();
  res.pc_ticks = r.passivity().active_ticks();
  return res;
}

TEST(HapticsCoupling, CriterionSeparatesStableFromUnstableGains) {
  const DeviceImpedance touch = device_profile("touch").value().impedance;
  const CouplingGains stable = auto_coupling_gains(touch, 1e-3, 400);
  const CouplingGains unstable{3 * 2 * touch.damping / 1e-3, 0};  // k_c T/2 = 3 b
  ASSERT_GT(llewellyn_margin(stable, touch, 1e-3), 0);
  ASSERT_LT(llewellyn_margin(unstable, touch, 1e-3), 0);
  const LoopResult a = run_rigid_anchor(stable, false);
  const LoopResult b = run_rigid_anchor(unstable, false);
  // Stable: settled at rest, the controller never gave energy back (observer >= 0).
  EXPECT_LT(a.late_swing, 1e-6);
  EXPECT_GE(a.min_energy, -1e-12);
  // Unstable: a growing oscillation that the observer sees as generated energy.
  EXPECT_GT(b.late_swing, 1e-3);
  EXPECT_LT(b.min_energy, -1e-4);
}

TEST(HapticsCoupling, PassivityControllerTamesUnstableGains) {
  const DeviceImpedance touch = device_profile("touch").value().impedance;
  const CouplingGains unstable{3 * 2 * touch.damping / 1e-3, 0};
  const LoopResult off = run_rigid_anchor(unstable, false);
  const LoopResult on = run_rigid_anchor(unstable, true);
  EXPECT_GT(on.pc_ticks, 0);
  EXPECT_LT(on.late_swing, 0.01 * off.late_swing);
  EXPECT_GT(on.min_energy, 0.01 * off.min_energy);  // both negative; far less generated
}

TEST(HapticsCoupling, ObserverCountsWorkPerAxis) {
  PassivityGuard g(1000);  // a damping limit that does not bind here
  // The hand pushes +x 1 mm against -2 N: 2 mJ into the controller.
  g.observe({-2, 0, 0}, {1e-3, 0, 0});
  EXPECT_NEAR(g.energy(), 2e-3, 1e-15);
  // The controller pushes the hand back along y: -1 mJ on that axis.
  g.observe({0, 1, 0}, {0, 1e-3, 0});
  EXPECT_NEAR(g.axis_energy().y, -1e-3, 1e-15);
  EXPECT_NEAR(g.energy(), 1e-3, 1e-15);
  // The controller damps only y, and dissipates the deficit in one period at this velocity.
  const Vec3d f = g.control({0, 0, 0}, {0.1, 0.1, 0}, 1e-3);
  EXPECT_EQ(f.x, 0.0);
  EXPECT_NEAR(f.y * 0.1 * 1e-3, -1e-3, 1e-12);  // = -E_y: the force's work over T
}

TEST(HapticsCoupling, ControllerReturnsAtMostTheStoredEnergy) {
  PassivityGuard g(1000);
  // The hand pressed 1 mm in against 0.1 N: 0.1 mJ stored on x.
  g.observe({-0.1, 0, 0}, {1e-3, 0, 0});
  ASSERT_NEAR(g.energy(), 1e-4, 1e-15);
  // A stale 2 N held while the hand yields at 0.1 m/s would return 0.2 mJ in one period: the
  // bound scales it so that even twice the predicted motion returns only what x holds (same
  // direction, never reversed).
  const Vec3d f = g.control({-2, 0, 0}, {-0.1, 0, 0}, 1e-3);
  EXPECT_NEAR(f.x * -0.1 * 1e-3, 0.5e-4, 1e-15);
  EXPECT_LT(f.x, 0.0);
  EXPECT_NEAR(g.clipped(), 2e-4 - 0.5e-4, 1e-15);
  // Held over a period in which the device moved twice as far as predicted, the observer ends
  // at zero, not below.
  g.observe(f, {-2e-4, 0, 0});
  EXPECT_NEAR(g.energy(), 0, 1e-15);
  // A force resisting the motion is never touched; nor is one on an axis with energy to spare.
  PassivityGuard h(1000);
  h.observe({-1, 0, 0}, {1e-3, 0, 0});
  EXPECT_EQ(h.control({-1, 0, 0}, {0.1, 0, 0}, 1e-3).x, -1.0);
  EXPECT_EQ(h.control({-0.5, 0, 0}, {-0.1, 0, 0}, 1e-3).x, -0.5);  // 2 x 50 uJ of the 1 mJ
  EXPECT_EQ(h.active_ticks(), 0);
}

}  // namespace
}  // namespace zona
