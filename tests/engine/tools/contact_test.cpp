// Tests for engine/tools/contact: surface adjacency, ray-triangle intersection and Ladjal et al.'s
// local search on the rest and the deformed surface.
#include "engine/tools/contact.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <random>

#include "engine/sim/integrator.h"
#include "engine/mesh/mesh_generate.h"
#include "engine/fem/state.h"

namespace zona {
namespace {

void expect_vec(Vec3d a, Vec3d b, double tol) {
  EXPECT_NEAR(a.x, b.x, tol);
  EXPECT_NEAR(a.y, b.y, tol);
  EXPECT_NEAR(a.z, b.z, tol);
}

TEST(Contact, BoxSurfaceIsClosedWithSymmetricAdjacency) {
  const Mesh box = generate_box_mesh(Vec3d{0, 0, 0}, Vec3d{2, 3, 4}, 2, 3, 4);
  Result<ContactSurface> r = build_contact_surface(box);
  ASSERT_TRUE(r.ok()) << r.error().message;
  const ContactSurface& s = *r;
  // 2 triangles per boundary square.
  EXPECT_EQ(s.triangles.size(), 2u * 2u * (2 * 3 + 3 * 4 + 2 * 4));
  EXPECT_NEAR(s.area, 2.0 * (2 * 3 + 3 * 4 + 2 * 4), 1e-12);
  for (size_t t = 0; t < s.triangles.size(); ++t)
    for (int e = 0; e < 3; ++e) {
      const int32_t n = s.triangle_neighbors[t][e];
      ASSERT_GE(n, 0) << "open edge on a closed surface";
      // The neighbour shares the edge's two vertices and points back.
      const int32_t a = s.triangles[t][e], b = s.triangles[t][(e + 1) % 3];
      int back = -1;
      for (int f = 0; f < 3; ++f)
        if (s.triangles[static_cast<size_t>(n)][f] == b &&
            s.triangles[static_cast<size_t>(n)][(f + 1) % 3] == a)
          back = f;
      ASSERT_GE(back, 0);
      EXPECT_EQ(s.triangle_neighbors[static_cast<size_t>(n)][back], static_cast<int32_t>(t));
    }
  double area = 0;
  for (double a : s.vertex_area) area += a;
  EXPECT_NEAR(area, s.area, 1e-12);
  for (int32_t v : s.vertices) EXPECT_GE(s.surface_index[static_cast<size_t>(v)], 0);
}

TEST(Contact, RayTriangleKnownAnswer) {
  double t = 0, b1 = 0, b2 = 0;
  const Vec3d a{0, 0, 0}, b{1, 0, 0}, c{0, 1, 0};
  ASSERT_TRUE(ray_triangle(Vec3d{0.25, 0.5, 2}, Vec3d{0, 0, -1}, a, b, c, &t, &b1, &b2));
  EXPECT_NEAR(t, 2.0, 1e-15);
  EXPECT_NEAR(b1, 0.25, 1e-15);
  EXPECT_NEAR(b2, 0.5, 1e-15);
  // Outside the triangle: weights still reported (the walk uses them).
  ASSERT_TRUE(ray_triangle(Vec3d{2, 0.5, 2}, Vec3d{0, 0, -1}, a, b, c, &t, &b1, &b2));
  EXPECT_LT(1.0 - b1 - b2, 0.0);
  // Parallel to the plane.
  EXPECT_FALSE(ray_triangle(Vec3d{0, 0, 1}, Vec3d{1, 0, 0}, a, b, c, &t, &b1, &b2));
}

TEST(Contact, LocalSearchFindsTheGlobalHit) {
  CellMeshSpec spec;
  spec.diameter = 56e-6;
  spec.target_vertices = 800;
  Result<Mesh> mesh = generate_cell_mesh(spec);
  ASSERT_TRUE(mesh.ok());
  Result<ContactSurface> surface = build_contact_surface(*mesh);
  ASSERT_TRUE(surface.ok());
  const std::vector<Vec3d> u(mesh->vertex_count(), Vec3d{0, 0, 0});
  std::mt19937 rng(7);
  std::normal_distribution<double> normal(0.0, 1.0);
  int32_t last = 0;
  int local = 0;
  for (int i = 0; i < 50; ++i) {
    Vec3d d{normal(rng), normal(rng), normal(rng)};
    d = d / norm(d);
    const Vec3d origin = -100e-6 * d + Vec3d{1e-6, -2e-6, 0.5e-6};
    const RayHit global = cast_ray(*surface, mesh->rest_positions, u, origin, d, -1);
    ASSERT_GE(global.triangle, 0);
    EXPECT_TRUE(global.global_scan);
    // From the previous ray's triangle (Ladjal et al.: search from the last contact triangle).
    const RayHit walked = cast_ray(*surface, mesh->rest_positions, u, origin, d, last);
    ASSERT_GE(walked.triangle, 0);
    expect_vec(walked.point, global.point, 1e-12);
    EXPECT_NEAR(walked.t, global.t, 1e-12);
    local += walked.global_scan ? 0 : 1;
    last = walked.triangle;
  }
  // The walk succeeds for most rays even when the last hit is on another side of the cell (it
  // falls back to the scan at silhouettes).
  EXPECT_GT(local, 25);
  // A nearby ray is found in a few steps from the last hit.
  const Vec3d d{1, 0, 0};
  const RayHit first = cast_ray(*surface, mesh->rest_positions, u, Vec3d{-1e-4, 0, 0}, d, -1);
  const RayHit next = cast_ray(*surface, mesh->rest_positions, u, Vec3d{-1e-4, 0.3e-6, 0}, d,
                               first.triangle);
  EXPECT_FALSE(next.global_scan);
  EXPECT_LE(next.walk_steps, 4);
}

TEST(Contact, RayFollowsTheDeformedSurface) {
  const Mesh box = generate_box_mesh(Vec3d{0, 0, 0}, Vec3d{4, 4, 2}, 4, 4, 2);
  Result<ContactSurface> s = build_contact_surface(box);
  ASSERT_TRUE(s.ok());
  std::vector<Vec3d> u(box.vertex_count(), Vec3d{0, 0, 0});
  const Vec3d origin{2.1, 1.9, 10}, dir{0, 0, -1};
  RayHit hit = cast_ray(*s, box.rest_positions, u, origin, dir, -1);
  ASSERT_GE(hit.triangle, 0);
  EXPECT_NEAR(hit.point.z, 2.0, 1e-12);
  // Push the whole top face down by 0.5: the hit follows.
  for (size_t v = 0; v < box.vertex_count(); ++v)
    if (box.rest_positions[v].z == 2.0) u[v] = Vec3d{0, 0, -0.5};
  hit = cast_ray(*s, box.rest_positions, u, origin, dir, hit.triangle);
  ASSERT_GE(hit.triangle, 0);
  EXPECT_NEAR(hit.point.z, 1.5, 1e-12);
  // A ray pointing away from the box misses it.
  EXPECT_LT(cast_ray(*s, box.rest_positions, u, origin, Vec3d{0, 0, 1}, hit.triangle).triangle, 0);
}

}  // namespace
}  // namespace zona
