// CPU side of the renderer (no Vulkan needed): render space, smooth normals from deformed
// positions, surface compaction, pipette meshes, camera framing, legend labels.
#include "render/geometry.h"

#include <gtest/gtest.h>

#include <cmath>

#include "render/frame_source.h"
#include "render/overlay.h"

namespace zona::render {
namespace {

// A regular octahedron of radius r about the origin: 6 vertices, 8 outward triangles.
struct Octahedron {
  std::vector<Vec3d> rest;
  std::vector<Triangle> triangles;
  explicit Octahedron(double r) {
    rest = {{r, 0, 0}, {-r, 0, 0}, {0, r, 0}, {0, -r, 0}, {0, 0, r}, {0, 0, -r}};
    triangles = {{0, 2, 4}, {2, 1, 4}, {1, 3, 4}, {3, 0, 4},
                 {2, 0, 5}, {1, 2, 5}, {3, 1, 5}, {0, 3, 5}};
  }
};

TEST(RenderGeometry, NormalsPointOutOfTheDeformedSurface) {
  Octahedron o(10e-6);
  RenderFrame f;
  f.rest = o.rest;
  f.triangles = o.triangles;
  RenderSpace space{{0, 0, 0}, 1e5};
  SurfaceGeometry s;
  ASSERT_TRUE(update_surface(f, space, &s).ok());
  ASSERT_EQ(s.mesh.positions.size(), 6u);
  for (size_t i = 0; i < 6; ++i) {
    const gpu::vec3 p(s.mesh.positions[i]), n(s.mesh.normals[i]);
    EXPECT_NEAR(glm::length(n), 1.0f, 1e-5f);
    EXPECT_NEAR(glm::dot(n, glm::normalize(p)), 1.0f, 1e-5f);  // a vertex normal is radial
    EXPECT_NEAR(glm::length(p), 1.0f, 1e-6f);                  // 10 um at 1e5 / m
  }
  // Rotate the body 90 degrees about z through its displacement: every normal must turn with
  // it (from the deformed positions), e.g. mesh vertex 0 at rest on +x now faces +y.
  std::vector<Vec3d> u(6);
  for (size_t i = 0; i < 6; ++i) u[i] = Vec3d{-o.rest[i].y, o.rest[i].x, o.rest[i].z} - o.rest[i];
  f.displacement = u;
  ASSERT_TRUE(update_surface(f, space, &s).ok());
  for (size_t i = 0; i < 6; ++i) {
    const Vec3d r = o.rest[static_cast<size_t>(s.mesh_vertex[i])];
    const gpu::vec3 n(s.mesh.normals[i]);
    const gpu::vec3 turned(static_cast<float>(-r.y), static_cast<float>(r.x),
                           static_cast<float>(r.z));
    EXPECT_NEAR(glm::dot(n, glm::normalize(turned)), 1.0f, 1e-5f) << "vertex " << i;
  }
}

TEST(RenderGeometry, CompactsToTheVerticesTheTrianglesUse) {
  Octahedron o(1e-6);
  o.rest.push_back({5e-6, 5e-6, 5e-6});  // an interior vertex no triangle uses
  std::vector<float> scalar = {1, 2, 3, 4, 5, 6, 100};
  RenderFrame f;
  f.rest = o.rest;
  f.triangles = o.triangles;
  f.scalar = scalar;
  SurfaceGeometry s;
  ASSERT_TRUE(update_surface(f, RenderSpace{}, &s).ok());
  EXPECT_EQ(s.mesh_vertex.size(), 6u);
  EXPECT_EQ(s.mesh.indices.size(), 24u);
  EXPECT_EQ(s.scalar_min, 1.0);
  EXPECT_EQ(s.scalar_max, 6.0);  // the unused vertex does not widen the range
  for (size_t i = 0; i < 6; ++i)
    EXPECT_EQ(s.mesh.positions[i].w, scalar[static_cast<size_t>(s.mesh_vertex[i])]);
}

TEST(RenderGeometry, PercentileIgnoresASingularPeak) {
  // 100 vertices on a strip of triangles with values 0..98 and one tip value of 1e6.
  std::vector<Vec3d> rest;
  std::vector<float> scalar;
  std::vector<Triangle> triangles;
  for (int i = 0; i < 100; ++i) {
    rest.push_back({1e-6 * (i / 2), 1e-6 * (i % 2), 0});
    scalar.push_back(i == 50 ? 1e6f : static_cast<float>(i < 50 ? i : i - 1));
    if (i >= 2) triangles.push_back({i - 2, i - 1, i});
  }
  RenderFrame f;
  f.rest = rest;
  f.triangles = triangles;
  f.scalar = scalar;
  SurfaceGeometry s;
  ASSERT_TRUE(update_surface(f, RenderSpace{}, &s).ok());
  EXPECT_EQ(s.scalar_max, 1e6);
  EXPECT_GE(s.scalar_p98, 96.0);
  EXPECT_LE(s.scalar_p98, 98.0);
}

TEST(RenderGeometry, RejectsInconsistentInput) {
  Octahedron o(1e-6);
  RenderFrame f;
  f.rest = o.rest;
  f.triangles = o.triangles;
  std::vector<float> scalar(5, 0.0f);
  f.scalar = scalar;
  SurfaceGeometry s;
  EXPECT_FALSE(update_surface(f, RenderSpace{}, &s).ok());
  f.scalar = {};
  std::vector<Triangle> bad = {{0, 1, 6}};
  f.triangles = bad;
  const Status st = update_surface(f, RenderSpace{}, &s);
  ASSERT_FALSE(st.ok());
  EXPECT_NE(st.error().message.find("vertex 6"), std::string::npos);
}

TEST(RenderGeometry, NeedleMeshIsARoundedCylinder) {
  NeedlePose needle;
  needle.visible = true;
  needle.tip = {1e-6, 2e-6, 3e-6};
  needle.direction = {0, 0, 1};
  needle.tip_radius = 2e-6;
  MeshData mesh;
  RenderSpace space{{0, 0, 0}, 1e6};  // micrometres
  append_needle(needle, 50e-6, space, &mesh);
  ASSERT_FALSE(mesh.indices.empty());
  float zmax = -1e9f, zmin = 1e9f;
  for (size_t i = 0; i < mesh.positions.size(); ++i) {
    const gpu::vec3 p(mesh.positions[i]);
    zmax = std::max(zmax, p.z);
    zmin = std::min(zmin, p.z);
    // Every vertex lies within the tip radius of the axis through the tip.
    EXPECT_LE(std::hypot(p.x - 1.0f, p.y - 2.0f), 2.0f + 1e-4f);
  }
  EXPECT_NEAR(zmax, 3.0f, 1e-4f);          // the apex is the tip point
  EXPECT_NEAR(zmin, 3.0f - 50.0f, 1e-3f);  // the shaft runs back along -direction
  for (uint32_t i : mesh.indices) EXPECT_LT(i, mesh.positions.size());
}

TEST(RenderGeometry, HoldingPipetteIsATubeBehindItsMouth) {
  HoldingPose holding;
  holding.visible = true;
  holding.mouth = {30e-6, 0, 0};
  holding.axis = {1, 0, 0};
  holding.inner_radius = 10e-6;
  holding.outer_radius = 12e-6;
  MeshData mesh;
  append_holding(holding, 100e-6, RenderSpace{{0, 0, 0}, 1e6}, &mesh);
  ASSERT_FALSE(mesh.indices.empty());
  for (const gpu::vec4& p : mesh.positions) {
    const float rho = std::hypot(p.y, p.z);
    EXPECT_GE(p.x, 30.0f - 1e-3f);  // nothing on the cell's side of the mouth
    EXPECT_GE(rho, 10.0f - 1e-3f);  // the bore is open
    EXPECT_LE(rho, 12.0f + 1e-3f);
  }
}

TEST(RenderGeometry, FitCameraShowsTheSphereAtTheAskedSize) {
  const OrbitCamera c = fit_camera({1e-6, 0, 0}, 28e-6, 0.5, 0, 0, 40);
  // Eye on +z at the distance where the sphere subtends half of the 40 degree view.
  const Vec3d eye = camera_eye(c);
  EXPECT_NEAR(eye.x, 1e-6, 1e-12);
  EXPECT_NEAR(eye.z, c.distance, 1e-12);
  EXPECT_NEAR(2 * std::asin(28e-6 / c.distance) * 180 / 3.14159265358979, 20.0, 1e-9);
  OrbitCamera o = c;
  orbit_camera(&o, 0, 120);
  EXPECT_EQ(o.pitch_deg, 89.0);  // clamped short of the pole
}

TEST(RenderGeometry, ColorMapRunsColdToWarm) {
  const gpu::vec3 low = gpu::color_map(0.0f), high = gpu::color_map(1.0f);
  EXPECT_GT(low.b, low.r);
  EXPECT_GT(high.r, high.b);
  EXPECT_EQ(gpu::color_map(-3.0f), low);  // clamped
  EXPECT_EQ(gpu::color_map(7.0f), high);
}

TEST(RenderGeometry, LegendLabelsUseCellScaleUnits) {
  EXPECT_EQ(format_field_value(ColorField::kDisplacement, 12.5e-6), "12.5");
  EXPECT_EQ(format_field_value(ColorField::kStress, 2500.0), "2.5");
  EXPECT_EQ(field_title(ColorField::kStress), "von Mises stress [kPa]");
  EXPECT_TRUE(parse_color_field("stress").ok());
  EXPECT_FALSE(parse_color_field("strain").ok());
}

}  // namespace
}  // namespace zona::render
