// Tests for engine/particle_model (Asgari et al.): spring and damping forces against hand values,
// layouts, volume and pressure under uniform scaling against the analytic values, forces as the
// energy's gradient, the stable step, determinism, bad parameters, and the model inside the
// injection simulation (volume conservation, split step, CPU backend, scene round trip).
#include "engine/particles/particle_model.h"

#include <gtest/gtest.h>

#include <cmath>
#include <nlohmann/json.hpp>

#include "engine/particles/particle_element.h"
#include "engine/sim/backend_cpu.h"
#include "engine/sim/simulation.h"
#include "tests/engine/test_scenes.h"

namespace zona {
namespace {

using json = nlohmann::json;
using test::particle_scene;
constexpr double kPi = 3.14159265358979323846;

ParticleModelDesc small_desc(ParticleLayout layout = ParticleLayout::kIcosphere, int64_t count = 642) {
  ParticleModelDesc d;
  d.radius = 400e-6;
  d.layout = layout;
  d.target_particles = count;
  d.membrane_modulus = 20.0;
  d.radial_stiffness = 1e3;
  d.radial_damping = 1e3;
  d.membrane_relaxation_time = 1e-6;
  d.damping = Vec3d{2e3, 2e3, 4e3};
  d.compressibility = 1e-6;
  d.target_dt = 10e-6;
  return d;
}

ParticleModel build(const ParticleModelDesc& d) {
  Result<ParticleModel> pm = build_particle_model(d);
  EXPECT_TRUE(pm.ok()) << (pm.ok() ? "" : pm.error().message);
  return pm.ok() ? std::move(*pm) : ParticleModel{};
}

// ---------------------------------------------------------------------------------------------
// Element functions against hand values.

TEST(ParticleElement, SpringForceHandValues) {
  // |xj - xi| = 5 um along (0.6, 0.8, 0), free length 4 um: tension k dL = 2 N/m * 1 um.
  const Vec3d xi{0, 0, 0}, xj{3e-6, 4e-6, 0}, rest{0, 0, 0};
  const Vec3d f = particle_spring_force(xi, xj, rest, rest, 4e-6, 2.0, 0.5);
  EXPECT_NEAR(f.x, 2e-6 * 0.6, 1e-18);
  EXPECT_NEAR(f.y, 2e-6 * 0.8, 1e-18);
  EXPECT_EQ(f.z, 0.0);
  // The dashpot adds c (vj - vi).r: vj = 1 mm/s along x gives 0.5 * 0.6e-3 N more tension.
  const Vec3d g = particle_spring_force(xi, xj, rest, Vec3d{1e-3, 0, 0}, 4e-6, 2.0, 0.5);
  EXPECT_NEAR(g.x, (2e-6 + 3e-4) * 0.6, 1e-15);
  EXPECT_NEAR(g.y, (2e-6 + 3e-4) * 0.8, 1e-15);
  // A compressed spring pushes i away from j; equal and opposite on j.
  const Vec3d h = particle_spring_force(xi, xj, rest, rest, 6e-6, 2.0, 0.0);
  EXPECT_NEAR(h.x, -2e-6 * 0.6, 1e-18);
  const Vec3d hj = particle_spring_force(xj, xi, rest, rest, 6e-6, 2.0, 0.0);
  EXPECT_NEAR(hj.x, -h.x, 1e-20);
  EXPECT_NEAR(particle_spring_energy(xi, xj, 4e-6, 2.0), 0.5 * 2.0 * 1e-12, 1e-24);
}

TEST(ParticleElement, DampedUpdateHandValues) {
  // (m + b dt/2) u+ = 2 m u - (m - b dt/2) u- + dt^2 f with m 1, b 2, dt 0.1: h = 0.1.
  EXPECT_NEAR(particle_update(1.0, 0.0, 0.0, 1.0, 2.0, 0.1), 2.0 / 1.1, 1e-15);
  EXPECT_NEAR(particle_update(0.0, 0.0, 3.0, 1.0, 2.0, 0.1), 0.03 / 1.1, 1e-15);
  // At rest with no force nothing moves; undamped it is the plain centred difference.
  EXPECT_EQ(particle_update(2.0, 2.0, 0.0, 1.0, 5.0, 0.1), 2.0);
  EXPECT_NEAR(particle_update(1.0, 0.5, 4.0, 2.0, 0.0, 0.1), 2.0 - 0.5 + 0.01 * 4.0 / 2.0, 1e-15);
}

TEST(ParticleElement, PressureAndEnergyOfEquationSix) {
  // beta = -(1/V) dV/dP: 1 % compression at beta 1e-6 /Pa is about 10 kPa.
  EXPECT_NEAR(hydraulic_pressure(0.99, 1.0, 1e-6), std::log(1 / 0.99) / 1e-6, 1e-6);
  EXPECT_GT(hydraulic_pressure(0.99, 1.0, 1e-6), 0.0);
  EXPECT_LT(hydraulic_pressure(1.01, 1.0, 1e-6), 0.0);
  EXPECT_EQ(hydraulic_energy(1.0, 1.0, 1e-6), 0.0);
  // dE/dV = -P.
  const double e = 1e-7;
  const double dE = (hydraulic_energy(0.99 + e, 1.0, 1e-6) - hydraulic_energy(0.99 - e, 1.0, 1e-6)) / (2 * e);
  EXPECT_NEAR(dE, -hydraulic_pressure(0.99, 1.0, 1e-6), 1e-3 * std::fabs(dE));
}

// ---------------------------------------------------------------------------------------------
// Layouts.

TEST(ParticleModel, IcosphereIsAClosedOutwardTriangulation) {
  const ParticleModel pm = build(small_desc());
  ASSERT_EQ(pm.membrane_count, 642);  // 10 n^2 + 2 at n = 8
  EXPECT_EQ(pm.particle_count(), 643u);
  // Euler: V - E + F = 2; every edge in two triangles.
  EXPECT_EQ(pm.membrane_count - static_cast<int64_t>(pm.spring_count()) +
                static_cast<int64_t>(pm.triangles.size()),
            2);
  // Volume of the inscribed polyhedron: a little below the sphere's.
  const double sphere = 4.0 / 3.0 * kPi * std::pow(400e-6, 3);
  EXPECT_LT(pm.rest_volume, sphere);
  EXPECT_GT(pm.rest_volume, 0.98 * sphere);
  EXPECT_NEAR(pm.rest_area, 4 * kPi * 400e-6 * 400e-6, 0.02 * 4 * kPi * 400e-6 * 400e-6);
  for (const Triangle& t : pm.triangles) {
    const Vec3d a = pm.rest_positions[size_t(t[0])], b = pm.rest_positions[size_t(t[1])],
                c = pm.rest_positions[size_t(t[2])];
    ASSERT_GT(dot(triangle_area_vector(a, b, c), a + b + c), 0.0);
  }
  // 5 or 6 neighbours each; spacing within a factor 1.5 (geodesic subdivision).
  for (int i = 0; i < pm.membrane_count; ++i) {
    const int deg = pm.neighbor_offsets[size_t(i) + 1] - pm.neighbor_offsets[size_t(i)];
    ASSERT_TRUE(deg == 5 || deg == 6) << i;
  }
  EXPECT_LT(pm.max_spring_length / pm.min_spring_length, 1.5);
}

TEST(ParticleModel, LatLongHasFourNeighboursAndCrowdedPoles) {
  ParticleModelDesc d = small_desc(ParticleLayout::kLatLong, 642);
  d.pole_axis = Vec3d{0, 1, 0};
  const ParticleModel pm = build(d);
  // n_lat rings of 2 (n_lat + 1): 2 n (n + 1) + 2 = 614 at n = 17 (the nearest to 642).
  ASSERT_EQ(pm.membrane_count, 614);
  int poles = 0;
  for (int i = 0; i < pm.membrane_count; ++i) {
    const int deg = pm.neighbor_offsets[size_t(i) + 1] - pm.neighbor_offsets[size_t(i)];
    if (deg == 36) {
      ++poles;
      EXPECT_NEAR(std::fabs(pm.rest_positions[size_t(i)].y), 400e-6, 1e-12);
    } else {
      ASSERT_EQ(deg, 4) << i;
    }
  }
  EXPECT_EQ(poles, 2);
  // Near the poles the ring springs are far shorter than at the equator.
  EXPECT_GT(pm.max_spring_length / pm.min_spring_length, 5.0);
}

TEST(ParticleModel, LatLongPolesShortenTheStableStep) {
  // Same particle count, same parameters, no mass scaling: the crowded poles of the seed's grid
  // (short, stiff springs on light particles) cut the stable step against the icosphere.
  ParticleModelDesc a = small_desc(ParticleLayout::kIcosphere, 2562), b = a;
  b.layout = ParticleLayout::kLatLong;
  a.target_dt = b.target_dt = 0;
  const ParticleModel ico = build(a), grid = build(b);
  EXPECT_LT(grid.dt_critical, 0.5 * ico.dt_critical)
      << "icosphere " << ico.dt_critical << " s, lat-long " << grid.dt_critical << " s";
}

// ---------------------------------------------------------------------------------------------
// Forces.

TEST(ParticleModel, VolumeAndPressureUnderUniformScaling) {
  const ParticleModel pm = build(small_desc());
  const size_t n = pm.particle_count();
  for (double s : {0.97, 1.0, 1.02}) {
    std::vector<Vec3d> u(n), f(n);
    for (size_t i = 0; i < n; ++i) u[i] = (s - 1.0) * pm.rest_positions[i];
    const ParticleStepInfo info = particle_forces(pm, u, u, 0.0, f);
    // V = s^3 V0 and P = -3 ln(s) / beta (eq. 6 integrated at constant beta).
    EXPECT_NEAR(info.volume, s * s * s * pm.rest_volume, 1e-12 * pm.rest_volume);
    EXPECT_NEAR(info.pressure, -3.0 * std::log(s) / pm.compressibility, 1e-6 * std::fabs(info.pressure) + 1e-9);
    // Each membrane particle: springs stretched by s (tension k L0 (s - 1) along each spring,
    // radial springs likewise) plus the pressure on a third of its scaled area vectors.
    for (int i = 0; i < pm.membrane_count; i += 37) {
      const size_t p = size_t(i);
      Vec3d expected{0, 0, 0};
      for (int32_t e = pm.neighbor_offsets[p]; e < pm.neighbor_offsets[p + 1]; ++e) {
        const Vec3d d = pm.rest_positions[size_t(pm.neighbor_index[size_t(e)])] - pm.rest_positions[p];
        expected += pm.neighbor_stiffness[size_t(e)] * (s - 1.0) * d;
      }
      expected += -pm.centre_stiffness[p] * (s - 1.0) * pm.rest_positions[p];
      Vec3d g{0, 0, 0};
      for (int32_t e = pm.triangle_offsets[p]; e < pm.triangle_offsets[p + 1]; ++e) {
        const Triangle& t = pm.triangles[size_t(pm.particle_triangles[size_t(e)])];
        g += triangle_area_vector(pm.rest_positions[size_t(t[0])], pm.rest_positions[size_t(t[1])],
                                  pm.rest_positions[size_t(t[2])]);
      }
      expected += (s * s * info.pressure / 3.0) * g;
      const double scale = norm(expected) + 1e-12;
      EXPECT_NEAR(f[p].x, expected.x, 1e-9 * scale) << "particle " << i << " s " << s;
      EXPECT_NEAR(f[p].y, expected.y, 1e-9 * scale);
      EXPECT_NEAR(f[p].z, expected.z, 1e-9 * scale);
    }
    // Forces are internal: they sum to zero.
    Vec3d total{0, 0, 0};
    for (const Vec3d& x : f) total += x;
    EXPECT_LT(norm(total), 1e-9 * (std::fabs(info.pressure) * pm.rest_area + 1e-6));
  }
}

TEST(ParticleModel, StaticForcesAreTheEnergyGradient) {
  const ParticleModel pm = build(small_desc(ParticleLayout::kIcosphere, 162));
  const size_t n = pm.particle_count();
  std::vector<Vec3d> u(n), f(n), scratch(n);
  // A smooth non-uniform deformation, several um.
  for (size_t i = 0; i < n; ++i) {
    const Vec3d x = pm.rest_positions[i];
    u[i] = Vec3d{3e-6 * std::sin(1e4 * x.y), -2e-6 * std::cos(7e3 * x.z), 4e-6 * std::sin(5e3 * x.x)};
  }
  particle_forces(pm, u, u, 0.0, f);
  for (size_t i : {size_t(0), size_t(17), size_t(101), n - 1}) {
    for (int a = 0; a < 3; ++a) {
      const double h = 1e-10;
      std::vector<Vec3d> up = u, um = u;
      up[i][a] += h;
      um[i][a] -= h;
      const double ep = particle_forces(pm, up, up, 0.0, scratch).elastic_energy;
      const double em = particle_forces(pm, um, um, 0.0, scratch).elastic_energy;
      const double expected = -(ep - em) / (2 * h);
      EXPECT_NEAR(f[i][a], expected, 1e-5 * (std::fabs(expected) + norm(f[i])))
          << "particle " << i << " axis " << a;
    }
  }
}

TEST(ParticleModel, AnisotropicDampingOfARigidTranslation) {
  const ParticleModel pm = build(small_desc());
  const Mesh mesh = particle_body_mesh(pm);
  Result<Model> body = particle_body_model(pm, mesh, {});
  ASSERT_TRUE(body.ok()) << body.error().message;
  State s = make_state(*body, 1);
  // Every particle moving at v: no spring or pressure force, only eq. 5's B slows the membrane,
  // v+ = v (m - b dt/2) / (m + b dt/2) per axis; the undamped centre keeps its velocity.
  const Vec3d v{1e-4, -2e-4, 3e-4};
  const double dt = body->dt;
  for (size_t i = 0; i < s.u.size(); ++i) s.u_prev[i] = -dt * v;
  ASSERT_EQ(particle_step(pm, *body, s, nullptr), kStepOk);
  for (size_t i : {size_t(0), size_t(300), size_t(641)}) {
    const Vec3d vel = (s.u[i] - s.u_prev[i]) / dt;
    for (int a = 0; a < 3; ++a) {
      const double h = 0.5 * pm.damping[i][a] * dt, m = pm.mass[i];
      EXPECT_NEAR(vel[a], v[a] * (m - h) / (m + h), 1e-9 * std::fabs(v[a])) << i << " " << a;
    }
  }
  // Per mass the z damping is twice x's (damping {2e3, 2e3, 4e3}): z slows more.
  const Vec3d vel = (s.u[0] - s.u_prev[0]) / dt;
  EXPECT_LT(vel.z / v.z, vel.x / v.x);
  const Vec3d centre = (s.u[size_t(pm.centre)] - s.u_prev[size_t(pm.centre)]) / dt;
  EXPECT_NEAR(centre.x, v.x, 1e-12);
}

TEST(ParticleModel, StableStepHoldsAndAboveItIsRefused) {
  const ParticleModel pm = build(small_desc(ParticleLayout::kIcosphere, 162));
  EXPECT_LE(pm.dt, pm.dt_critical);
  EXPECT_NEAR(pm.dt, 0.9 * pm.dt_critical, 1e-12 * pm.dt);
  // The bound's three parts are all there.
  const ParticleStepBound b = particle_critical_step(pm, pm.mass);
  EXPECT_GT(b.spring_omega_sq, 0);
  EXPECT_GT(b.hydraulic_omega_sq, 0);
  EXPECT_GT(b.dashpot_rate, 0);
  // A kicked, undriven cell at the automatic step keeps its energy bounded (damped: it decays).
  const Mesh mesh = particle_body_mesh(pm);
  Result<Model> body = particle_body_model(pm, mesh, {});
  ASSERT_TRUE(body.ok());
  State s = make_state(*body, 1);
  for (size_t i = 0; i < s.u.size(); ++i)
    s.u[i] = Vec3d{static_cast<double>(i % 3) * 1e-6, static_cast<double>(i % 5) * -1e-6,
                   static_cast<double>(i % 7) * 5e-7};
  s.u_prev = s.u;
  StepStatus all = 0;
  for (int k = 0; k < 2000; ++k) all |= particle_step(pm, *body, s, nullptr);
  EXPECT_EQ(all, kStepOk);
  double max_u = 0;
  for (const Vec3d& x : s.u) max_u = std::max(max_u, norm(x));
  EXPECT_LT(max_u, 1e-5);
  // An explicit dt above the bound is refused at build and at the step.
  ParticleModelDesc d = small_desc(ParticleLayout::kIcosphere, 162);
  d.target_dt = 0;
  d.dt = 1.0;
  Result<ParticleModel> bad = build_particle_model(d);
  ASSERT_FALSE(bad.ok());
  EXPECT_NE(bad.error().message.find("critical step"), std::string::npos);
  Model fast = *body;
  fast.dt = 2 * fast.dt_critical;
  EXPECT_EQ(particle_step(pm, fast, s, nullptr), kStepDtAboveCritical);
}

TEST(ParticleModel, MassScalingReachesTheTargetStep) {
  ParticleModelDesc d = small_desc(ParticleLayout::kIcosphere, 162);
  d.target_dt = 50e-6;
  const ParticleModel pm = build(d);
  EXPECT_GT(pm.mass_scaling, 1.0);
  EXPECT_NEAR(pm.dt, 50e-6, 1e-9 * 50e-6);
}

TEST(ParticleModel, BadParametersAreRefusedInOneLine) {
  auto refused = [](ParticleModelDesc d, const char* key) {
    Result<ParticleModel> pm = build_particle_model(d);
    ASSERT_FALSE(pm.ok()) << key;
    EXPECT_NE(pm.error().message.find(key), std::string::npos) << pm.error().message;
    EXPECT_EQ(pm.error().message.find('\n'), std::string::npos);
  };
  ParticleModelDesc d = small_desc();
  d.membrane_modulus = -1;
  refused(d, "particles.membrane_modulus");
  d = small_desc();
  d.compressibility = 0;
  refused(d, "particles.compressibility");
  d = small_desc();
  d.radius = std::nan("");
  refused(d, "particles.radius");
  d = small_desc();
  d.damping.y = -1;
  refused(d, "particles.damping");
  d = small_desc();
  d.target_particles = 5;
  refused(d, "particles.particles");
  d = small_desc();
  d.pole_axis = Vec3d{0, 0, 0};
  refused(d, "particles.pole_axis");
  d = small_desc();
  d.dt_safety = 1.5;
  refused(d, "integrator.dt_safety");
}

// ---------------------------------------------------------------------------------------------
// In the injection simulation.



std::unique_ptr<Simulation> make_sim(const json& j, const SimulationOptions& options = {}) {
  Result<Scene> scene = parse_scene(j, "particles_test.json");
  EXPECT_TRUE(scene.ok()) << (scene.ok() ? "" : scene.error().message);
  if (!scene.ok()) return nullptr;
  Result<std::unique_ptr<Simulation>> sim = Simulation::create(*scene, options);
  EXPECT_TRUE(sim.ok()) << (sim.ok() ? "" : sim.error().message);
  return sim.ok() ? std::move(*sim) : nullptr;
}

TEST(ParticleSimulation, InjectionConservesVolumeWithinFivePercent) {
  std::unique_ptr<Simulation> sim = make_sim(particle_scene());
  ASSERT_TRUE(sim);
  ASSERT_NE(sim->particle_model(), nullptr);
  RunResult run = run_simulation(*sim);
  EXPECT_FALSE(run.stopped_early) << run.stop_reason;
  // The needle went 240 um into the cell against a rising force...
  EXPECT_GT(run.peak_deformation, 150e-6);
  EXPECT_GT(run.peak_force, 0.0);
  ASSERT_GT(run.samples.size(), 10u);
  EXPECT_GT(run.samples.back().force, run.samples[run.samples.size() / 2].force);
  // ... while eq. 6 kept the enclosed volume within 5 % (and it did change).
  EXPECT_LT(sim->volume_change_max_rel(), 0.05);
  EXPECT_GT(sim->volume_change_max_rel(), 0.0);
}

// The particle model on the job's step: the needle's penalty is the stiffest the particle step
// carries without raising a mass (the FEM's scale multiplied the scaled membrane's mass), so
// the body's masses stay the particle model's own, and the run reports the stiffness it took.
TEST(ParticleSimulation, TheNeedlesPenaltyRaisesNoMass) {
  std::unique_ptr<Simulation> sim = make_sim(particle_scene());
  ASSERT_TRUE(sim);
  EXPECT_TRUE(sim->job_mode());
  const ParticleModel& pm = *sim->particle_model();
  ASSERT_EQ(sim->model().vertex_mass.size(), pm.mass.size());
  for (size_t v = 0; v < pm.mass.size(); ++v)
    ASSERT_EQ(sim->model().vertex_mass[v], pm.mass[v]) << v;
  const ParticleModel rebuilt =
      build_particle_model(particle_desc_from_scene(*parse_scene(particle_scene(), "p.json")).value())
          .value();
  for (size_t v = 0; v < pm.mass.size(); ++v) ASSERT_EQ(pm.mass[v], rebuilt.mass[v]) << v;
  bool penalty_note = false;
  for (const std::string& n : sim->notes()) {
    EXPECT_EQ(n.find("masses raised"), std::string::npos) << n;
    penalty_note = penalty_note || n.find("particle membrane's penalty") != std::string::npos;
  }
  EXPECT_TRUE(penalty_note);
}

// A tip smaller than the particles' spacing (30 um against 48-66 um on 642 particles) passes
// between them under the penalty: the run ends with the breach error, and no puncture is
// recorded from it.
TEST(ParticleSimulation, ATipSmallerThanTheSpacingEndsWithTheBreachError) {
  json j = particle_scene();
  j["needle"]["tip_radius"] = "30 um";
  std::unique_ptr<Simulation> sim = make_sim(j);
  ASSERT_TRUE(sim);
  const RunResult run = run_simulation(*sim);
  EXPECT_TRUE(run.stopped_early);
  EXPECT_NE(run.stop_reason.find("went through the cell surface"), std::string::npos)
      << run.stop_reason;
  EXPECT_FALSE(sim->puncture().punctured);
}

TEST(ParticleSimulation, SplitStepTakesTheHapticToolPose) {
  std::unique_ptr<Simulation> sim = make_sim(particle_scene());
  ASSERT_TRUE(sim);
  // Drive the tip by hand 100 um into the cell through step1 / set_needle_tip / step2.
  const Vec3d start = sim->needle_script().start;
  const int steps = 2000;
  for (int k = 1; k <= steps; ++k) {
    sim->step1();
    sim->set_needle_tip(start + (120e-6 * k / steps) * Vec3d{1, 0, 0});
    ASSERT_EQ(sim->step2() & kStepNotAdvanced, 0u);
  }
  EXPECT_GT(sim->report().contacts, 0);
  EXPECT_GT(sim->report().force, 0.0);
  EXPECT_GT(sim->report().deformation, 50e-6);
}

TEST(ParticleSimulation, RunsAreDeterministic) {
  json j = particle_scene();
  j["needle"]["max_travel"] = "60 um";
  std::unique_ptr<Simulation> a = make_sim(j), b = make_sim(j);
  ASSERT_TRUE(a && b);
  for (int k = 0; k < 1500; ++k) {
    a->step();
    b->step();
  }
  EXPECT_GT(a->report().contacts, 0);
  for (size_t i = 0; i < a->state().u.size(); ++i) {
    ASSERT_EQ(a->state().u[i].x, b->state().u[i].x) << i;
    ASSERT_EQ(a->state().u[i].z, b->state().u[i].z) << i;
  }
  EXPECT_EQ(a->report().force, b->report().force);
}

// A particle body with a fixed cap, a prescribed (indented) patch and a load: the setting the
// backends are compared in.
struct Driven {
  ParticleModel pm;
  Mesh mesh;
  Model body;
  State state;
  std::vector<int32_t> patch;
};

Driven make_driven() {
  Driven d;
  d.pm = build(small_desc(ParticleLayout::kIcosphere, 642));
  d.mesh = particle_body_mesh(d.pm);
  std::vector<int32_t> fixed;
  for (int i = 0; i < d.pm.membrane_count; ++i) {
    const Vec3d x = d.pm.rest_positions[size_t(i)];
    if (x.x > 350e-6) fixed.push_back(i);
    if (x.x < -370e-6) d.patch.push_back(i);
  }
  Result<Model> body = particle_body_model(d.pm, d.mesh, fixed);
  EXPECT_TRUE(body.ok());
  d.body = std::move(*body);
  d.state = make_state(d.body, 1);
  EXPECT_TRUE(set_prescribed_vertices(d.body, d.state, d.patch).ok());
  d.state.external_force[5] = Vec3d{0, 1e-6, -2e-6};
  return d;
}

// Target of the indented patch after `k` steps: pushed along +x at 1 mm/s.
Vec3d patch_target(const Driven& d, int64_t k) { return Vec3d{1e-3 * static_cast<double>(k) * d.body.dt, 0, 0}; }

TEST(ParticleSimulation, CpuBackendMatchesTheInPlaceStep) {
  Driven ref = make_driven(), via = make_driven();
  std::unique_ptr<Backend> backend = make_particle_cpu_backend(via.pm);
  ASSERT_TRUE(backend->upload(via.body, via.state).ok());
  std::vector<Vec3d> targets(via.patch.size());
  for (int call = 1; call <= 40; ++call) {
    // In place: five steps with the targets moving linearly; the backend: one call of five.
    for (int k = 1; k <= 5; ++k) {
      for (size_t i = 0; i < ref.patch.size(); ++i)
        ref.state.prescribed_displacement[i] = patch_target(ref, 5 * (call - 1) + k);
      ASSERT_EQ(particle_step(ref.pm, ref.body, ref.state, nullptr) & kStepNotAdvanced, 0u);
    }
    for (Vec3d& t : targets) t = patch_target(via, 5 * call);
    ASSERT_TRUE(backend->set_prescribed_targets(targets).ok());
    const StepReport r = backend->step(5);
    ASSERT_EQ(r.steps, 5);
    ASSERT_EQ(r.status & kStepNotAdvanced, 0u);
  }
  ASSERT_TRUE(backend->download(via.state).ok());
  EXPECT_EQ(via.state.step_count, 200);
  double max_u = 0, max_diff = 0;
  for (size_t i = 0; i < ref.state.u.size(); ++i) {
    max_u = std::max(max_u, norm(ref.state.u[i]));
    max_diff = std::max(max_diff, norm(ref.state.u[i] - via.state.u[i]));
  }
  EXPECT_GT(max_u, 1e-6);  // the patch went 2 um in
  EXPECT_LT(max_diff, 1e-12 * max_u);
  // The constraint pushes the patch into the cell (+x) against the body's resistance.
  EXPECT_GT(ref.state.diag.constraint_force.x, 0.0);
  EXPECT_NEAR(via.state.diag.constraint_force.x, ref.state.diag.constraint_force.x,
              1e-9 * std::fabs(ref.state.diag.constraint_force.x));
}

// The Backend path of the simulation (upload on a new contact set, targets, step, download), as
// the GPU backends are driven, against the in-place reference: with the CPU backend both do the
// same arithmetic, so a difference is the path's own (state handed over incompletely).
TEST(ParticleSimulation, BackendPathMatchesTheInPlacePath) {
  json j = particle_scene();
  j["needle"]["max_travel"] = "120 um";
  SimulationOptions via;
  via.keep_cpu_backend = true;
  via.particle_backend_factory = [](const ParticleModel& pm, std::string*) {
    return Result<std::unique_ptr<Backend>>(make_particle_cpu_backend(pm));
  };
  std::unique_ptr<Simulation> ref = make_sim(j), sim = make_sim(j, via);
  ASSERT_TRUE(ref && sim);
  ASSERT_EQ(sim->backend_description().find("in place"), std::string::npos)
      << sim->backend_description();
  const RunResult a = run_simulation(*ref), b = run_simulation(*sim);
  ASSERT_EQ(a.samples.size(), b.samples.size());
  ASSERT_GT(a.peak_force, 0.0);
  double worst = 0;
  for (size_t i = 0; i < a.samples.size(); ++i)
    worst = std::max(worst, std::fabs(a.samples[i].force - b.samples[i].force));
  EXPECT_LT(worst, 1e-9 * a.peak_force);
  EXPECT_NEAR(b.peak_deformation, a.peak_deformation, 1e-12);
}

TEST(ParticleSimulation, SceneReaderAndWriterRoundTrip) {
  json j = particle_scene();
  j["particles"]["layout"] = "latlong";
  j["particles"]["pole_axis"] = "+y";
  j["particles"]["areal_density"] = "2e-3 kg/m^2";
  j["particles"]["membrane_relaxation_time"] = "1 us";
  Result<Scene> scene = parse_scene(j, "particles_test.json");
  ASSERT_TRUE(scene.ok()) << scene.error().message;
  EXPECT_EQ(scene->model, ModelKind::kParticles);
  EXPECT_EQ(scene->particles.layout, ParticleLayout::kLatLong);
  EXPECT_DOUBLE_EQ(scene->particles.radial_stiffness, 1000.0);
  EXPECT_DOUBLE_EQ(scene->particles.damping.z, 2e4);
  EXPECT_DOUBLE_EQ(scene->particles.compressibility, 1e-6);
  EXPECT_DOUBLE_EQ(scene->particles.areal_density, 2e-3);
  Result<Scene> back = parse_scene(scene_to_json(*scene), "round_trip.json");
  ASSERT_TRUE(back.ok()) << back.error().message;
  EXPECT_EQ(back->particles.layout, ParticleLayout::kLatLong);
  EXPECT_DOUBLE_EQ(back->particles.membrane_modulus, scene->particles.membrane_modulus);
  EXPECT_DOUBLE_EQ(back->particles.radial_damping, scene->particles.radial_damping);
  EXPECT_DOUBLE_EQ(back->particles.compressibility, scene->particles.compressibility);
  EXPECT_DOUBLE_EQ(back->particles.membrane_relaxation_time, 1e-6);
  EXPECT_DOUBLE_EQ(back->particles.pole_axis.y, 1.0);
}

TEST(ParticleSimulation, SceneErrorsAreOneLine) {
  auto error_of = [](const json& j) {
    Result<Scene> scene = parse_scene(j, "bad.json");
    if (!scene.ok()) return scene.error().message;
    Result<std::unique_ptr<Simulation>> sim = Simulation::create(*scene);
    return sim.ok() ? std::string() : sim.error().message;
  };
  json j = particle_scene();
  j["particles"]["compressibility"] = "-1 1/Pa";
  std::string e = error_of(j);
  EXPECT_NE(e.find("particles.compressibility"), std::string::npos) << e;
  j = particle_scene();
  j["particles"]["membrane_modulus"] = "20 Pa";  // wrong dimension
  e = error_of(j);
  EXPECT_NE(e.find("particles.membrane_modulus"), std::string::npos) << e;
  j = particle_scene();
  j["model"] = "svk";
  j["materials"] = {{"default", {{"young", "1 kPa"}, {"poisson", 0.3}}}};
  e = error_of(j);
  EXPECT_NE(e.find("only used with"), std::string::npos) << e;
  j = particle_scene();
  j["puncture"] = {{"criterion", "strain"}, {"threshold", 0.2}};
  e = error_of(j);
  EXPECT_NE(e.find("strain"), std::string::npos) << e;
  EXPECT_EQ(e.find('\n'), std::string::npos);
}

}  // namespace
}  // namespace zona
