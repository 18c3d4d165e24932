// Tests for engine/scene_mesh: the needle's entry point and the generator spec of a scene.
#include "engine/scene/scene_mesh.h"

#include <gtest/gtest.h>

namespace zona {
namespace {

TEST(SceneMesh, EntryPointOfAimedNeedleOnBall) {
  Scene scene;
  scene.mesh.generate.diameter = 56e-6;
  scene.needle.direction = {1, 0, 0};
  const Vec3d p = needle_entry_point(scene);
  EXPECT_NEAR(p.x, -28e-6, 1e-18);
  EXPECT_NEAR(p.y, 0, 1e-18);
  EXPECT_NEAR(p.z, 0, 1e-18);
}

TEST(SceneMesh, EntryPointOffAxisOnEllipsoid) {
  Scene scene;
  scene.mesh.generate.diameter = 2.0;  // semi-axes (2, 1, 1)
  scene.mesh.generate.radii_scale = {2, 1, 1};
  scene.needle.direction = {0, 0, -1};
  scene.needle.start = Vec3d{1.0, 0.0, 5.0};
  const Vec3d p = needle_entry_point(scene);
  // On x^2/4 + z^2 = 1 at x = 1: z = sqrt(3)/2, on the side the needle comes from.
  EXPECT_NEAR(p.x, 1.0, 1e-12);
  EXPECT_NEAR(p.z, std::sqrt(3.0) / 2.0, 1e-12);
  EXPECT_NEAR(p.x * p.x / 4 + p.y * p.y + p.z * p.z, 1.0, 1e-12);
}

TEST(SceneMesh, SpecCopiesGeneratorFields) {
  Scene scene;
  scene.mesh.generate.diameter = 56e-6;
  scene.mesh.generate.radii_scale = {1, 1.2, 1};
  scene.mesh.generate.edge_length = 5e-6;
  scene.mesh.generate.refine_edge_length = 1e-6;
  scene.mesh.generate.refine_at = {0, 0, 28e-6};
  const CellMeshSpec spec = cell_mesh_spec(scene);
  EXPECT_EQ(spec.radii_scale.y, 1.2);
  ASSERT_TRUE(spec.refine_at.has_value());
  EXPECT_EQ(spec.refine_at->z, 28e-6);
  scene.mesh.generate.refine_edge_length = 0;
  EXPECT_FALSE(cell_mesh_spec(scene).refine_at.has_value());
}

}  // namespace
}  // namespace zona
