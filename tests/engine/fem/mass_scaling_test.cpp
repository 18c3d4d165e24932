// Tests for engine/mass_scaling: selective scaling reaches the target step, scales small
// elements most, keeps damping rates, and leaves the static answer unchanged.
#include "engine/fem/mass_scaling.h"

#include <gtest/gtest.h>

#include <cmath>
#include <cstring>
#include <numeric>

#include "engine/sim/integrator.h"
#include "engine/mesh/mesh_generate.h"
#include "engine/fem/state.h"

namespace zona {
namespace {

Mesh graded_ball() {
  CellMeshSpec spec;
  spec.diameter = 56e-6;
  spec.edge_length = 10e-6;
  spec.refine_edge_length = 2.5e-6;
  spec.refine_radius = 6e-6;
  spec.refine_at = Vec3d{-28e-6, 0, 0};
  Result<Mesh> mesh = generate_cell_mesh(spec);
  EXPECT_TRUE(mesh.ok());
  return *mesh;
}

TEST(MassScaling, TotalMassPredictionMatchesTheScaling) {
  // selective_scaling_total_mass (the derived step's bisection) predicts, without changing the
  // model, the total mass apply_selective_mass_scaling then gives; it grows with the step.
  const Mesh mesh = graded_ball();
  ModelDesc desc;
  Result<Model> m = build_model(mesh, desc);
  ASSERT_TRUE(m.ok());
  std::vector<double> need;
  const double small = selective_scaling_total_mass(*m, 1e-6, desc.dt_safety, &need);
  const double predicted = selective_scaling_total_mass(*m, 2e-6, desc.dt_safety, &need);
  EXPECT_GT(predicted, small);
  Result<SelectiveScalingReport> r = apply_selective_mass_scaling(*m, 2e-6, desc.dt_safety);
  ASSERT_TRUE(r.ok()) << r.error().message;
  EXPECT_NEAR(predicted, r->mass_after, 1e-9 * r->mass_after);
}

TEST(MassScaling, ModelAndScalingAreTheSameForAnyThreadCount) {
  // build_model's per-element work and the scaling's element measures run in ranges side by
  // side (engine/core/parallel.h): every number equals the serial one's, bit for bit.
  const Mesh mesh = graded_ball();
  ASSERT_GT(mesh.tet_count(), 2 * 4096u);  // two ranges at least
  ModelDesc desc;
  desc.constitutive = ConstitutiveModel::kStableNeoHookean;
  desc.nodal_pressure = true;
  std::vector<Model> models;
  for (int threads : {1, 4}) {
    desc.precompute_threads = threads;
    Result<Model> m = build_model(mesh, desc);
    ASSERT_TRUE(m.ok()) << m.error().message;
    std::vector<double> need;
    const double predicted = selective_scaling_total_mass(*m, 2e-6, desc.dt_safety, &need, threads);
    ASSERT_TRUE(apply_selective_mass_scaling(*m, 2e-6, desc.dt_safety, threads).ok());
    const double total = std::accumulate(m->vertex_mass.begin(), m->vertex_mass.end(), 0.0);
    EXPECT_NEAR(predicted, total, 1e-9 * total);
    models.push_back(std::move(*m));
  }
  const Model& a = models[0];
  const Model& b = models[1];
  EXPECT_EQ(a.dt, b.dt);
  EXPECT_EQ(a.dt_altitude_estimate, b.dt_altitude_estimate);
  EXPECT_EQ(a.min_altitude, b.min_altitude);
  EXPECT_EQ(a.max_wave_speed, b.max_wave_speed);
  EXPECT_EQ(a.vertex_mass, b.vertex_mass);
  EXPECT_EQ(a.cpu_tet_batches, b.cpu_tet_batches);
  ASSERT_EQ(a.tet_shape.size(), b.tet_shape.size());
  EXPECT_EQ(std::memcmp(a.tet_shape.data(), b.tet_shape.data(),
                        a.tet_shape.size() * sizeof(a.tet_shape[0])),
            0);
}

TEST(MassScaling, SelectiveScalingReachesTheTargetWithLessMass) {
  const Mesh mesh = graded_ball();
  ModelDesc desc;
  desc.material.damping = 100;
  const double target = 2e-6;
  // Uniform scaling to the same step, for comparison.
  ModelDesc uniform = desc;
  uniform.target_dt = target;
  Result<Model> u = build_model(mesh, uniform);
  ASSERT_TRUE(u.ok());
  Result<Model> m = build_model(mesh, desc);
  ASSERT_TRUE(m.ok());
  const double dt0 = m->dt;
  Result<SelectiveScalingReport> r = apply_selective_mass_scaling(*m, target, desc.dt_safety);
  ASSERT_TRUE(r.ok()) << r.error().message;
  EXPECT_GE(m->dt, target * (1 - 1e-12));
  EXPECT_NEAR(m->dt, desc.dt_safety * m->dt_critical, 1e-18);
  EXPECT_GT(m->dt, dt0);
  // Less total mass than uniform scaling needs, and the factor is reported.
  EXPECT_LT(r->mass_after, u->mass_scaling * r->mass_before);
  EXPECT_NEAR(m->mass_scaling, r->mass_after / r->mass_before, 1e-12);
  EXPECT_GT(r->max_vertex_factor, m->mass_scaling);  // the small elements took the most
  // Damping rate gamma / M per vertex unchanged; coefficients consistent with the new step.
  for (size_t v = 0; v < m->vertex_count(); ++v) {
    EXPECT_NEAR(m->vertex_damping[v] / m->vertex_mass[v], 100.0, 1e-9);
    const double denom = m->vertex_mass[v] + 0.5 * m->vertex_damping[v] * m->dt;
    EXPECT_NEAR(m->vertex_coefficients[v].c, m->dt * m->dt / denom, 1e-12 * m->vertex_coefficients[v].c);
  }
  // A step at the new dt is not refused and stays finite.
  State s = make_state(*m, 1);
  for (size_t v = 0; v < m->vertex_count(); ++v) s.u[v] = s.u_prev[v] = Vec3d{1e-9 * static_cast<double>(v % 7), 0, 0};
  for (int i = 0; i < 200; ++i) EXPECT_FALSE(step(*m, s) & (kStepNonFinite | kStepDtAboveCritical));
}

TEST(MassScaling, StaticAnswerDoesNotDependOnIt) {
  // Dynamic relaxation of a loaded ball: masses only change the path, not the equilibrium.
  const Mesh mesh = graded_ball();
  ModelDesc desc;
  desc.constitutive = ConstitutiveModel::kLinear;
  // Fix every vertex with x > 20 um and pull those with x < -20 um.
  for (size_t v = 0; v < mesh.vertex_count(); ++v)
    if (mesh.rest_positions[v].x > 20e-6) desc.fixed_vertices.push_back(static_cast<int32_t>(v));
  std::vector<Vec3d> answers[2];
  for (int k = 0; k < 2; ++k) {
    Result<Model> m = build_model(mesh, desc);
    ASSERT_TRUE(m.ok());
    if (k == 1) {
      ASSERT_TRUE(apply_selective_mass_scaling(*m, 1e-6, 0.9).ok());
    }
    State s = make_state(*m, 1);
    std::vector<int32_t> pulled;
    for (size_t v = 0; v < m->vertex_count(); ++v)
      if (m->rest_positions[v].x < -20e-6) pulled.push_back(static_cast<int32_t>(v));
    ASSERT_TRUE(set_prescribed_vertices(*m, s, pulled).ok());
    for (Vec3d& t : s.prescribed_displacement) t = Vec3d{-0.5e-6, 0, 0};
    RelaxOptions o;
    o.relative_tolerance = 1e-8;
    const RelaxResult r = relax_to_equilibrium(*m, s, o);
    ASSERT_TRUE(r.converged);
    answers[k] = s.u;
  }
  double worst = 0, scale = 0;
  for (size_t v = 0; v < answers[0].size(); ++v) {
    worst = std::max(worst, norm(answers[0][v] - answers[1][v]));
    scale = std::max(scale, norm(answers[0][v]));
  }
  EXPECT_LT(worst, 1e-5 * scale);
}

TEST(MassScaling, BadArgumentsAreRefused) {
  Result<Model> m = build_model(generate_box_mesh(Vec3d{0, 0, 0}, Vec3d{1, 1, 1}, 1, 1, 1), ModelDesc{});
  ASSERT_TRUE(m.ok());
  EXPECT_FALSE(apply_selective_mass_scaling(*m, 0.0, 0.9).ok());
  EXPECT_FALSE(apply_selective_mass_scaling(*m, 1e-3, 1.5).ok());
}

}  // namespace
}  // namespace zona
