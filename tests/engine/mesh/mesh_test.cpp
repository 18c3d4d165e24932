// Tests for engine/mesh: validation, boundary extraction, adjacency, quality.
#include "engine/mesh/mesh.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <map>

namespace zona {
namespace {

// A unit cube split into 6 positively oriented tetrahedra around the diagonal 0-6.
Mesh unit_cube() {
  Mesh m;
  m.rest_positions = {{0, 0, 0}, {1, 0, 0}, {1, 1, 0}, {0, 1, 0},
                      {0, 0, 1}, {1, 0, 1}, {1, 1, 1}, {0, 1, 1}};
  m.tets = {{0, 1, 2, 6}, {0, 2, 3, 6}, {0, 3, 7, 6}, {0, 7, 4, 6}, {0, 4, 5, 6}, {0, 5, 1, 6}};
  for (Tet& t : m.tets)
    if (tet_rest_volume(m, static_cast<size_t>(&t - m.tets.data())) < 0) std::swap(t[2], t[3]);
  m.tet_region.assign(m.tets.size(), kRegionCytoplasm);
  return m;
}

TEST(Mesh, CubeVolumeAndOrientation) {
  Mesh m = unit_cube();
  ASSERT_TRUE(validate_mesh(m, "cube").ok());
  double v = 0;
  for (size_t t = 0; t < m.tet_count(); ++t) {
    EXPECT_GT(tet_rest_volume(m, t), 0);
    v += tet_rest_volume(m, t);
  }
  EXPECT_NEAR(v, 1.0, 1e-14);
  EXPECT_NEAR(mesh_quality(m).volume, 1.0, 1e-14);
}

TEST(Mesh, BoundaryIsClosedAndOutward) {
  Mesh m = unit_cube();
  ASSERT_TRUE(validate_mesh(m, "cube").ok());
  const BoundarySurface s = extract_boundary(m);
  // 6 square faces, two triangles each; all 8 corners on the boundary.
  EXPECT_EQ(s.triangles.size(), 12u);
  EXPECT_EQ(s.vertices.size(), 8u);
  // Divergence theorem: sum over outward faces of (centroid . n) area / 3 equals the volume.
  double flux = 0;
  for (const Triangle& tri : s.triangles) {
    const Vec3d a = m.rest_positions[tri[0]], b = m.rest_positions[tri[1]],
                c = m.rest_positions[tri[2]];
    const Vec3d n2 = cross(b - a, c - a);  // twice the area times the normal
    flux += dot((a + b + c) / 3.0, n2) / 6.0;
  }
  EXPECT_NEAR(flux, 1.0, 1e-14);
  // Closed 2-manifold: every edge used by exactly two triangles, in opposite directions.
  std::map<std::pair<int, int>, int> directed;
  for (const Triangle& tri : s.triangles)
    for (int i = 0; i < 3; ++i) ++directed[{tri[i], tri[(i + 1) % 3]}];
  for (const auto& [edge, count] : directed) {
    EXPECT_EQ(count, 1);
    EXPECT_EQ(directed.count({edge.second, edge.first}), 1u);
  }
}

TEST(Mesh, AdjacencyListsEveryCornerOnce) {
  Mesh m = unit_cube();
  ASSERT_TRUE(validate_mesh(m, "cube").ok());
  const VertexTetAdjacency a = build_vertex_tet_adjacency(m);
  ASSERT_EQ(a.offsets.size(), m.vertex_count() + 1);
  EXPECT_EQ(a.offsets.back(), static_cast<int32_t>(4 * m.tet_count()));
  // Vertices 0 and 6 are on the shared diagonal: in all six tetrahedra.
  EXPECT_EQ(a.offsets[1] - a.offsets[0], 6);
  EXPECT_EQ(a.offsets[7] - a.offsets[6], 6);
  for (size_t v = 0; v < m.vertex_count(); ++v)
    for (int32_t s = a.offsets[v]; s < a.offsets[v + 1]; ++s) {
      EXPECT_EQ(m.tets[a.tets[s]][a.corner[s]], static_cast<int32_t>(v));
      if (s > a.offsets[v]) {
        EXPECT_LT(a.tets[s - 1], a.tets[s]);
      }
    }
}

TEST(Mesh, RegularTetrahedronQuality) {
  const Vec3d a{1, 1, 1}, b{1, -1, -1}, c{-1, 1, -1}, d{-1, -1, 1};
  TetQuality q = tet_quality(a, b, c, d);
  if (q.volume < 0) q = tet_quality(a, b, d, c);
  const double dihedral = std::acos(1.0 / 3.0) * 180.0 / M_PI;  // 70.53 degrees
  EXPECT_NEAR(q.min_dihedral_deg, dihedral, 1e-9);
  EXPECT_NEAR(q.max_dihedral_deg, dihedral, 1e-9);
  EXPECT_NEAR(q.aspect_ratio, 1.0, 1e-12);
  EXPECT_NEAR(std::abs(q.volume), 8.0 / 3.0, 1e-12);
}

TEST(Mesh, SliverHasSmallDihedral) {
  // Four nearly coplanar points: a sliver, with dihedral angles near 0 and 180 degrees.
  const TetQuality q = tet_quality({0, 0, 0}, {1, 0, 0}, {0, 1, 0}, {1, 1, 1e-3});
  EXPECT_LT(q.min_dihedral_deg, 1.0);
  EXPECT_GT(q.max_dihedral_deg, 179.0);
  EXPECT_GT(q.aspect_ratio, 100.0);
}

TEST(Mesh, InvertedElementRepairedWithWarning) {
  Mesh m = unit_cube();
  std::swap(m.tets[3][0], m.tets[3][1]);
  std::vector<std::string> warnings;
  ASSERT_TRUE(validate_mesh(m, "cube", {}, &warnings).ok());
  ASSERT_EQ(warnings.size(), 1u);
  EXPECT_NE(warnings[0].find("first: 3"), std::string::npos) << warnings[0];
  EXPECT_GT(tet_rest_volume(m, 3), 0);
}

TEST(Mesh, InvertedElementRejectedWhenAsked) {
  Mesh m = unit_cube();
  std::swap(m.tets[4][0], m.tets[4][1]);
  ValidateOptions options;
  options.inverted = InvertedPolicy::kReject;
  const Status s = validate_mesh(m, "cube.msh", options);
  ASSERT_FALSE(s.ok());
  EXPECT_NE(s.error().message.find("cube.msh: tetrahedron 4 is inverted"), std::string::npos)
      << s.error().message;
}

TEST(Mesh, BadInputsNameTheElement) {
  struct Case {
    const char* what;
    void (*mutate)(Mesh&);
    const char* expected;
  };
  const Case cases[] = {
      {"out of range", [](Mesh& m) { m.tets[2][1] = 99; }, "tetrahedron 2 references vertex 99"},
      {"negative", [](Mesh& m) { m.tets[1][0] = -1; }, "tetrahedron 1 references vertex -1"},
      {"repeated", [](Mesh& m) { m.tets[5][3] = m.tets[5][0]; }, "tetrahedron 5 repeats vertex"},
      {"nan", [](Mesh& m) { m.rest_positions[4].y = std::nan(""); },
       "vertex 4 has a non-finite coordinate"},
      {"flat", [](Mesh& m) { m.rest_positions[6] = {0.5, 0.5, 0}; }, "has zero volume"},
      {"regions", [](Mesh& m) { m.tet_region.pop_back(); }, "5 region tags for 6 tetrahedra"},
      {"empty", [](Mesh& m) { m.tets.clear(); }, "no tetrahedra"},
  };
  for (const Case& c : cases) {
    Mesh m = unit_cube();
    c.mutate(m);
    const Status s = validate_mesh(m, "bad.msh", {});
    ASSERT_FALSE(s.ok()) << c.what;
    EXPECT_NE(s.error().message.find(c.expected), std::string::npos)
        << c.what << ": " << s.error().message;
    EXPECT_EQ(s.error().message.rfind("bad.msh: ", 0), 0u) << s.error().message;
  }
}

TEST(Mesh, UnreferencedVertexWarnsOrFails) {
  Mesh m = unit_cube();
  m.rest_positions.push_back({5, 5, 5});
  std::vector<std::string> warnings;
  ASSERT_TRUE(validate_mesh(m, "cube", {}, &warnings).ok());
  ASSERT_EQ(warnings.size(), 1u);
  EXPECT_NE(warnings[0].find("first: 8"), std::string::npos);
  ValidateOptions strict;
  strict.reject_unreferenced = true;
  const Status s = validate_mesh(m, "cube", strict);
  ASSERT_FALSE(s.ok());
  EXPECT_NE(s.error().message.find("vertex 8 is not used"), std::string::npos);
}

TEST(Mesh, MinAltitudeOfCube) {
  Mesh m = unit_cube();
  ASSERT_TRUE(validate_mesh(m, "cube").ok());
  const MeshQuality q = mesh_quality(m);
  // Tets around the long diagonal: smallest height is from a corner onto the opposite face.
  EXPECT_GT(q.min_altitude, 0.0);
  EXPECT_LE(q.min_altitude, q.min_edge);
  EXPECT_NEAR(q.min_edge, 1.0, 1e-14);
  EXPECT_NEAR(q.max_edge, std::sqrt(3.0), 1e-14);
}

}  // namespace
}  // namespace zona
