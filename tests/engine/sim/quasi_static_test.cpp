// The quasi-static check (engine/sim/quasi_static.h): what it measures, from which force it
// judges, what it remembers, and that only an enforcing experiment blocks a puncture.
#include "engine/sim/quasi_static.h"

#include <gtest/gtest.h>

#include <cmath>

namespace zona {
namespace {

QuasiStaticLimits limits() {
  QuasiStaticLimits lim;
  lim.enforce = 1;
  lim.has_holder = 1;
  lim.max_imbalance = 0.2;
  lim.force_floor = 1e-6;
  lim.energy_floor = 1e-20;
  return lim;
}

TEST(QuasiStatic, AnEquilibriumPassesAndAnUnheldLoadFails) {
  const QuasiStaticLimits lim = limits();
  QuasiStaticState q;
  // The holder carries 95 % of 4 uN: imbalance 0.05.
  EXPECT_FALSE(quasi_static_step(lim, q, true, 4e-6, -3.8e-6, 0, 1e-12, 10, 0.1, 10e-6));
  EXPECT_NEAR(q.imbalance, 0.05, 1e-12);
  EXPECT_EQ(q.failed_steps, 0);
  // The holder carries nothing of 5 uN (the scaled mass's inertia does): imbalance 1.
  EXPECT_TRUE(quasi_static_step(lim, q, true, 5e-6, 0.0, 0, 1e-12, 11, 0.11, 11e-6));
  EXPECT_NEAR(q.imbalance, 1.0, 1e-12);
  EXPECT_EQ(q.failed_steps, 1);
  EXPECT_EQ(q.first_failed_step, 11);
  EXPECT_DOUBLE_EQ(q.first_failed_deformation, 11e-6);
  EXPECT_DOUBLE_EQ(q.first_failed_force, 5e-6);
  // A holder pulling the cell the needle's way (suction transient) counts the same.
  EXPECT_TRUE(quasi_static_step(lim, q, true, 2e-6, 1e-6, 0, 1e-12, 12, 0.12, 12e-6));
  EXPECT_NEAR(q.imbalance, 1.5, 1e-12);
  // The worst is kept with where it was; the first failure stays the first.
  EXPECT_NEAR(q.worst_imbalance, 1.5, 1e-12);
  EXPECT_DOUBLE_EQ(q.worst_imbalance_deformation, 12e-6);
  EXPECT_EQ(q.first_failed_step, 11);
  EXPECT_EQ(q.failed_steps, 2);
}

TEST(QuasiStatic, BelowTheFloorItIsShownButNotJudged) {
  const QuasiStaticLimits lim = limits();
  QuasiStaticState q;
  // First touch: 0.1 uN of needle force, the holder still swinging by 0.5 uN. Shown over the
  // floor (0.6 / 1), not judged.
  EXPECT_FALSE(quasi_static_step(lim, q, true, 0.1e-6, 0.5e-6, 0, 1e-14, 1, 0.01, 0.5e-6));
  EXPECT_NEAR(q.imbalance, 0.6, 1e-12);
  EXPECT_EQ(q.failed_steps, 0);
  EXPECT_EQ(q.worst_imbalance, 0.0);
  // After puncture (not judged) nothing is measured.
  EXPECT_FALSE(quasi_static_step(lim, q, false, 5e-6, 0.0, 0, 1e-12, 2, 0.02, 1e-6));
  EXPECT_EQ(q.imbalance, 0.0);
  EXPECT_EQ(q.failed_steps, 0);
}

TEST(QuasiStatic, ADynamicExperimentIsMeasuredButNeverBlocked) {
  QuasiStaticLimits lim = limits();
  lim.enforce = 0;
  QuasiStaticState q;
  EXPECT_FALSE(quasi_static_step(lim, q, true, 5e-6, 0.0, 0, 1e-12, 3, 0.03, 3e-6));
  EXPECT_EQ(q.failed_steps, 1);  // it says it was not quasi-static
  EXPECT_NEAR(q.worst_imbalance, 1.0, 1e-12);
}

TEST(QuasiStatic, KineticShareIsRecordedAndJudgedOnlyWithALimit) {
  QuasiStaticLimits lim = limits();
  lim.has_holder = 0;  // cell held by fixed vertices: no holder force to compare
  QuasiStaticState q;
  EXPECT_FALSE(quasi_static_step(lim, q, true, 2e-6, 0.0, 3e-12, 1e-12, 4, 0.04, 4e-6));
  EXPECT_NEAR(q.kinetic_share, 0.75, 1e-12);
  EXPECT_EQ(q.imbalance, 0.0);
  EXPECT_EQ(q.failed_steps, 0);
  EXPECT_FALSE(quasi_static_measured(lim));
  lim.max_kinetic_share = 0.5;
  EXPECT_TRUE(quasi_static_measured(lim));
  EXPECT_TRUE(quasi_static_step(lim, q, true, 2e-6, 0.0, 3e-12, 1e-12, 5, 0.05, 5e-6));
  EXPECT_EQ(q.failed_steps, 1);
  // A non-finite measure fails (it is never a puncture).
  lim.has_holder = 1;
  EXPECT_TRUE(quasi_static_step(lim, q, true, 2e-6, NAN, 0, 1e-12, 6, 0.06, 6e-6));
}

}  // namespace
}  // namespace zona
