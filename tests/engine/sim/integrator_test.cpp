// Explicit dynamics: energy conservation below the critical step and detected blow-up above
// it, refusal, health flags, boundary conditions, dynamic relaxation and mass-scaling
// independence, determinism across thread counts, the inversion remedy, and the float32
// displacement experiment behind the precision choice (docs/physics.md).
#include "engine/sim/integrator.h"

#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <cstring>
#include <vector>

#include "engine/fem/forces_cpu.h"
#include "tests/engine/physics_test_meshes.h"

namespace zona {
namespace {

using testing::box_mesh;
using testing::vertices_where;

constexpr double kL = 10e-6;

Model build(const Mesh& mesh, const ModelDesc& d) {
  Result<Model> m = build_model(mesh, d);
  EXPECT_TRUE(m.ok()) << (m.ok() ? "" : m.error().message);
  return std::move(m).value();
}

// A smooth initial displacement with strains of order `strain`, at rest (zero velocity).
void set_wavy(const Mesh& mesh, State& s, double strain) {
  std::vector<Vec3d> u(mesh.vertex_count());
  for (size_t v = 0; v < u.size(); ++v) {
    const Vec3d x = mesh.rest_positions[v] / kL;
    u[v] = strain * kL * Vec3d{std::sin(3 * x.y) * x.x, x.y * x.z - 0.5 * x.x, std::cos(2 * x.x) * x.z};
  }
  set_displacement(s, u);
}

// Runs `steps` steps; returns the OR of the statuses and the energy range seen.
struct RunSummary {
  StepStatus status = 0;
  int64_t first_blowup = -1;
  double e_min = 1e300, e_max = -1e300;
};
RunSummary run_steps(const Model& m, State& s, int64_t steps) {
  RunSummary r;
  for (int64_t i = 0; i < steps; ++i) {
    const StepStatus st = step(m, s);
    r.status |= st;
    if ((st & kStepEnergyBlowUp) && r.first_blowup < 0) r.first_blowup = i;
    if (st & (kStepNonFinite | kStepEnergyBlowUp)) break;
    const double e = s.diag.kinetic_energy + s.diag.elastic_energy;
    r.e_min = std::min(r.e_min, e);
    r.e_max = std::max(r.e_max, e);
  }
  return r;
}

// Relative spread (max - min) / max of kinetic + elastic energy over `steps` undamped steps
// of a free block released from a 1 % strain field, at dt = fraction x the automatic step.
double energy_spread(double fraction, int64_t steps, StepStatus* status) {
  const Mesh mesh = box_mesh({0, 0, 0}, {kL, kL, kL}, 3, 3, 3);
  ModelDesc d;
  d.dt = fraction * build(mesh, ModelDesc{}).dt;
  const Model m = build(mesh, d);
  State s = make_state(m, 1);
  set_wavy(mesh, s, 0.01);
  const RunSummary r = run_steps(m, s, steps);
  *status = r.status;
  return (r.e_max - r.e_min) / r.e_max;
}

TEST(Integrator, UndampedEnergyIsConservedBelowTheCriticalStep) {
  StepStatus status_full, status_quarter;
  // At the automatic step (0.9 x the element bound, ~0.6 x the exact limit): bounded, no drift.
  const double full = energy_spread(1.0, 3000, &status_full);
  // A quarter of it, over the same simulated time: the spread falls like dt^2 (second order).
  const double quarter = energy_spread(0.25, 12000, &status_quarter);
  EXPECT_EQ(status_full, kStepOk);
  EXPECT_EQ(status_quarter, kStepOk);
  EXPECT_LT(full, 0.15);
  EXPECT_LT(quarter, full / 8);
  RecordProperty("energy_spread", std::to_string(full) + " at dt_auto, " +
                                      std::to_string(quarter) + " at dt_auto / 4");
}

// Stability sits exactly at dt = 2 / omega_max: slightly below it runs, slightly above it
// blows up, and the blow-up is flagged before anything becomes non-finite.
TEST(Integrator, BlowUpAboveTheExactLimitIsDetected) {
  const Mesh mesh = box_mesh({0, 0, 0}, {kL, kL, kL}, 3, 3, 3);
  const Model reference = build(mesh, ModelDesc{});
  const double exact = 2.0 / estimate_max_frequency(reference, 3000);
  ModelDesc d;
  d.unsafe_allow_dt_above_critical = true;  // above the bound on purpose
  d.dt = 0.97 * exact;
  const Model below = build(mesh, d);
  State s = make_state(below, 1);
  set_wavy(mesh, s, 0.001);
  RunSummary r = run_steps(below, s, 3000);
  EXPECT_EQ(r.status & (kStepEnergyBlowUp | kStepNonFinite), 0u);
  EXPECT_TRUE(r.status & kStepDtAboveCritical);  // the override is reported on every step

  d.dt = 1.03 * exact;
  const Model above = build(mesh, d);
  State s2 = make_state(above, 1);
  set_wavy(mesh, s2, 0.001);
  r = run_steps(above, s2, 3000);
  EXPECT_TRUE(r.status & kStepEnergyBlowUp) << describe_step_status(r.status, above, s2);
  EXPECT_FALSE(r.status & kStepNonFinite);
  EXPECT_GT(r.first_blowup, 0);
  RecordProperty("blowup_step_at_1.03x", std::to_string(r.first_blowup));
}

TEST(Integrator, StepAboveTheCriticalStepIsRefused) {
  const Mesh mesh = box_mesh({0, 0, 0}, {kL, kL, kL}, 2, 2, 2);
  Model m = build(mesh, ModelDesc{});
  m.dt = 1.5 * m.dt_critical;  // a model edited by hand behind build_model's back
  State s = make_state(m, 1);
  set_wavy(mesh, s, 0.01);
  const std::vector<Vec3d> before = s.u;
  const StepStatus st = step(m, s);
  EXPECT_EQ(st, uint32_t{kStepDtAboveCritical});
  EXPECT_EQ(std::memcmp(before.data(), s.u.data(), before.size() * sizeof(Vec3d)), 0);
  EXPECT_EQ(s.step_count, 0);
  EXPECT_NE(describe_step_status(st, m, s).find("step refused"), std::string::npos);
  const AdvanceResult a = advance(m, s, 10 * m.dt);
  EXPECT_EQ(a.steps, 0);
}

TEST(Integrator, NonFiniteUpdateLeavesTheStateUnchanged) {
  const Mesh mesh = box_mesh({0, 0, 0}, {kL, kL, kL}, 2, 2, 2);
  const Model m = build(mesh, ModelDesc{});
  State s = make_state(m, 2);
  set_wavy(mesh, s, 0.01);
  ASSERT_EQ(step(m, s) & kStepNonFinite, 0u);
  const std::vector<Vec3d> u = s.u, up = s.u_prev;
  s.external_force[7] = Vec3d{std::nan(""), 0, 0};
  const StepStatus st = step(m, s);
  EXPECT_TRUE(st & kStepNonFinite);
  EXPECT_EQ(s.diag.first_nonfinite, 7);
  EXPECT_EQ(std::memcmp(u.data(), s.u.data(), u.size() * sizeof(Vec3d)), 0);
  EXPECT_EQ(std::memcmp(up.data(), s.u_prev.data(), up.size() * sizeof(Vec3d)), 0);
  EXPECT_EQ(s.step_count, 1);
  EXPECT_NE(describe_step_status(st, m, s).find("vertex 7"), std::string::npos);
}

TEST(Integrator, AdvanceSubStepsAFrame) {
  const Mesh mesh = box_mesh({0, 0, 0}, {kL, kL, kL}, 2, 2, 2);
  const Model m = build(mesh, ModelDesc{});
  State s = make_state(m, 1);
  const AdvanceResult a = advance(m, s, 10 * m.dt);
  EXPECT_EQ(a.steps, 10);
  const AdvanceResult b = advance(m, s, 10.5 * m.dt);
  EXPECT_EQ(b.steps, 11);
  EXPECT_GE(b.time_advanced, 10.5 * m.dt);
  EXPECT_EQ(s.step_count, 21);
}

// Indentation of a block: bottom fixed, a patch of the top pushed down by `depth`; returns the
// force the patch applies (z) once relaxed.
struct Indentation {
  Mesh mesh = box_mesh({0, 0, 0}, {kL, kL, 0.5 * kL}, 4, 4, 2);
  std::vector<int32_t> bottom = vertices_where(mesh, 2, 0.0, 1e-9 * kL);
  std::vector<int32_t> patch;
  Indentation() {
    for (int32_t v : vertices_where(mesh, 2, 0.5 * kL, 1e-9 * kL)) {
      const Vec3d x = mesh.rest_positions[v];
      if (std::abs(x.x - 0.5 * kL) < 0.3 * kL && std::abs(x.y - 0.5 * kL) < 0.3 * kL)
        patch.push_back(v);
    }
  }
  ModelDesc desc() const {
    ModelDesc d;
    d.fixed_vertices = bottom;
    return d;
  }
  RelaxResult relax(const Model& m, State& s, double depth) const {
    EXPECT_TRUE(set_prescribed_vertices(m, s, patch).ok());
    for (Vec3d& t : s.prescribed_displacement) t = Vec3d{0, 0, -depth};
    RelaxOptions o;
    o.relative_tolerance = 1e-9;
    return relax_to_equilibrium(m, s, o);
  }
};

TEST(Integrator, DynamicRelaxationAnswerDoesNotDependOnMassScaling) {
  const Indentation ind;
  const double depth = 0.05 * kL;  // 10 % of the block height: SVK is non-linear here
  double reference = 0;
  std::string report;
  for (double scaling : {1.0, 100.0, 1e4}) {
    ModelDesc d = ind.desc();
    d.mass_scaling = scaling;
    const Model m = build(ind.mesh, d);
    State s = make_state(m, 1);
    const RelaxResult r = ind.relax(m, s, depth);
    ASSERT_TRUE(r.converged) << "scaling " << scaling << ": residual " << r.residual_norm;
    EXPECT_EQ(r.status & (kStepNonFinite | kStepEnergyBlowUp), 0u);
    const double fz = s.diag.constraint_force.z;
    EXPECT_LT(fz, 0);  // pushing down
    if (scaling == 1.0) reference = fz;
    EXPECT_NEAR(fz, reference, 1e-6 * std::abs(reference)) << "scaling " << scaling;
    report += std::to_string(static_cast<long long>(scaling)) + ": " +
              std::to_string(r.steps) + " steps; ";
  }
  // Kinetic damping reaches the same answer (more slowly).
  {
    const Model m = build(ind.mesh, ind.desc());
    State s = make_state(m, 1);
    ASSERT_TRUE(set_prescribed_vertices(m, s, ind.patch).ok());
    for (Vec3d& t : s.prescribed_displacement) t = Vec3d{0, 0, -depth};
    RelaxOptions o;
    o.method = RelaxMethod::kKineticDamping;
    o.relative_tolerance = 1e-5;
    const RelaxResult r = relax_to_equilibrium(m, s, o);
    ASSERT_TRUE(r.converged);
    EXPECT_GT(r.kinetic_resets, 0);
    EXPECT_NEAR(s.diag.constraint_force.z, reference, 1e-4 * std::abs(reference));
    report += "kinetic damping (1e-5): " + std::to_string(r.steps) + " steps";
  }
  // The seed's uniform vertex mass instead of densities: same static answer.
  ModelDesc d = ind.desc();
  d.vertex_mass = 7.995e-12;
  const Model m = build(ind.mesh, d);
  State s = make_state(m, 1);
  ASSERT_TRUE(ind.relax(m, s, depth).converged);
  EXPECT_NEAR(s.diag.constraint_force.z, reference, 1e-6 * std::abs(reference));
  RecordProperty("relaxation_steps_by_scaling", report);
}

// The same static answer reached by plain damped dynamics (slow ramp, then hold): with 100x
// mass scaling the step is 10x larger and the run 10x shorter in steps, the answer the same.
TEST(Integrator, DampedQuasiStaticAnswerDoesNotDependOnMassScaling) {
  const Indentation ind;
  const double depth = 0.02 * kL;
  ModelDesc d0 = ind.desc();
  const Model m0 = build(ind.mesh, d0);
  State s0 = make_state(m0, 1);
  ASSERT_TRUE(ind.relax(m0, s0, depth).converged);
  const double reference = s0.diag.constraint_force.z;
  const double omega1 = 1.0 / (0.5 * kL) * std::sqrt(m0.material_lame[0].mu / 1000.0);
  for (double scaling : {1.0, 100.0}) {
    ModelDesc d = ind.desc();
    d.mass_scaling = scaling;
    d.material.damping = 2.0 * omega1 / std::sqrt(scaling);  // about critical for mode 1
    const Model m = build(ind.mesh, d);
    State s = make_state(m, 1);
    ASSERT_TRUE(set_prescribed_vertices(m, s, ind.patch).ok());
    const double t_ramp = 20.0 / omega1 * std::sqrt(scaling);
    const int64_t ramp_steps = static_cast<int64_t>(t_ramp / m.dt);
    StepStatus all = 0;
    for (int64_t i = 0; i < 3 * ramp_steps; ++i) {
      const double f = std::min(1.0, static_cast<double>(i + 1) / static_cast<double>(ramp_steps));
      for (Vec3d& t : s.prescribed_displacement) t = Vec3d{0, 0, -depth * f};
      all |= step(m, s);
    }
    EXPECT_EQ(all & (kStepNonFinite | kStepEnergyBlowUp), 0u);
    EXPECT_NEAR(s.diag.constraint_force.z, reference, 2e-3 * std::abs(reference))
        << "scaling " << scaling << " after " << 3 * ramp_steps << " steps";
  }
}

TEST(Integrator, FixedAndPrescribedVerticesAndTheReactionForce) {
  const Indentation ind;
  const Model m = build(ind.mesh, ind.desc());
  State s = make_state(m, 1);
  const RelaxResult r = ind.relax(m, s, 0.01 * kL);
  ASSERT_TRUE(r.converged);
  for (int32_t v : ind.bottom) EXPECT_EQ(norm(s.u[v]), 0.0);
  for (int32_t v : ind.patch) EXPECT_EQ(s.u[v].z, -0.01 * kL);
  // At equilibrium the patch's reaction balances the elastic forces there, and the fixed
  // bottom holds the opposite total.
  compute_elastic_forces(m, s);
  Vec3d elastic_patch{0, 0, 0}, elastic_bottom{0, 0, 0};
  for (int32_t v : ind.patch) elastic_patch += s.force[v];
  for (int32_t v : ind.bottom) elastic_bottom += s.force[v];
  const double scale = std::abs(elastic_patch.z);
  EXPECT_NEAR(elastic_bottom.z, -elastic_patch.z, 1e-6 * scale);
  // The constraint force of the last step is minus the elastic force on the patch.
  step(m, s);
  EXPECT_NEAR(s.diag.constraint_force.z, -elastic_patch.z, 1e-6 * scale);
}

TEST(Integrator, TrajectoriesAreBitwiseIdenticalForAnyThreadCount) {
  const Mesh mesh = box_mesh({0, 0, 0}, {kL, kL, kL}, 5, 4, 4);
  ModelDesc d;
  d.fixed_vertices = vertices_where(mesh, 2, 0.0, 1e-9 * kL);
  d.material.damping = 1e5;
  const Model m = build(mesh, d);
  const std::vector<int32_t> top = vertices_where(mesh, 2, kL, 1e-9 * kL);
  std::vector<std::vector<Vec3d>> finals;
  std::vector<double> energies;
  for (int threads : {1, 2, 3}) {
    State s = make_state(m, threads);
    // The plan is the mesh's, whatever the thread count: two segments with late slots, so the
    // vertex forces are partial sums that one thread and several must form alike.
    EXPECT_EQ(s.assembly.segment_count(), 2);
    EXPECT_GT(s.assembly.late_count(), 0);
    set_wavy(mesh, s, 0.02);
    ASSERT_TRUE(set_prescribed_vertices(m, s, std::span(top).subspan(0, 5)).ok());
    for (size_t v = 0; v < mesh.vertex_count(); v += 7) s.external_force[v] = Vec3d{1e-9, 0, -2e-9};
    for (int i = 0; i < 60; ++i) {
      for (Vec3d& t : s.prescribed_displacement) t = t + Vec3d{0, 0, -1e-10};
      ASSERT_EQ(step(m, s) & kStepNotAdvanced, 0u);
    }
    finals.push_back(s.u);
    energies.push_back(s.diag.kinetic_energy + s.diag.elastic_energy + s.diag.constraint_force.z);
  }
  for (size_t i = 1; i < finals.size(); ++i) {
    EXPECT_EQ(std::memcmp(finals[0].data(), finals[i].data(), finals[0].size() * sizeof(Vec3d)),
              0);
    EXPECT_EQ(std::memcmp(&energies[0], &energies[i], sizeof(double)), 0);
  }
}

// The vertex pass updates four vertices per pack (and a padded last group): its displacements
// equal a vertex-by-vertex Vec3d update bit for bit, for free, fixed and prescribed vertices,
// with 16 and 32 vector registers; its sums (kinetic energy, residual) match the direct sums.
TEST(Integrator, VertexPassEqualsAVertexByVertexUpdate) {
  const Mesh mesh = box_mesh({0, 0, 0}, {kL, kL, kL}, 5, 4, 4);  // 150 vertices: 64 + 64 + 22
  ASSERT_NE(mesh.vertex_count() % 4, 0u);
  ModelDesc d;
  d.fixed_vertices = vertices_where(mesh, 2, 0.0, 1e-9 * kL);
  d.material.damping = 1e5;
  const Model m = build(mesh, d);
  const std::vector<int32_t> top = vertices_where(mesh, 2, kL, 1e-9 * kL);
  for (int registers : {16, 32}) {
    set_cpu_simd_registers(registers);
    SCOPED_TRACE(::testing::Message() << "registers " << cpu_simd_registers());
    auto prepare = [&](State& st) {
      set_wavy(mesh, st, 0.02);
      for (size_t v = 0; v < mesh.vertex_count(); ++v)  // a velocity: u_{n-1} != u_n
        if (!m.vertex_fixed[v]) st.u_prev[v] = 0.999 * st.u[v] + Vec3d{1e-12, -2e-12, 3e-12};
      ASSERT_TRUE(set_prescribed_vertices(m, st, std::span(top).subspan(0, 5)).ok());
      for (Vec3d& t : st.prescribed_displacement) t = t + Vec3d{0, 0, -1e-10};
      for (size_t v = 0; v < mesh.vertex_count(); v += 3)
        st.external_force[v] = Vec3d{1e-9, 0, -2e-9};
    };
    State s = make_state(m, 2), ref = make_state(m, 1);
    prepare(s);
    prepare(ref);
    compute_elastic_forces(m, ref);
    ASSERT_EQ(step(m, s) & kStepNotAdvanced, 0u);
    double kinetic = 0, residual_sq = 0;
    for (size_t v = 0; v < mesh.vertex_count(); ++v) {
      Vec3d next = ref.u[v];
      if (ref.vertex_constraint[v] == kVertexFree) {
        const VertexCoefficients& k = m.vertex_coefficients[v];
        const Vec3d total = ref.force[v] + ref.external_force[v];
        next = k.a * ref.u[v] - k.b * ref.u_prev[v] + k.c * total;
        const Vec3d vel = (0.5 / m.dt) * (next - ref.u_prev[v]);
        kinetic += 0.5 * m.vertex_mass[v] * dot(vel, vel);
        residual_sq += dot(total, total);
      } else if (ref.vertex_constraint[v] == kVertexFixed) {
        next = Vec3d{0, 0, 0};
      } else {
        continue;  // prescribed: its target, checked below
      }
      EXPECT_EQ(std::memcmp(&next, &s.u[v], sizeof(Vec3d)), 0) << "vertex " << v;
      EXPECT_EQ(std::memcmp(&ref.force[v], &s.force[v], sizeof(Vec3d)), 0) << "vertex " << v;
    }
    for (size_t i = 0; i < s.prescribed_vertices.size(); ++i)
      EXPECT_EQ(std::memcmp(&s.u[static_cast<size_t>(s.prescribed_vertices[i])],
                            &s.prescribed_displacement[i], sizeof(Vec3d)),
                0);
    // The sums add in another order (per lane): equal to rounding. Prescribed vertices add
    // their kinetic energy in stage 3.
    EXPECT_GT(s.diag.kinetic_energy, kinetic);
    EXPECT_NEAR(s.diag.residual_norm, std::sqrt(residual_sq), 1e-13 * std::sqrt(residual_sq));
    EXPECT_GT(residual_sq, 0);
  }
  set_cpu_simd_registers(32);
}

// One tetrahedron with its base fixed and its apex pushed through the base, released with
// damping for 20000 steps.
struct InvertedTetRun {
  Model model;
  State state;
  RunSummary run;
};
InvertedTetRun run_inverted_tet(InversionHandling handling) {
  Mesh mesh;
  mesh.rest_positions = {{0, 0, 0}, {1e-6, 0, 0}, {0, 1e-6, 0}, {0, 0, 1e-6}};
  mesh.tets = {Tet{0, 1, 2, 3}};
  mesh.tet_region = {0};
  ModelDesc d;
  d.fixed_vertices = {0, 1, 2};
  d.inversion = handling;
  d.material.damping = 2e6;
  InvertedTetRun out{build(mesh, d), State{}, RunSummary{}};
  out.state = make_state(out.model, 1);
  std::vector<Vec3d> u(4, Vec3d{0, 0, 0});
  u[3] = Vec3d{0.1e-6, 0.1e-6, -1.6e-6};  // apex 0.6 um below the base
  set_displacement(out.state, u);
  out.run = run_steps(out.model, out.state, 20000);
  return out;
}

TEST(Integrator, PlainSvkStaysInvertedAndSaysSo) {
  const InvertedTetRun r = run_inverted_tet(InversionHandling::kReport);
  EXPECT_TRUE(r.run.status & kStepInvertedElement);
  EXPECT_EQ(r.state.diag.first_inverted, 0);
  // Plain SVK has an equilibrium at the mirror image (E = 0 there): it settles inverted.
  EXPECT_LT(r.state.u[3].z, -1e-6);
  EXPECT_NE(describe_step_status(kStepInvertedElement, r.model, r.state).find("inverted"),
            std::string::npos);
}

TEST(Integrator, ClampedSvkRecoversFromInversion) {
  const InvertedTetRun r = run_inverted_tet(InversionHandling::kClampStretch);
  EXPECT_TRUE(r.run.status & kStepClampedElement);
  EXPECT_FALSE(r.run.status & (kStepNonFinite | kStepEnergyBlowUp));
  // Back at rest, positively oriented, no longer flagged.
  EXPECT_LT(norm(r.state.u[3]), 1e-9);
  EXPECT_EQ(r.state.diag.inverted_count, 0);
  EXPECT_EQ(r.state.diag.clamped_count, 0);
}

// Precision experiment (docs/physics.md): cell-scale block of 1 um elements (E = 17.9 kPa,
// nu = 0.49, dt ~2e-8 s), sitting `offset` from its rest place, its top pushed down at
// `speed`, integrated with the displacement STORED in float32 versus float64 (forces and
// updates in float64 in both), and with float64 storage but float32 element forces (edges
// formed in float64). Light mass-proportional damping, as in a quasi-static run.
struct PrecisionResult {
  double motion = 0;        // probe displacement over the run [m]
  double velocity = 0;      // probe velocity over the last step [m/s]
  double stalled = 0;       // fraction of steps in which the probe's stored value did not change
};

template <class Store, class ForceT>
PrecisionResult precision_run(const Model& m, const std::vector<int32_t>& top,
                              const std::vector<int32_t>& bottom, Vec3d offset, double speed,
                              int steps, size_t probe) {
  const size_t nv = m.vertex_count();
  std::vector<Vec3<Store>> u(nv, vec_cast<Store>(offset)), up(u);
  std::vector<uint8_t> held(nv, 0);
  for (int32_t v : top) held[v] = 1;
  for (int32_t v : bottom) held[v] = 2;
  std::vector<Vec3d> f(nv);
  int stalled = 0;
  for (int n = 0; n < steps; ++n) {
    std::fill(f.begin(), f.end(), Vec3d{0, 0, 0});
    for (size_t t = 0; t < m.tet_count(); ++t) {
      const Tet& e = m.tets[t];
      Vec3d ue[4];
      for (int c = 0; c < 4; ++c) ue[c] = vec_cast<double>(u[e[c]]);
      const Vec3<ForceT> du[3] = {vec_cast<ForceT>(ue[1] - ue[0]), vec_cast<ForceT>(ue[2] - ue[0]),
                                  vec_cast<ForceT>(ue[3] - ue[0])};
      const TetShape<ForceT> shape = tet_shape_cast<ForceT>(m.tet_shape[t]);
      Mat3<ForceT> p;
      svk_first_piola(tet_displacement_gradient_from_edges(shape, du),
                      static_cast<ForceT>(m.tet_lame(t).lambda),
                      static_cast<ForceT>(m.tet_lame(t).mu), &p);
      Vec3<ForceT> fe[4];
      tet_forces_from_stress(shape, p, fe);
      for (int c = 0; c < 4; ++c) f[e[c]] += vec_cast<double>(fe[c]);
    }
    const double t_next = (n + 1) * m.dt;
    for (size_t v = 0; v < nv; ++v) {
      Vec3d next;
      if (held[v] == 1)
        next = offset + Vec3d{0, 0, -speed * t_next};
      else if (held[v] == 2)
        next = offset;
      else {
        const VertexCoefficients& k = m.vertex_coefficients[v];
        next = k.a * vec_cast<double>(u[v]) - k.b * vec_cast<double>(up[v]) + k.c * f[v];
      }
      up[v] = u[v];
      u[v] = vec_cast<Store>(next);
      if (v == probe && u[v].z == up[v].z) ++stalled;
    }
  }
  PrecisionResult r;
  r.motion = static_cast<double>(u[probe].z) - offset.z;
  r.velocity = (static_cast<double>(u[probe].z) - static_cast<double>(up[probe].z)) / m.dt;
  r.stalled = static_cast<double>(stalled) / steps;
  return r;
}

TEST(Integrator, Float32DisplacementStallsAtCellScale) {
  const double h = 1e-6;
  const Mesh mesh = box_mesh({0, 0, 0}, {3 * h, 3 * h, 3 * h}, 3, 3, 3);
  ModelDesc d;  // E 17.9 kPa, nu 0.49, rho 1000
  d.material.damping = 1e6;  // [1/s]: about critical for the block's first modes
  const Model m = build(mesh, d);
  const auto top = vertices_where(mesh, 2, 3 * h, 1e-9 * h);
  const auto bottom = vertices_where(mesh, 2, 0.0, 1e-9 * h);
  const size_t probe = 1 + 4 * (1 + 4 * 2);  // vertex (1, 1, 2): interior, below the top
  const int steps = 1500;
  struct Case {
    double offset_z;  // how far the block sits from its rest place [m]
    double speed;     // top speed [m/s]
    PrecisionResult ref, store32, force32;
  };
  Case cases[] = {{40e-6, 5e-5, {}, {}, {}}, {20e-6, 1e-3, {}, {}, {}}, {0.0, 5e-5, {}, {}, {}}};
  std::string report;
  for (Case& c : cases) {
    const Vec3d offset{0, 0, c.offset_z};
    c.ref = precision_run<double, double>(m, top, bottom, offset, c.speed, steps, probe);
    c.store32 = precision_run<float, double>(m, top, bottom, offset, c.speed, steps, probe);
    c.force32 = precision_run<double, float>(m, top, bottom, offset, c.speed, steps, probe);
    EXPECT_LT(c.ref.motion, 0);  // the probe moved down with the top
    char text[400];
    std::snprintf(
        text, sizeof text,
        "[offset %.0f um, %.2f mm/s, %.3g m per step] float64: motion %.4g m, velocity %.4g "
        "m/s; float32 u: motion error %.2g, velocity %.4g m/s, stalled %.0f%% of steps; float32 "
        "forces: motion error %.2g, velocity error %.2g. ",
        c.offset_z * 1e6, c.speed * 1e3, c.speed * m.dt, c.ref.motion, c.ref.velocity,
        std::abs(c.store32.motion / c.ref.motion - 1), c.store32.velocity,
        100 * c.store32.stalled, std::abs(c.force32.motion / c.ref.motion - 1),
        std::abs(c.force32.velocity / c.ref.velocity - 1));
    report += text;
  }
  RecordProperty("precision_experiment", report);
  // 40 um from rest (a deeply indented oocyte), 0.05 mm/s: with float32 storage the probe's
  // value stays put in most steps, and its velocity (what damping and kinetic energy see) is
  // lost: it reads zero or a multiple of ulp / dt.
  EXPECT_GT(cases[0].store32.stalled, 0.3);
  EXPECT_GT(std::abs(cases[0].store32.velocity - cases[0].ref.velocity),
            0.5 * std::abs(cases[0].ref.velocity));
  // float64 storage never stalls.
  EXPECT_LT(cases[0].ref.stalled, 0.01);
  // float32 forces over float64 displacements (edges formed in float64): fine everywhere.
  for (const Case& c : cases) EXPECT_LT(std::abs(c.force32.motion / c.ref.motion - 1), 1e-4);
}

}  // namespace
}  // namespace zona
