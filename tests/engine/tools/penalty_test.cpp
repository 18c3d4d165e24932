// The penalty contact law as pure functions: the normal energy's gradient and Hessian (with the
// tool's curvature) and the friction potential's (sticking and sliding) agree with central
// differences; the explicit step's force is minus their gradients; evaluating never moves an
// anchor, and committing reproduces the stored-anchor form step by step.
#include "engine/tools/penalty.h"

#include <algorithm>

#include <gtest/gtest.h>

namespace zona {
namespace {

TEST(Penalty, NormalEnergyGradientAndHessianMatchCentralDifferences) {
  const Vec3d tip{0, 0, 0}, d{1, 0, 0};
  const double r = 1.0, k = 3.0;
  const Vec3d x{-0.3, 0.4, 0.2};  // inside the hemisphere
  Mat3d hess_phi;
  const ToolSdf sdf = needle_sdf(tip, d, r, false, x, &hess_phi);
  ASSERT_LT(sdf.distance, 0);
  const Vec3d g = penalty_gradient(k, sdf);
  const Mat3d hm = penalty_hessian(k, sdf, hess_phi);
  const double h = 1e-6;
  for (int i = 0; i < 3; ++i) {
    Vec3d e{0, 0, 0};
    e[i] = h;
    const ToolSdf p = needle_sdf(tip, d, r, false, x + e), m = needle_sdf(tip, d, r, false, x - e);
    EXPECT_NEAR(g[i], (penalty_energy(k, p.distance) - penalty_energy(k, m.distance)) / (2 * h), 1e-7);
    const Vec3d dg = (1.0 / (2 * h)) * (penalty_gradient(k, p) - penalty_gradient(k, m));
    for (int rr = 0; rr < 3; ++rr) EXPECT_NEAR(hm.m[rr][i], dg[rr], 1e-6);
  }
  // Outside: nothing.
  const ToolSdf out = needle_sdf(tip, d, r, false, Vec3d{2, 0, 0});
  EXPECT_EQ(penalty_energy(k, out.distance), 0);
  EXPECT_EQ(norm(penalty_gradient(k, out)), 0);
}

TEST(Penalty, FrictionPotentialMatchesCentralDifferencesStickingAndSliding) {
  const Vec3d n = Vec3d{0.2, 1, -0.3} / norm(Vec3d{0.2, 1, -0.3});
  const double k = 4.0, cap = 1.0;
  // |P d| = 0.1 (k s = 0.4 < cap: sticking) and 0.6 (2.4 > cap: sliding).
  for (double len : {0.1, 0.6}) {
    const Vec3d t = any_perpendicular(n);
    const Vec3d d = len * t + 0.37 * n;  // a normal part the potential ignores
    const Vec3d g = friction_gradient(k, cap, n, d);
    const Mat3d hm = friction_hessian(k, cap, n, d);
    const double h = 1e-6;
    for (int i = 0; i < 3; ++i) {
      Vec3d e{0, 0, 0};
      e[i] = h;
      EXPECT_NEAR(g[i], (friction_energy(k, cap, n, d + e) - friction_energy(k, cap, n, d - e)) / (2 * h), 1e-7);
      const Vec3d dg = (1.0 / (2 * h)) * (friction_gradient(k, cap, n, d + e) - friction_gradient(k, cap, n, d - e));
      for (int r = 0; r < 3; ++r) EXPECT_NEAR(hm.m[r][i], dg[r], 1e-6) << len;
    }
    EXPECT_NEAR(norm(g), len * k > cap ? cap : k * len, 1e-12);
  }
  // Continuous at the cap.
  const Vec3d t = any_perpendicular(n);
  EXPECT_NEAR(friction_energy(k, cap, n, (cap / k) * t * (1 - 1e-12)),
              friction_energy(k, cap, n, (cap / k) * t * (1 + 1e-12)), 1e-10);
}

TEST(Penalty, TheExplicitForceIsMinusTheGradientsAndEvaluatingMovesNoAnchor) {
  ToolSdf sdf;
  sdf.distance = -0.2;
  sdf.normal = Vec3d{0, 0, 1};
  const double kappa = 10, mu = 0.3, area = 0.5, k = kappa * area, cap = mu * k * 0.2;
  const Vec3d anchor{0, 0, 0};
  // Without a stick length (the spring as stiff as the contact) and with one wider than the
  // contact's own zone mu |phi| = 0.06 (the spring softened to cap / 0.3).
  for (const double stick : {0.0, 0.3}) {
    const double kt = friction_stiffness(k, cap, stick);
    EXPECT_DOUBLE_EQ(kt, stick > 0 ? cap / stick : k);
    for (const Vec3d rel : {Vec3d{0.01, 0, 0}, Vec3d{0.1, 0.05, 0}, Vec3d{0.5, 0.2, 0.1}}) {
      const PenaltyContact c = penalty_contact(sdf, kappa, mu, stick, area, rel, anchor);
      const Vec3d expect = -1.0 * (penalty_gradient(k, sdf) +
                                   friction_gradient(kt, cap, sdf.normal, rel - anchor));
      EXPECT_NEAR(norm(c.force - expect), 0, 1e-15);
      // Sticking keeps the anchor; sliding moves it so that the spring sits at the cap.
      const Vec3d d = c.anchor - rel;
      const double spring = kt * norm(d - dot(d, sdf.normal) * sdf.normal);
      const double s = norm(rel - anchor - dot(rel - anchor, sdf.normal) * sdf.normal);
      if (s * kt < cap)
        EXPECT_EQ(norm(c.anchor - anchor), 0) << stick;
      else
        EXPECT_NEAR(spring, cap, 1e-12) << stick;
    }
  }
}

// The stick zone (the tangential offset at which the spring reaches the Coulomb cap) is the
// contact's own mu |phi| where that is wider than the stick length, else the stick length; the
// spring is never stiffer than the contact.
TEST(Penalty, TheStickZoneIsAtLeastTheStickLength) {
  const double k = 8.0, mu = 0.25;
  for (const double depth : {1e-3, 0.4}) {
    const double cap = mu * k * depth;
    for (const double stick : {0.0, 0.01, 0.05}) {
      const double kt = friction_stiffness(k, cap, stick);
      EXPECT_LE(kt, k);
      EXPECT_NEAR(cap / kt, std::max(mu * depth, stick), 1e-15) << depth << " " << stick;
      // Just inside the zone the point sticks (the force grows with the offset), just outside
      // it slides at the cap.
      const Vec3d n{0, 0, 1}, t{1, 0, 0};
      bool slid = true;
      const Vec3d in = friction_spring(kt, cap, n, 0.99 * (cap / kt) * t, &slid);
      EXPECT_FALSE(slid);
      EXPECT_NEAR(norm(in), 0.99 * cap, 1e-12);
      friction_spring(kt, cap, n, 1.01 * (cap / kt) * t, &slid);
      EXPECT_TRUE(slid);
    }
  }
  // No normal force, no friction.
  EXPECT_EQ(friction_stiffness(k, 0.0, 0.01), 0.0);
}

// A point dragged along the surface over several steps: evaluate, then commit, gives what the
// stored-anchor form gives, step by step (the explicit step's fused commit is the same thing).
TEST(Penalty, CommittingAfterEachStepReproducesTheStoredAnchorForm) {
  ToolSdf sdf;
  sdf.distance = -0.1;
  sdf.normal = Vec3d{0, 1, 0};
  StickAnchor stored, committed;
  const double stick = 0.05;  // wider than the contact's own zone (0.02)
  for (int64_t step = 0; step < 12; ++step) {
    const Vec3d rel{0.03 * static_cast<double>(step), 0, 0.01 * static_cast<double>(step % 3)};
    const Vec3d f_stored = penalty_contact_force(sdf, 10, 0.2, stick, 1, rel, step, &stored);
    const PenaltyContact c =
        penalty_contact(sdf, 10, 0.2, stick, 1, rel, stick_anchor_in_step(committed, step, rel));
    const StickAnchor before = committed;
    // Evaluating twice at trial states changes nothing.
    penalty_contact(sdf, 10, 0.2, stick, 1, rel + Vec3d{1, 0, 0}, stick_anchor_in_step(committed, step, rel));
    EXPECT_EQ(before.mark, committed.mark);
    committed = stick_anchor_commit(c.anchor, step);
    EXPECT_EQ(norm(f_stored - c.force), 0) << step;
    EXPECT_EQ(norm(stored.at - committed.at), 0) << step;
  }
  // A point that left the tool for a step starts afresh where it touches again.
  EXPECT_EQ(norm(stick_anchor_in_step(committed, 20, Vec3d{5, 0, 0}) - Vec3d{5, 0, 0}), 0);
}

}  // namespace
}  // namespace zona
