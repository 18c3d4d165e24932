// Haptic rendering: interpolation against analytic signals, scaling, coupling solve, safety.
#include "engine/haptics/haptics_render.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <limits>

namespace zona {
namespace {

TEST(HapticsRender, FirstOrderHoldIsExactForLinearSignalWithinOneInterval) {
  // f(t) = (0.2 + 3 t, -1 t, 0): the extrapolation of a line from two samples is the line.
  auto f = [](double t) { return Vec3d{0.2 + 3 * t, -t, 0}; };
  ForceInterpolator in;
  in.mode = HapticInterpolation::kFirstOrderHold;
  const double dt = 1.0 / 30;
  in.push(f(0), 0, {1, 0, 0}, {0, 0, 0}, 0);
  in.push(f(dt), 0, {1, 0, 0}, {0, 0, 0}, dt);
  for (double t = dt; t <= 2 * dt + 1e-12; t += 1e-3) {
    const Vec3d e = in.first_order_hold(t) - f(t);
    EXPECT_NEAR(norm(e), 0, 1e-12) << t;
  }
  // Beyond one interval the slope stops: a stalled simulation cannot ramp the force.
  EXPECT_NEAR(norm(in.first_order_hold(10.0) - f(2 * dt)), 0, 1e-12);
  // A quadratic: the error is the curvature term, (1/2) f'' tau (tau + dt) at lag tau.
  ForceInterpolator q;
  q.mode = HapticInterpolation::kFirstOrderHold;
  q.push({0, 0, 0}, 0, {1, 0, 0}, {0, 0, 0}, 0);
  q.push({dt * dt, 0, 0}, 0, {1, 0, 0}, {0, 0, 0}, dt);  // f = t^2
  const double tau = 0.5 * dt;
  EXPECT_NEAR((dt + tau) * (dt + tau) - q.first_order_hold(dt + tau).x, tau * (tau + dt),
              1e-15);
}

TEST(HapticsRender, StiffnessModelIsExactForUnilateralSpringAlongAxis) {
  // Environment: a contact spring along n, f(x) = -k max(n.x, 0) n, sampled at x1; the model
  // reproduces it on both sides of the sample, and releases (zero axial force, never a pull)
  // where the spring would extend past its rest point.
  const double k = 250;
  const Vec3d n = Vec3d{1, 2, 2} / 3.0;
  auto f = [&](Vec3d x) { return (-k * std::max(dot(n, x), 0.0)) * n; };
  ForceInterpolator in;
  const Vec3d x1{0.01, 0.002, -0.001};  // n.x1 = 4 mm into the spring
  in.push(f(x1), k, {1, 2, 2}, x1, 0.0);  // the axis is normalised on push
  int released = 0;
  for (double s = -0.01; s <= 0.01; s += 0.0025) {
    const Vec3d x = x1 + Vec3d{s, -0.5 * s, 2 * s};  // n.dx = 4 s / 3
    EXPECT_NEAR(norm(in.stiffness_model(x) - f(x)), 0, 1e-12) << s;
    released += dot(n, x) < 0;
  }
  EXPECT_GT(released, 0);  // the sweep crossed the release point
  // A lateral force component is kept as it is; only the axial part is a spring.
  in.push(f(x1) + Vec3d{0, 0.5, -1}, k, {1, 2, 2}, x1, 0.1);
  const Vec3d behind = x1 - 0.01 * n;
  const Vec3d g = in.stiffness_model(behind);
  EXPECT_NEAR(dot(g, n), 0, 1e-12);
  EXPECT_NEAR(norm(g - dot(g, n) * n - (Vec3d{0, 0.5, -1} - dot(Vec3d{0, 0.5, -1}, n) * n)), 0,
              1e-12);
}

TEST(HapticsRender, ScalingMapsHandToCellAndBack) {
  HapticScaling sc;
  sc.workspace_scale = 5e-3;   // 1 cm -> 50 um
  sc.force_scale = 3e5;        // 1 uN -> 0.3 N
  sc.device_origin = {0.1, 0, 0};
  sc.cell_origin = {-30e-6, 0, 0};
  const Vec3d d{0.11, 0.002, 0};
  const Vec3d c = sc.to_cell(d);
  EXPECT_NEAR(c.x, -30e-6 + 50e-6, 1e-15);
  EXPECT_NEAR(norm(sc.to_device(c) - d), 0, 1e-12);
  EXPECT_NEAR(sc.force_to_device({7.5e-6, 0, 0}).x, 2.25, 1e-12);
  // 7.5 uN over 45 um in the cell -> 2.25 N over 9 mm at the hand = 250 N/m.
  EXPECT_NEAR(sc.stiffness_to_device(7.5e-6 / 45e-6), 2.25 / 9e-3, 1e-9);
}

HapticRenderConfig test_config() {
  HapticRenderConfig c;
  c.period = 1e-3;
  c.coupling = {300, 0.1};
  c.max_force = 100;
  c.max_stiffness = 1e9;
  c.stall_timeout = 0.05;
  c.fade_time = 0.01;
  c.passivity_control = false;
  return c;
}

TEST(HapticsRender, StaticContactRendersSeriesSpring) {
  // Device held 10 mm into a linear environment of stiffness K (device units): the massless
  // tool settles where the coupling spring balances the environment, so the hand feels the
  // series stiffness k_c K / (k_c + K).
  HapticRenderConfig c = test_config();
  const double K = 200;
  HapticSample s;
  s.sequence = 1;
  s.force = {0, 0, 0};
  s.stiffness = K;
  // Identity scaling: the sample is already in device units.
  HapticRenderConfig ci = c;
  ci.scaling.workspace_scale = 1;
  ci.scaling.force_scale = 1;
  ci.stall_timeout = 1e9;  // one sample for the whole test
  HapticRenderer ri(ci);
  ri.push_sample(s, 0.0);
  HapticOutput out;
  for (int i = 0; i < 200; ++i) out = ri.tick({0.01, 0, 0}, {0, 0, 0}, i * 1e-3);
  const double series = c.coupling.stiffness * K / (c.coupling.stiffness + K);
  EXPECT_NEAR(out.force.x, -series * 0.01, 1e-9);
  EXPECT_NEAR(out.force.y, 0, 1e-15);
  // The tool sits between the sample point and the device.
  EXPECT_NEAR(out.tool_device.x, 0.01 * c.coupling.stiffness / (c.coupling.stiffness + K), 1e-9);
  EXPECT_NEAR(out.tool_cell.x, out.tool_device.x, 1e-15);
}

TEST(HapticsRender, ClampKeepsDirectionAndCounts) {
  HapticSafety s;
  Vec3d f{};
  for (int i = 0; i < 20; ++i) f = s.apply({6, 8, 0}, 0.0, 1e-3, 0.05, 0.005, 3.3);
  EXPECT_NEAR(norm(f), 3.3, 1e-12);
  EXPECT_NEAR(f.x / f.y, 0.75, 1e-12);
  EXPECT_GT(s.clamped_ticks(), 0);
  const int64_t clamped = s.clamped_ticks();
  f = s.apply({1, 0, 0}, 0.0, 1e-3, 0.05, 0.005, 3.3);
  EXPECT_EQ(s.clamped_ticks(), clamped);
  EXPECT_EQ(f.x, 1.0);
}

TEST(HapticsRender, NanGuardOutputsLastGoodForceOrZero) {
  const double nan = std::numeric_limits<double>::quiet_NaN();
  HapticSafety s;
  // Before any good force: zero.
  Vec3d f = s.apply({nan, 0, 0}, 0.0, 1e-3, 0.05, 1e-3, 3.3);
  EXPECT_EQ(norm(f), 0.0);
  EXPECT_EQ(s.nan_ticks(), 1);
  for (int i = 0; i < 5; ++i) f = s.apply({1, 2, 0}, 0.0, 1e-3, 0.05, 1e-3, 3.3);
  const Vec3d good = f;
  f = s.apply({0, std::numeric_limits<double>::infinity(), 0}, 0.0, 1e-3, 0.05, 1e-3, 3.3);
  EXPECT_EQ(f.x, good.x);
  EXPECT_EQ(f.y, good.y);
  EXPECT_EQ(s.nan_ticks(), 2);
}

TEST(HapticsRender, StallFadesOutAndRecovers) {
  HapticSafety s;
  const double T = 1e-3, fade = 0.02;
  Vec3d f{};
  for (int i = 0; i < 30; ++i) f = s.apply({2, 0, 0}, 0.001, T, 0.05, fade, 3.3);
  EXPECT_NEAR(f.x, 2.0, 1e-12);  // faded in after fade / T = 20 ticks
  // Stalled: the gain falls by T / fade per tick, never a step.
  double prev = f.x;
  for (int i = 0; i < 10; ++i) {
    f = s.apply({2, 0, 0}, 0.08, T, 0.05, fade, 3.3);
    EXPECT_NEAR(prev - f.x, 2.0 * T / fade, 1e-12);
    prev = f.x;
  }
  for (int i = 0; i < 20; ++i) f = s.apply({2, 0, 0}, 0.08, T, 0.05, fade, 3.3);
  EXPECT_EQ(f.x, 0.0);
  EXPECT_GT(s.stalled_ticks(), 0);
  // Recovery: back to full force.
  for (int i = 0; i < 25; ++i) f = s.apply({2, 0, 0}, 0.001, T, 0.05, fade, 3.3);
  EXPECT_NEAR(f.x, 2.0, 1e-12);
}

TEST(HapticsRender, EmergencyStopZeroesForce) {
  HapticSafety s;
  Vec3d f{};
  for (int i = 0; i < 30; ++i) f = s.apply({1, 0, 0}, 0.0, 1e-3, 0.05, 1e-3, 3.3);
  EXPECT_EQ(f.x, 1.0);
  s.emergency_stop();
  f = s.apply({1, 0, 0}, 0.0, 1e-3, 0.05, 1e-3, 3.3);
  EXPECT_EQ(norm(f), 0.0);
  s.release();
  f = s.apply({1, 0, 0}, 0.0, 1e-3, 0.05, 1e-3, 3.3);
  EXPECT_EQ(f.x, 1.0);  // fade_time = T: back in one tick
}

TEST(HapticsRender, RendererIgnoresNanSamplesAndPositions) {
  HapticRenderConfig c = test_config();
  HapticRenderer r(c);
  HapticSample good;
  good.sequence = 1;
  good.force = {-1e-6, 0, 0};
  r.push_sample(good, 0.0);
  HapticSample bad = good;
  bad.sequence = 2;
  bad.force.x = std::numeric_limits<double>::quiet_NaN();
  r.push_sample(bad, 0.001);
  EXPECT_EQ(r.interpolator().count, 1);
  HapticOutput out;
  for (int i = 0; i < 20; ++i) out = r.tick({0, 0, 0}, {0, 0, 0}, i * 1e-3);
  out = r.tick({std::numeric_limits<double>::quiet_NaN(), 0, 0}, {0, 0, 0}, 0.021);
  EXPECT_TRUE(std::isfinite(out.force.x) && std::isfinite(out.force.y));
  EXPECT_TRUE(std::isfinite(out.tool_cell.x));
}

TEST(HapticsRender, CouplingReleasesWhenToolBacksOffContact) {
  // The sample: 1 N of resistance with 200 N/m at x1 = 0 (device units). A device held 10 mm
  // behind feels nothing: the linear extrapolation would pull it forward with 1 N.
  HapticRenderConfig c = test_config();
  c.scaling.workspace_scale = 1;
  c.scaling.force_scale = 1;
  c.stall_timeout = 1e9;
  HapticRenderer r(c);
  HapticSample s;
  s.sequence = 1;
  s.force = {-1, 0, 0};
  s.stiffness = 200;
  r.push_sample(s, 0.0);
  HapticOutput out;
  for (int i = 0; i < 100; ++i) out = r.tick({-0.01, 0, 0}, {0, 0, 0}, i * 1e-3);
  EXPECT_NEAR(out.force.x, 0, 1e-12);
  EXPECT_NEAR(out.tool_device.x, -0.01, 1e-12);  // the coupling is slack
  // Pressed 10 mm in, the contact is a series spring from the sampled force on.
  for (int i = 100; i < 300; ++i) out = r.tick({0.01, 0, 0}, {0, 0, 0}, i * 1e-3);
  const double kc = c.coupling.stiffness, K = 200;
  // Balance: kc e = 1 + K (0.01 - e)  ->  force = -(kc (1 + K 0.01) / (kc + K)).
  EXPECT_NEAR(out.force.x, -kc * (1 + K * 0.01) / (kc + K), 1e-9);
}

}  // namespace
}  // namespace zona
