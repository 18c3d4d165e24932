// Tests for engine/holding: the tube wall's distance, the aspirated patch and its suction force.
#include "engine/tools/holding.h"

#include <gtest/gtest.h>

#include <cmath>
#include <numbers>

#include "engine/tools/contact.h"
#include "engine/mesh/mesh_generate.h"

namespace zona {
namespace {

void expect_vec(Vec3d a, Vec3d b, double tol) {
  EXPECT_NEAR(a.x, b.x, tol);
  EXPECT_NEAR(a.y, b.y, tol);
  EXPECT_NEAR(a.z, b.z, tol);
}

// A tube along +x with its mouth at x = 10, bore 2, rim out to 5.
HoldingGeometry test_tube() {
  HoldingGeometry h;
  h.axis = Vec3d{1, 0, 0};
  h.mouth = Vec3d{10, 0, 0};
  h.inner_radius = 2;
  h.outer_radius = 5;
  return h;
}

TEST(Holding, TubeWallDistance) {
  const HoldingGeometry h = test_tube();
  // In front of the rim face: distance to the mouth plane, normal back towards the cell.
  ToolDistance d = holding_distance(h, Vec3d{8, 3, 0});
  EXPECT_DOUBLE_EQ(d.distance, 2.0);
  expect_vec(d.normal, Vec3d{-1, 0, 0}, 1e-15);
  // Over the opening, in front of the mouth: distance to the inner rim edge.
  d = holding_distance(h, Vec3d{7, 0, -2});
  EXPECT_NEAR(d.distance, 3.0, 1e-12);
  // Aspirated into the bore: distance to the bore wall, normal towards the axis.
  d = holding_distance(h, Vec3d{12, 0, 1.5});
  EXPECT_NEAR(d.distance, 0.5, 1e-12);
  expect_vec(d.normal, Vec3d{0, 0, -1}, 1e-15);
  // Pushed into the rim: leaves through the nearest face (the mouth).
  d = holding_distance(h, Vec3d{10.3, 0, 3.5});
  EXPECT_NEAR(d.distance, -0.3, 1e-12);
  expect_vec(d.normal, Vec3d{-1, 0, 0}, 1e-15);
  // Inside the wall, nearest the bore.
  d = holding_distance(h, Vec3d{15, 2.2, 0});
  EXPECT_NEAR(d.distance, -0.2, 1e-12);
  expect_vec(d.normal, Vec3d{0, -1, 0}, 1e-15);
}

TEST(Holding, RoundedMouthEdges) {
  // edge_radius 1 on a rim from 2 to 5: the mouth's flat face (rho 3..4), the bore and the outer
  // wall keep the sharp wall's distance; around each edge the distance is to a quarter circle
  // of radius 1 centred 1 inside the wall; the normal is the distance's gradient everywhere.
  const HoldingGeometry sharp = test_tube();
  HoldingGeometry round = sharp;
  round.edge_radius = 1;
  for (const Vec3d& x : {Vec3d{8, 3.5, 0}, Vec3d{12, 0, 1.5}, Vec3d{15, 2.2, 0}, Vec3d{14, 0, -6},
                         Vec3d{10.3, 0, 3.5}})
    EXPECT_NEAR(holding_distance(round, x).distance, holding_distance(sharp, x).distance, 1e-12)
        << x.x << " " << x.y << " " << x.z;
  // Around the inner edge (centre s = 1, rho = 3) and the outer one (s = 1, rho = 4), outside
  // and inside the wall.
  const struct {
    double s, rho, cs, crho;
  } corner[] = {{-1.0, 1.0, 1, 3}, {0.2, 2.1, 1, 3}, {0.5, 2.6, 1, 3}, {-0.5, 5.5, 1, 4},
                {0.4, 4.7, 1, 4}};
  for (const auto& c : corner) {
    const Vec3d x{10 + c.s, 0, c.rho};
    const double expected = std::hypot(c.s - c.cs, c.rho - c.crho) - 1.0;
    EXPECT_NEAR(holding_distance(round, x).distance, expected, 1e-12) << c.s << " " << c.rho;
    EXPECT_GT(holding_distance(round, x).distance, holding_distance(sharp, x).distance);
  }
  // The normal is the gradient of the distance (central differences) off the axis and the
  // wall's medial surfaces.
  const double h = 1e-6;
  int checked = 0;
  for (double s = -1.5; s <= 1.5; s += 0.37)
    for (double rho = 0.7; rho <= 6.0; rho += 0.41) {
      const Vec3d x{10 + s, 0.3 * rho, 0.954 * rho};
      const ToolDistance d = holding_distance(round, x);
      for (int i = 0; i < 3; ++i) {
        Vec3d xp = x, xm = x;
        xp[i] += h;
        xm[i] -= h;
        const double g =
            (holding_distance(round, xp).distance - holding_distance(round, xm).distance) / (2 * h);
        if (std::abs(g - d.normal[i]) > 1e-5) {
          // Only where the nearest face changes (the medial line inside the wall).
          EXPECT_LT(d.distance, 0) << s << " " << rho << " axis " << i;
          continue;
        }
        ++checked;
      }
    }
  EXPECT_GT(checked, 300);
}

struct Ball {
  Mesh mesh;
  ContactSurface surface;
};

Ball make_ball(double diameter, int64_t vertices) {
  CellMeshSpec spec;
  spec.diameter = diameter;
  spec.target_vertices = vertices;
  Result<Mesh> mesh = generate_cell_mesh(spec);
  EXPECT_TRUE(mesh.ok());
  Ball b{std::move(*mesh), {}};
  Result<ContactSurface> s = build_contact_surface(b.mesh);
  EXPECT_TRUE(s.ok());
  b.surface = std::move(*s);
  return b;
}

TEST(Holding, SuctionIsPressureTimesAspiratedArea) {
  const Ball b = make_ball(56e-6, 1500);
  HoldingPipetteDef def;
  def.enabled = true;
  def.mode = HoldingMode::kSuction;
  def.inner_radius = 12e-6;
  def.suction = 2.5e3;
  Result<HoldingSetup> h = make_holding(def, b.surface, b.mesh.rest_positions, Vec3d{0, 0, 0},
                                        Vec3d{1, 0, 0});
  ASSERT_TRUE(h.ok()) << h.error().message;
  // The mouth sits where the circle of the inner radius meets the cell: sqrt(R^2 - a^2).
  const double r = 28e-6, a = 12e-6;
  EXPECT_NEAR(h->geometry.mouth.x, std::sqrt(r * r - a * a), 0.05 * r);
  EXPECT_DOUBLE_EQ(h->geometry.outer_radius, 1.25 * a);  // thin rim default
  // Total suction force: exactly p times the patch's projected area, along the axis...
  EXPECT_NEAR(h->suction_total.x, def.suction * h->aspirated_area, 1e-12 * h->suction_total.x);
  EXPECT_NEAR(h->suction_total.y, 0.0, 0.02 * h->suction_total.x);
  EXPECT_NEAR(h->suction_total.z, 0.0, 0.02 * h->suction_total.x);
  // ... and that area is the opening's, pi a^2, up to the patch's faceting.
  EXPECT_NEAR(h->aspirated_area, std::numbers::pi * a * a, 0.25 * std::numbers::pi * a * a);
  // Patch vertices: on the pipette side, near the axis.
  ASSERT_FALSE(h->patch_vertices.empty());
  for (int32_t v : h->patch_vertices) {
    const Vec3d x = b.mesh.rest_positions[static_cast<size_t>(v)];
    EXPECT_GT(x.x, 0.0);
    EXPECT_LT(std::hypot(x.y, x.z), 2.0 * a);
  }
}

TEST(Holding, BadPipettesAreRefused) {
  const Ball b = make_ball(56e-6, 400);
  HoldingPipetteDef def;
  def.enabled = true;
  def.inner_radius = 40e-6;  // wider than the cell
  Result<HoldingSetup> h =
      make_holding(def, b.surface, b.mesh.rest_positions, Vec3d{0, 0, 0}, Vec3d{1, 0, 0});
  ASSERT_FALSE(h.ok());
  EXPECT_NE(h.error().message.find("not smaller than the cell radius"), std::string::npos);
  def.inner_radius = 0.05e-6;  // narrower than any triangle
  h = make_holding(def, b.surface, b.mesh.rest_positions, Vec3d{0, 0, 0}, Vec3d{1, 0, 0});
  ASSERT_FALSE(h.ok());
  EXPECT_NE(h.error().message.find("no surface triangle"), std::string::npos);
}

}  // namespace
}  // namespace zona
