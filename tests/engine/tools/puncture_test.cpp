// Tests for engine/puncture: criteria, the release ramp, the loads after puncture, the strain
// measure at the tip.
#include "engine/tools/puncture.h"

#include <gtest/gtest.h>

#include <cmath>

#include "engine/mesh/mesh_generate.h"

namespace zona {
namespace {

TEST(Puncture, ReleaseFactorRampsOverDropTime) {
  PunctureDef def;
  def.force_drop = 0.9;
  def.drop_time = 2e-3;
  EXPECT_DOUBLE_EQ(puncture_release_factor(def, 0.0), 1.0);
  EXPECT_NEAR(puncture_release_factor(def, 1e-3), 0.55, 1e-15);
  EXPECT_NEAR(puncture_release_factor(def, 2e-3), 0.1, 1e-15);
  EXPECT_NEAR(puncture_release_factor(def, 1.0), 0.1, 1e-15);
  def.drop_time = 0;  // immediate
  EXPECT_NEAR(puncture_release_factor(def, 0.0), 0.1, 1e-15);
}

TEST(Puncture, CriteriaCompareTheirOwnMeasure) {
  PunctureDef def;
  def.criterion = PunctureCriterion::kForce;
  def.threshold = 7.5e-6;
  Puncture p(def, Vec3d{1, 0, 0}, 4);
  EXPECT_FALSE(p.criterion_met({7.4e-6, 10.0, 10.0}));
  EXPECT_TRUE(p.criterion_met({7.5e-6, 0.0, 0.0}));
  def.criterion = PunctureCriterion::kStrain;
  def.threshold = 0.5;
  Puncture s(def, Vec3d{1, 0, 0}, 4);
  EXPECT_FALSE(s.criterion_met({1.0, 0.49, 0.0}));
  EXPECT_TRUE(s.criterion_met({0.0, 0.51, 0.0}));
  def.criterion = PunctureCriterion::kEnergy;
  def.threshold = 1e-12;
  Puncture e(def, Vec3d{1, 0, 0}, 4);
  EXPECT_TRUE(e.criterion_met({0.0, 0.0, 2e-12}));
  def.criterion = PunctureCriterion::kNone;
  Puncture none(def, Vec3d{1, 0, 0}, 4);
  EXPECT_FALSE(none.criterion_met({1.0, 1.0, 1.0}));
}

TEST(Puncture, TriggerReleasesTheTipForceAndAddsShaftDrag) {
  PunctureDef def;
  def.criterion = PunctureCriterion::kForce;
  def.threshold = 1e-6;
  def.force_drop = 0.8;
  def.drop_time = 1e-3;
  def.shaft_friction = 0.01;  // N/m
  const Vec3d d{1, 0, 0};
  Puncture p(def, d, 4);
  Contact a, b;
  a.vertex = 2;
  a.static_reaction = Vec3d{0.6e-6, 0.1e-6, 0};
  b.vertex = 5;
  b.static_reaction = Vec3d{0.4e-6, -0.1e-6, 0};
  const Contact contacts[2] = {a, b};
  PunctureRecord r;
  r.time = 0.1;
  r.needle_travel = 40e-6;
  r.deformation = 37e-6;
  r.force = 1e-6;
  p.trigger(r, contacts);
  ASSERT_TRUE(p.punctured());
  EXPECT_EQ(p.record().deformation, 37e-6);
  EXPECT_FALSE(p.criterion_met({1.0, 1.0, 1.0}));  // never twice
  ASSERT_EQ(p.released_vertices().size(), 2u);
  // At puncture the full force, then down to 20 % plus drag over 10 um of inserted shaft.
  std::vector<Vec3d> ext(8, Vec3d{0, 0, 0});
  EXPECT_NEAR(p.apply_loads(0.1, 40e-6, ext), 1e-6, 1e-18);
  EXPECT_NEAR(ext[2].x, 0.6e-6, 1e-18);
  std::fill(ext.begin(), ext.end(), Vec3d{0, 0, 0});
  const double f = p.apply_loads(0.2, 50e-6, ext);
  EXPECT_NEAR(f, 0.2e-6 + 0.01 * 10e-6, 1e-18);
  // The body gets the same force the needle feels, spread over the released vertices.
  const Vec3d body = ext[2] + ext[5];
  EXPECT_NEAR(body.x, f, 1e-18);
  EXPECT_NEAR(body.y, 0.0, 1e-18);
  EXPECT_NEAR(p.body_force(0.2, 50e-6).x, f, 1e-18);
}

TEST(Puncture, PrincipalStrainOfAStretchedMesh) {
  const Mesh box = generate_box_mesh(Vec3d{0, 0, 0}, Vec3d{1, 1, 1}, 2, 2, 2);
  ModelDesc desc;
  Result<Model> model = build_model(box, desc);
  ASSERT_TRUE(model.ok());
  // Uniform stretch 1.2 along y: Green strain (1.2^2 - 1) / 2 = 0.22 everywhere.
  std::vector<Vec3d> u(box.vertex_count());
  for (size_t v = 0; v < box.vertex_count(); ++v) u[v] = Vec3d{0, 0.2 * box.rest_positions[v].y, 0};
  const int32_t around[2] = {0, 13};
  EXPECT_NEAR(max_principal_strain_around(*model, u, around, {}), 0.22, 1e-12);
  // Counting no element gives 0.
  const std::vector<uint8_t> none(model->tet_count(), 0);
  EXPECT_EQ(max_principal_strain_around(*model, u, around, none), 0.0);
}

}  // namespace
}  // namespace zona
