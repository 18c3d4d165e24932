// State: sizes, prescribed-vertex bookkeeping and its errors, reset.
#include "engine/fem/state.h"

#include <gtest/gtest.h>

#include <algorithm>

#include "tests/engine/physics_test_meshes.h"

namespace zona {
namespace {

Model small_model() {
  ModelDesc d;
  d.fixed_vertices = {0, 1};
  return build_model(testing::box_mesh({0, 0, 0}, {1e-5, 1e-5, 1e-5}, 2, 2, 2), d).value();
}

TEST(State, MakeStateSizesEverything) {
  const Model m = small_model();
  const State s = make_state(m, 2);
  EXPECT_EQ(s.u.size(), m.vertex_count());
  EXPECT_EQ(s.u_prev.size(), m.vertex_count());
  EXPECT_EQ(s.u_next.size(), m.vertex_count());
  // One segment per thread; blocks: one per vertex, one per late corner.
  EXPECT_EQ(s.assembly.segment_count(), std::min<int64_t>(2, s.tet_chunks.size()));
  EXPECT_EQ(s.assembly.blocks.size(), 4 * (m.vertex_count() + s.assembly.late_count()));
  EXPECT_EQ(s.tet_chunks.size(), (m.tet_count() + kTetChunk - 1) / kTetChunk);
  EXPECT_EQ(s.vertex_constraint[0], kVertexFixed);
  EXPECT_EQ(s.vertex_constraint[2], kVertexFree);
  EXPECT_GE(s.prescribed_vertices.capacity(), m.vertex_count());
  EXPECT_EQ(s.pool->thread_count(), 2);
}

TEST(State, PrescribedVertices) {
  const Model m = small_model();
  State s = make_state(m, 1);
  s.u[5] = Vec3d{1e-7, 0, 0};
  const int32_t good[] = {5, 7};
  ASSERT_TRUE(set_prescribed_vertices(m, s, good).ok());
  EXPECT_EQ(s.vertex_constraint[5], kVertexPrescribed);
  EXPECT_EQ(s.prescribed_displacement[0].x, 1e-7);  // starts where the vertex is
  const auto* data = s.prescribed_vertices.data();

  const int32_t fixed[] = {1};
  Status st = set_prescribed_vertices(m, s, fixed);
  ASSERT_FALSE(st.ok());
  EXPECT_NE(st.error().message.find("fixed vertex"), std::string::npos);
  EXPECT_EQ(s.vertex_constraint[5], kVertexPrescribed);  // an error leaves the state unchanged
  const int32_t out_of_range[] = {3, 1000};
  EXPECT_NE(set_prescribed_vertices(m, s, out_of_range).error().message.find("out of range"),
            std::string::npos);
  const int32_t twice[] = {3, 4, 3};
  EXPECT_NE(set_prescribed_vertices(m, s, twice).error().message.find("twice"),
            std::string::npos);
  EXPECT_TRUE(s.prescribed_vertices.empty());
  for (size_t v = 0; v < m.vertex_count(); ++v) EXPECT_NE(s.vertex_constraint[v], kVertexPrescribed);

  const int32_t other[] = {8};
  ASSERT_TRUE(set_prescribed_vertices(m, s, other).ok());
  EXPECT_EQ(s.prescribed_vertices.data(), data);  // no reallocation
  EXPECT_EQ(s.vertex_constraint[5], kVertexFree);
}

TEST(State, ResetAndSetDisplacement) {
  const Model m = small_model();
  State s = make_state(m, 1);
  std::vector<Vec3d> u(m.vertex_count(), Vec3d{1e-8, 0, 0});
  set_displacement(s, u);
  EXPECT_EQ(s.u[3].x, 1e-8);
  EXPECT_EQ(s.u_prev[3].x, 1e-8);
  s.time = 1;
  reset_state(s);
  EXPECT_EQ(s.u[3].x, 0.0);
  EXPECT_EQ(s.time, 0.0);
  EXPECT_FALSE(s.energy_budget_valid);
}

}  // namespace
}  // namespace zona
