// Tests for engine/contact: surface adjacency, ray-triangle intersection and Ladjal et al.'s local
// search, and the contact set's add / release / friction logic on small models.
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

// A 2x2x1 box of unit cubes (1 m, E 1 kPa) with a flat tool above its top face.
struct ContactRig {
  Mesh mesh = generate_box_mesh(Vec3d{0, 0, 0}, Vec3d{2, 2, 1}, 2, 2, 1);
  ContactSurface surface;
  Model model;
  ContactTool tool;
  ContactRig(double friction) {
    surface = *build_contact_surface(mesh);
    ModelDesc desc;
    desc.material.young = 1e3;
    desc.material.poisson = 0.3;
    desc.constitutive = ConstitutiveModel::kLinear;
    model = *build_model(mesh, desc);
    tool.kind = ContactTool::Kind::kNeedle;
    tool.needle = {NeedleShape::kFlat, 10.0, Vec3d{0, 0, -1}};
    tool.friction = friction;
  }
  std::vector<uint8_t> none() const { return std::vector<uint8_t>(mesh.vertex_count(), 0); }
};

TEST(Contact, VerticesInsideTheToolAreHeldAndCarriedAlong) {
  ContactRig rig(0.3);
  ContactSet set(rig.tool, rig.surface, rig.mesh.vertex_count(), rig.mesh.vertex_count());
  std::vector<Vec3d> u(rig.mesh.vertex_count(), Vec3d{0, 0, 0});
  // The flat face 0.1 below the top (z = 1): the 9 top vertices are inside.
  const Vec3d origin{1, 1, 0.9};
  const int32_t seeds[1] = {0};
  ContactUpdate up = set.update(rig.model, u, origin, seeds, rig.none(), true, 1.0);
  EXPECT_EQ(up.added, 9);
  EXPECT_EQ(set.size(), 9u);
  for (const Contact& c : set.contacts()) {
    EXPECT_DOUBLE_EQ(rig.mesh.rest_positions[static_cast<size_t>(c.vertex)].z, 1.0);
    expect_vec(c.normal, Vec3d{0, 0, -1}, 1e-15);
    EXPECT_NEAR((origin + c.anchor).z, 0.9, 1e-15);  // projected onto the face
  }
  // Targets follow the tool's next pose.
  std::vector<Vec3d> targets(set.size());
  set.targets(rig.model, u, origin + Vec3d{0.3, 0, -0.05}, targets);
  for (size_t i = 0; i < set.size(); ++i) expect_vec(targets[i], Vec3d{0.3, 0, -0.15}, 1e-15);
  // The local search (no full scan) from one seed finds the same set.
  ContactSet local(rig.tool, rig.surface, rig.mesh.vertex_count(), rig.mesh.vertex_count());
  const int32_t top_corner[1] = {static_cast<int32_t>(rig.mesh.vertex_count() - 1)};
  up = local.update(rig.model, u, origin, top_corner, rig.none(), false, 0.5);
  EXPECT_EQ(up.added, 9);
  // Taken vertices are skipped; a full set reports the overflow.
  std::vector<uint8_t> taken = rig.none();
  taken[static_cast<size_t>(top_corner[0])] = 1;
  ContactSet small(rig.tool, rig.surface, rig.mesh.vertex_count(), 4);
  up = small.update(rig.model, u, origin, seeds, taken, true, 1.0);
  EXPECT_EQ(up.added, 4);
  EXPECT_TRUE(up.overflow);
  for (const Contact& c : small.contacts()) EXPECT_NE(c.vertex, top_corner[0]);
}

TEST(Contact, PullingContactsAreReleasedAndFrictionReturnsToTheCone) {
  ContactRig rig(0.5);
  ContactSet set(rig.tool, rig.surface, rig.mesh.vertex_count(), 16);
  const size_t nv = rig.mesh.vertex_count();
  std::vector<Vec3d> u(nv, Vec3d{0, 0, 0}), force(nv, Vec3d{0, 0, 0}), ext(nv, Vec3d{0, 0, 0});
  const Vec3d origin{1, 1, 0.9};
  const int32_t seeds[1] = {0};
  set.update(rig.model, u, origin, seeds, rig.none(), true, 1.0);
  ASSERT_EQ(set.size(), 9u);
  std::vector<Vec3d> targets(set.size());
  set.targets(rig.model, u, origin, targets);  // at rest: u_before = 0
  // Elastic forces on the contacts: the first pulls away from the tool (towards -normal = +z
  // ... the body is below: normal -z points into it), the second is pushed with a tangential
  // load beyond the cone, the rest inside the cone.
  const int32_t pulling = set.contacts()[0].vertex, sliding = set.contacts()[1].vertex;
  for (const Contact& c : set.contacts()) force[static_cast<size_t>(c.vertex)] = Vec3d{0.1, 0, 1.0};
  force[static_cast<size_t>(pulling)] = Vec3d{0, 0, -1.0};  // static reaction +z: pulls
  force[static_cast<size_t>(sliding)] = Vec3d{-2.0, 0, 1.0};  // r = (2, 0, -1): |r_t| 2 > 0.5
  // Measured twice: the first measurement after a take is the free vertex's (the one-step
  // lag), and a contact is judged from the second.
  set.measure_reactions(rig.model, u, u, force, ext);
  set.measure_reactions(rig.model, u, u, force, ext);
  for (const Contact& c : set.contacts()) expect_vec(c.static_reaction, -1.0 * force[static_cast<size_t>(c.vertex)], 0);
  const Vec3d anchor_before = set.contacts()[1].anchor;
  ContactUpdate up = set.update(rig.model, u, origin, seeds, rig.none(), false, 0.0, 1.0);
  EXPECT_EQ(up.released, 1);
  EXPECT_EQ(up.slipping, 1);
  EXPECT_FALSE(set.holds(pulling));
  // The sliding contact's anchor moved against the excess tangential force by the step's
  // compliance: -c (|r_t| - mu r_n) t_hat, with relax 1.
  for (const Contact& c : set.contacts()) {
    if (c.vertex != sliding) {
      EXPECT_FALSE(c.slipping);
      continue;
    }
    EXPECT_TRUE(c.slipping);
    const double compliance = rig.model.vertex_coefficients[static_cast<size_t>(sliding)].c;
    expect_vec(c.anchor - anchor_before, Vec3d{-compliance * (2.0 - 0.5 * 1.0), 0, 0}, 1e-15);
  }
  // The released vertex is found again once it is inside the tool and free.
  up = set.update(rig.model, u, origin, seeds, rig.none(), true, 1.0);
  EXPECT_EQ(up.added, 1);
  EXPECT_TRUE(set.holds(pulling));
}

// Fixture for the release rule: the rig's nine top vertices held by the flat tool, and the
// elastic forces that measure_reactions reads (static reaction -f; the tool normal is -z, so
// f = (0, 0, s) gives a normal reaction s: positive pushes, negative pulls).
struct ReleaseRig {
  ContactRig rig{0.3};
  size_t nv = rig.mesh.vertex_count();
  ContactSet set{rig.tool, rig.surface, nv, 16};
  std::vector<Vec3d> u = std::vector<Vec3d>(nv, Vec3d{0, 0, 0});
  std::vector<Vec3d> force = std::vector<Vec3d>(nv, Vec3d{0, 0, 0});
  std::vector<Vec3d> ext = std::vector<Vec3d>(nv, Vec3d{0, 0, 0});
  Vec3d origin{1, 1, 0.9};
  int32_t seeds[1] = {0};
  ReleaseRig() {
    set.update(rig.model, u, origin, seeds, rig.none(), true, 1.0);
    std::vector<Vec3d> targets(set.size());
    set.targets(rig.model, u, origin, targets);
  }
  int32_t vertex(size_t i) const { return set.contacts()[i].vertex; }
  void set_normal(int32_t v, double s, double tangential = 0) {
    force[static_cast<size_t>(v)] = Vec3d{tangential, 0, s};
  }
  ContactUpdate measure_and_update() {
    set.measure_reactions(rig.model, u, u, force, ext);
    return set.update(rig.model, u, origin, seeds, rig.none(), false, 0.0);
  }
};

TEST(Contact, ReleaseActsOnPullingReactionsNotOnRounding) {
  ReleaseRig r;
  ASSERT_EQ(r.set.size(), 9u);
  for (size_t i = 0; i < 9; ++i) r.set_normal(r.vertex(i), 1.0);
  const int32_t rounding_pull = r.vertex(0), zero = r.vertex(1), small_pull = r.vertex(2),
                clear_pull = r.vertex(3);
  // The first measurement after the take is the free vertex's force before it was put on the
  // tool: not judged, even where it pulls clearly.
  r.set_normal(clear_pull, -1.0);
  r.set_normal(zero, -0.0);
  ContactUpdate up = r.measure_and_update();
  EXPECT_EQ(up.released, 0);
  EXPECT_EQ(up.slipping, 0);
  EXPECT_EQ(r.set.size(), 9u);
  // Measured on the tool: five contacts push with 1 N; a pull at rounding level (1e-17 N), an
  // exact zero and a pull within the tolerance (2e-4 of the mean |reaction| ~0.56 N) are kept;
  // a pull of 1 % of the mean contact load is released.
  r.set_normal(rounding_pull, -1e-17);
  r.set_normal(small_pull, -2e-4, 0.1);
  r.set_normal(clear_pull, -1e-2);
  up = r.measure_and_update();
  EXPECT_EQ(up.released, 1);
  EXPECT_FALSE(r.set.holds(clear_pull));
  EXPECT_TRUE(r.set.holds(rounding_pull));
  EXPECT_TRUE(r.set.holds(zero));
  EXPECT_TRUE(r.set.holds(small_pull));
  // A kept contact that does not push has no friction cone: any tangential load slides it.
  for (const Contact& c : r.set.contacts()) EXPECT_EQ(c.slipping, c.vertex == small_pull) << c.vertex;
  // The same rounding-level pull with the opposite sign changes nothing either; the released
  // vertex, still inside the tool, is taken again (fresh).
  r.set_normal(rounding_pull, 1e-17);
  up = r.measure_and_update();
  EXPECT_EQ(up.released, 0);
  EXPECT_EQ(up.added, 1);
  EXPECT_TRUE(r.set.holds(rounding_pull));
  EXPECT_TRUE(r.set.holds(clear_pull));
  // A non-finite reaction releases its own contact only (it must not poison the tolerance).
  r.set_normal(zero, std::numeric_limits<double>::quiet_NaN());
  up = r.measure_and_update();
  EXPECT_EQ(up.released, 1);
  EXPECT_FALSE(r.set.holds(zero));
}

TEST(Contact, PeelingContactIsReleasedWithinAStepOfPulling) {
  // One contact's reaction falls through zero by 1 % of the contact load per update (a slow
  // peel: the tolerance is a tenth of a step of it); it must be released at the first or second
  // update that measures a pull, so the tolerance makes no sticky contact.
  ReleaseRig r;
  for (size_t i = 0; i < 9; ++i) r.set_normal(r.vertex(i), 1.0);
  const int32_t peeling = r.vertex(4);
  r.measure_and_update();  // the take's measurement
  int pulls_measured = 0;
  for (int k = 0; k < 200 && r.set.holds(peeling); ++k) {
    const double s = 0.105 - 0.01 * k;  // crosses zero between k = 10 and 11
    r.set_normal(peeling, s);
    if (s < 0) ++pulls_measured;
    r.measure_and_update();
  }
  EXPECT_FALSE(r.set.holds(peeling));
  EXPECT_GE(pulls_measured, 1);
  EXPECT_LE(pulls_measured, 2);
  EXPECT_EQ(r.set.size(), 8u);
}

TEST(Contact, WithdrawnToolReleasesEveryContactWithinTwoSteps) {
  // The flat tool pressed into the box, held, then pulled up past the rest surface with the
  // explicit integrator in the loop: each contact is released at most one update after the
  // first one that measured it pulling, and none is left once the tool has left the body.
  ContactRig rig(0.3);
  const size_t nv = rig.mesh.vertex_count();
  State state = make_state(rig.model, 1);
  ContactSet set(rig.tool, rig.surface, nv, nv);
  const int32_t seeds[1] = {0};
  std::vector<Vec3d> targets(nv);
  std::vector<int32_t> vertices;
  std::vector<int> first_pull(nv, -1);
  // Tool face height per step: down 0.05 over 20 steps, held 20, up to 1.1 over 10.
  auto height = [](int k) {
    if (k < 20) return 1.0 - 0.0025 * (k + 1);
    if (k < 40) return 0.95;
    return std::min(1.1, 0.95 + 0.015 * (k - 39));
  };
  Vec3d origin{1, 1, 1.0};
  int max_delay = 0, taken = 0;
  for (int k = 0; k < 60; ++k) {
    const ContactUpdate up =
        set.update(rig.model, state.u, origin, seeds, std::vector<uint8_t>(nv, 0), true, 1.0);
    taken += up.added;
    for (size_t v = 0; v < nv; ++v) {
      if (first_pull[v] < 0 || set.holds(static_cast<int32_t>(v))) continue;
      max_delay = std::max(max_delay, k - first_pull[v]);
      first_pull[v] = -1;
    }
    const Vec3d next{1, 1, height(k)};
    vertices.clear();
    for (const Contact& c : set.contacts()) vertices.push_back(c.vertex);
    set.targets(rig.model, state.u_prev, next, targets);
    ASSERT_TRUE(set_prescribed_vertices(rig.model, state, vertices).ok());
    std::copy(targets.begin(), targets.begin() + static_cast<std::ptrdiff_t>(set.size()),
              state.prescribed_displacement.begin());
    step(rig.model, state);
    set.measure_reactions(rig.model, state.u, state.u_prev, state.force, state.external_force);
    for (const Contact& c : set.contacts())
      if (c.measurements >= 2 && dot(c.static_reaction, c.normal) < 0 &&
          first_pull[static_cast<size_t>(c.vertex)] < 0)
        first_pull[static_cast<size_t>(c.vertex)] = k + 1;  // the update that reads it
    origin = next;
  }
  EXPECT_GE(taken, 9);
  EXPECT_EQ(set.size(), 0u);
  EXPECT_LE(max_delay, 1);
}

TEST(Contact, MeasuredReactionIsTheIntegratorsConstraintForce) {
  // One explicit step with the contacts prescribed: the contact set's reactions must sum to the
  // integrator's own constraint force.
  ContactRig rig(0.3);
  const size_t nv = rig.mesh.vertex_count();
  State state = make_state(rig.model, 1);
  ContactSet set(rig.tool, rig.surface, nv, nv);
  const int32_t seeds[1] = {0};
  const Vec3d origin{1, 1, 0.95};
  set.update(rig.model, state.u, origin, seeds, std::vector<uint8_t>(nv, 0), true, 1.0);
  std::vector<int32_t> vertices;
  for (const Contact& c : set.contacts()) vertices.push_back(c.vertex);
  std::vector<Vec3d> targets(set.size());
  set.targets(rig.model, state.u_prev, origin + Vec3d{0, 0, -0.01}, targets);
  ASSERT_TRUE(set_prescribed_vertices(rig.model, state, vertices).ok());
  std::copy(targets.begin(), targets.end(), state.prescribed_displacement.begin());
  step(rig.model, state);
  set.measure_reactions(rig.model, state.u, state.u_prev, state.force, state.external_force);
  const Vec3d total = set.total_reaction();
  expect_vec(total, state.diag.constraint_force, 1e-12 * norm(total));
  EXPECT_GT(norm(total), 0.0);
}

}  // namespace
}  // namespace zona
