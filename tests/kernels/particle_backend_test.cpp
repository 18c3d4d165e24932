// The particle model's GPU backend against its CPU reference on the same inputs (STYLE.md habit
// 7): static forces, a 200-step driven trajectory with fixed, prescribed and loaded particles
// (outputs poisoned with NaN first), bitwise-reproducible runs, the not-advanced rule on a
// non-finite load, and a whole injection through the Simulation. Every Cuda* test skips when the
// CUDA backend cannot be created (no GPU, or built without CUDA); the factory test runs always.
#include "kernels/particle_backend.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <limits>
#include <memory>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "engine/particles/particle_model.h"
#include "engine/sim/backend_cpu.h"
#include "engine/sim/simulation.h"
#include "tests/engine/test_scenes.h"

namespace zona {
namespace {

/// Forces: the same float64 arithmetic per particle; only the volume's and the centre's sums
/// are in another order (a tree instead of a serial loop), so agreement is to rounding.
constexpr double kForceTolerance = 1e-11;
/// Displacements after 200 steps, relative to the largest: rounding carried by the dynamics.
constexpr double kTrajectoryTolerance = 1e-9;
/// A whole simulated injection, relative. With the contact release rule robust to rounding
/// (issue 9, engine/tools/contact.h) the GPU and CPU runs take the same contact decisions, so the
/// force history is compared over the whole run. (With the old rule a release of the tip's first
/// contacts flipped on rounding: on the H100, 2026-11-21, mean force 14 % and peak force 12 %
/// apart.)
constexpr double kInjectionForceTolerance = 1e-2;
constexpr double kInjectionDeformationTolerance = 1e-2;
constexpr double kInjectionVolumeTolerance = 1e-2;
/// Samples whose needle contact counts may differ, as a fraction of all samples.
constexpr double kInjectionContactCountTolerance = 1e-2;

#define ZONA_PARTICLE_CUDA_OR_SKIP(var, model, options)                                    \
  Result<std::unique_ptr<Backend>> var##_result = make_particle_cuda_backend(model, options); \
  if (!var##_result) GTEST_SKIP() << var##_result.error().message;                          \
  std::unique_ptr<Backend> var = std::move(var##_result).value()

ParticleModel test_model() {
  ParticleModelDesc d;
  d.radius = 400e-6;
  d.target_particles = 642;
  d.membrane_modulus = 20.0;
  d.radial_stiffness = 1e3;
  d.radial_damping = 1e3;
  d.membrane_relaxation_time = 1e-6;
  d.damping = Vec3d{2e3, 2e3, 4e3};
  d.compressibility = 1e-6;
  d.target_dt = 10e-6;
  Result<ParticleModel> pm = build_particle_model(d);
  EXPECT_TRUE(pm.ok()) << (pm.ok() ? "" : pm.error().message);
  return pm.ok() ? std::move(*pm) : ParticleModel{};
}

// A body with a fixed cap (+x), an indented patch (-x, prescribed) and one load.
struct Driven {
  ParticleModel pm = test_model();
  Mesh mesh;
  Model body;
  State state;
  std::vector<int32_t> patch;
  Driven() {
    mesh = particle_body_mesh(pm);
    std::vector<int32_t> fixed;
    for (int i = 0; i < pm.membrane_count; ++i) {
      const Vec3d x = pm.rest_positions[size_t(i)];
      if (x.x > 350e-6) fixed.push_back(i);
      if (x.x < -370e-6) patch.push_back(i);
    }
    Result<Model> b = particle_body_model(pm, mesh, fixed);
    EXPECT_TRUE(b.ok());
    body = std::move(*b);
    state = make_state(body, 1);
    EXPECT_TRUE(set_prescribed_vertices(body, state, patch).ok());
    state.external_force[5] = Vec3d{0, 1e-6, -2e-6};
  }
  Vec3d target(int64_t k) const { return Vec3d{1e-3 * static_cast<double>(k) * body.dt, 0, 0}; }
};

// Runs 40 calls of 5 sub-steps with the patch pushed in at 1 mm/s; returns the last report.
StepReport drive(Backend& backend, const Driven& d) {
  std::vector<Vec3d> targets(d.patch.size());
  StepReport last;
  for (int call = 1; call <= 40; ++call) {
    for (Vec3d& t : targets) t = d.target(5 * call);
    EXPECT_TRUE(backend.set_prescribed_targets(targets).ok());
    last = backend.step(5);
    EXPECT_EQ(last.steps, 5);
  }
  return last;
}

double max_norm(const std::vector<Vec3d>& v) {
  double m = 0;
  for (const Vec3d& x : v) m = std::max(m, norm(x));
  return m;
}

double max_diff(const std::vector<Vec3d>& a, const std::vector<Vec3d>& b) {
  double m = 0;
  for (size_t i = 0; i < a.size(); ++i) m = std::max(m, norm(a[i] - b[i]));
  return m;
}

TEST(CudaParticleForces, MatchCpu) {
  Driven d;
  BackendOptions options;
  options.poison_outputs = true;
  ZONA_PARTICLE_CUDA_OR_SKIP(gpu, d.pm, options);
  ASSERT_TRUE(gpu->upload(d.body, d.state).ok());
  std::vector<Vec3d> u(d.pm.particle_count()), f_cpu(u.size()), f_gpu(u.size(), Vec3d{NAN, NAN, NAN});
  for (size_t i = 0; i < u.size(); ++i) {
    const Vec3d x = d.pm.rest_positions[i];
    u[i] = Vec3d{5e-6 * std::sin(1e4 * x.y), -3e-6 * std::cos(7e3 * x.z), 4e-6 * std::sin(5e3 * x.x)};
  }
  particle_forces(d.pm, u, u, 0.0, f_cpu);
  ASSERT_TRUE(gpu->elastic_forces(u, f_gpu).ok());
  EXPECT_LT(max_diff(f_cpu, f_gpu), kForceTolerance * max_norm(f_cpu));
}

TEST(CudaParticleTrajectory, TwoHundredStepsMatchCpu) {
  Driven a, b;
  BackendOptions options;
  options.poison_outputs = true;
  ZONA_PARTICLE_CUDA_OR_SKIP(gpu, b.pm, options);
  std::unique_ptr<Backend> cpu = make_particle_cpu_backend(a.pm);
  ASSERT_TRUE(cpu->upload(a.body, a.state).ok());
  ASSERT_TRUE(gpu->upload(b.body, b.state).ok());
  const StepReport rc = drive(*cpu, a), rg = drive(*gpu, b);
  EXPECT_EQ(rc.status, rg.status);
  ASSERT_TRUE(cpu->download(a.state).ok());
  ASSERT_TRUE(gpu->download(b.state).ok());
  EXPECT_EQ(a.state.step_count, b.state.step_count);
  EXPECT_DOUBLE_EQ(a.state.time, b.state.time);
  const double scale = max_norm(a.state.u);
  EXPECT_GT(scale, 1e-6);  // the patch went 2 um in
  EXPECT_LT(max_diff(a.state.u, b.state.u), kTrajectoryTolerance * scale);
  EXPECT_LT(max_diff(a.state.u_prev, b.state.u_prev), kTrajectoryTolerance * scale);
  EXPECT_LT(max_diff(a.state.force, b.state.force), kTrajectoryTolerance * max_norm(a.state.force));
  EXPECT_LT(norm(rc.constraint_force - rg.constraint_force), kTrajectoryTolerance * norm(rc.constraint_force));
  EXPECT_NEAR(rc.kinetic_energy, rg.kinetic_energy, kTrajectoryTolerance * rc.kinetic_energy + 1e-30);
  EXPECT_NEAR(rc.elastic_energy, rg.elastic_energy, kTrajectoryTolerance * rc.elastic_energy);
  // The prescribed targets reached the last call's.
  EXPECT_LT(max_diff(a.state.prescribed_displacement, b.state.prescribed_displacement), 1e-18);
}

TEST(CudaParticleTrajectory, RunsAreBitwiseIdentical) {
  Driven a, b;
  ZONA_PARTICLE_CUDA_OR_SKIP(g1, a.pm, BackendOptions{});
  ZONA_PARTICLE_CUDA_OR_SKIP(g2, b.pm, BackendOptions{});
  ASSERT_TRUE(g1->upload(a.body, a.state).ok());
  ASSERT_TRUE(g2->upload(b.body, b.state).ok());
  drive(*g1, a);
  drive(*g2, b);
  ASSERT_TRUE(g1->download(a.state).ok());
  ASSERT_TRUE(g2->download(b.state).ok());
  for (size_t i = 0; i < a.state.u.size(); ++i) {
    ASSERT_EQ(a.state.u[i].x, b.state.u[i].x) << i;
    ASSERT_EQ(a.state.u[i].y, b.state.u[i].y) << i;
    ASSERT_EQ(a.state.u[i].z, b.state.u[i].z) << i;
  }
}

TEST(CudaParticleHealth, NonFiniteLoadKeepsTheLastGoodState) {
  Driven d;
  ZONA_PARTICLE_CUDA_OR_SKIP(gpu, d.pm, BackendOptions{});
  ASSERT_TRUE(gpu->upload(d.body, d.state).ok());
  drive(*gpu, d);
  ASSERT_TRUE(gpu->download(d.state).ok());
  const std::vector<Vec3d> u_before = d.state.u, u_prev_before = d.state.u_prev;
  const int64_t steps_before = d.state.step_count;
  // A NaN load: the first sub-step is not advanced and the rest of the call does nothing.
  d.state.external_force[7] = Vec3d{std::numeric_limits<double>::quiet_NaN(), 0, 0};
  ASSERT_TRUE(gpu->upload(d.body, d.state).ok());
  const StepReport r = gpu->step(3);
  EXPECT_TRUE(r.status & kStepNonFinite);
  EXPECT_EQ(r.steps, 0);
  ASSERT_TRUE(gpu->download(d.state).ok());
  EXPECT_EQ(d.state.step_count, steps_before);
  for (size_t i = 0; i < u_before.size(); ++i) {
    ASSERT_EQ(d.state.u[i].x, u_before[i].x) << i;
    ASSERT_EQ(d.state.u_prev[i].z, u_prev_before[i].z) << i;
  }
}

// The injection both CudaParticleSimulation tests run: 642 particles, a 30 um sphere at 2 mm/s.
nlohmann::json injection_scene() {
  nlohmann::json j = test::particle_scene(2e-3);
  j["needle"]["max_travel"] = "120 um";
  j["output"] = {{"frames", 0}};
  return j;
}

TEST(CudaParticleSimulation, InjectionMatchesCpu) {
  const nlohmann::json j = injection_scene();
  Result<Scene> scene = parse_scene(j, "cuda_particles.json");
  ASSERT_TRUE(scene.ok()) << scene.error().message;
  {
    // Skip without a device (the probe builds a throwaway model).
    Result<std::unique_ptr<Backend>> probe = make_particle_cuda_backend(test_model(), BackendOptions{});
    if (!probe) GTEST_SKIP() << probe.error().message;
  }
  SimulationOptions gpu_options;
  gpu_options.particle_backend_factory = [](const ParticleModel& pm, std::string* notice) {
    return make_particle_backend(BackendKind::kCuda, pm, BackendOptions{}, notice);
  };
  Result<std::unique_ptr<Simulation>> cpu = Simulation::create(*scene);
  Result<std::unique_ptr<Simulation>> gpu = Simulation::create(*scene, gpu_options);
  ASSERT_TRUE(cpu.ok() && gpu.ok());
  EXPECT_NE((*gpu)->backend_description().find("cuda"), std::string::npos);
  const RunResult rc = run_simulation(**cpu), rg = run_simulation(**gpu);
  EXPECT_EQ(rc.steps, rg.steps);
  EXPECT_GT(rc.peak_force, 0.0);
  ASSERT_EQ(rc.samples.size(), rg.samples.size());
  double mean_c = 0, mean_g = 0;
  size_t contact_samples = 0, contacts_differ = 0;
  for (size_t i = 0; i < rc.samples.size(); ++i) {
    mean_c += rc.samples[i].force;
    mean_g += rg.samples[i].force;
    if (rc.samples[i].contacts > 0) ++contact_samples;
    if (rc.samples[i].contacts != rg.samples[i].contacts) ++contacts_differ;
  }
  mean_c /= static_cast<double>(rc.samples.size());
  mean_g /= static_cast<double>(rg.samples.size());
  std::printf("[ measured ] injection cpu vs cuda: mean force %.6g / %.6g N, peak force %.6g / %.6g N, "
              "peak deformation %.6g / %.6g m, %zu of %zu samples with other contact counts\n",
              mean_c, mean_g, rc.peak_force, rg.peak_force, rc.peak_deformation, rg.peak_deformation,
              contacts_differ, rc.samples.size());
  // The same experiment over the whole run (the needle is on the membrane for most of it).
  EXPECT_GT(contact_samples, rc.samples.size() / 2);
  EXPECT_LE(static_cast<double>(contacts_differ),
            kInjectionContactCountTolerance * static_cast<double>(rc.samples.size()));
  EXPECT_NEAR(mean_g, mean_c, kInjectionForceTolerance * mean_c);
  EXPECT_NEAR(rg.peak_force, rc.peak_force, kInjectionForceTolerance * rc.peak_force);
  EXPECT_NEAR(rg.peak_deformation, rc.peak_deformation,
              kInjectionDeformationTolerance * rc.peak_deformation);
  EXPECT_NEAR((*gpu)->volume_change_max_rel(), (*cpu)->volume_change_max_rel(),
              kInjectionVolumeTolerance * (*cpu)->volume_change_max_rel());
}

// The same injection step by step against the CPU backend driven through the same Backend
// calls (SimulationOptions::keep_cpu_backend): the state within rounding of the CPU's until the
// first differing contact decision (a face quadrature point in the tip one step apart), and over
// the whole run the same contact count at all but a few steps and the needle force within 1 % of
// its peak.
TEST(CudaParticleSimulation, StepByStepMatchesTheCpuBackend) {
  const nlohmann::json j = injection_scene();
  Result<Scene> scene = parse_scene(j, "cuda_particles_steps.json");
  ASSERT_TRUE(scene.ok()) << scene.error().message;
  {
    Result<std::unique_ptr<Backend>> probe = make_particle_cuda_backend(test_model(), BackendOptions{});
    if (!probe) GTEST_SKIP() << probe.error().message;
  }
  SimulationOptions gpu_options, cpu_options;
  gpu_options.particle_backend_factory = [](const ParticleModel& pm, std::string* notice) {
    return make_particle_backend(BackendKind::kCuda, pm, BackendOptions{}, notice);
  };
  cpu_options.keep_cpu_backend = true;
  cpu_options.particle_backend_factory = [](const ParticleModel& pm, std::string* notice) {
    return make_particle_backend(BackendKind::kCpu, pm, BackendOptions{}, notice);
  };
  Result<std::unique_ptr<Simulation>> cpu = Simulation::create(*scene, cpu_options);
  Result<std::unique_ptr<Simulation>> gpu = Simulation::create(*scene, gpu_options);
  ASSERT_TRUE(cpu.ok() && gpu.ok());
  Simulation& c = **cpu;
  Simulation& g = **gpu;
  int contact_steps = 0, steps = 0, sets_differ = 0, first_differing = -1;
  double peak = 0, max_force_diff = 0;
  for (int k = 0; k < 6000 && !c.finished(); ++k) {
    const StepStatus sc = c.step(), sg = g.step();
    ++steps;
    ASSERT_EQ(sc & kStepNotAdvanced, sg & kStepNotAdvanced) << "step " << k;
    if (c.report().contacts > 0) ++contact_steps;
    peak = std::max(peak, std::fabs(c.report().force));
    max_force_diff = std::max(max_force_diff, std::fabs(g.report().force - c.report().force));
    // A contact decision can still flip where a geometric test straddles its threshold (a face
    // quadrature point entering the tip one step apart); count those steps, and compare the
    // states to rounding only up to the first.
    if (c.report().contacts != g.report().contacts) {
      ++sets_differ;
      if (first_differing < 0) first_differing = k;
    }
    if (first_differing >= 0) continue;
    double scale = 0, diff = 0, fscale = 0, fdiff = 0;
    for (size_t i = 0; i < c.state().u.size(); ++i) {
      scale = std::max(scale, norm(c.state().u[i]));
      diff = std::max(diff, norm(c.state().u[i] - g.state().u[i]));
      fscale = std::max(fscale, norm(c.state().force[i]));
      fdiff = std::max(fdiff, norm(c.state().force[i] - g.state().force[i]));
    }
    // Rounding carried by the dynamics and the contact stage: 1e-7 of the largest value, with
    // 1e-15 m / 1e-15 N floors (the state starts at zero).
    ASSERT_LE(diff, 1e-7 * scale + 1e-15) << "step " << k;
    ASSERT_LE(fdiff, 1e-7 * fscale + 1e-15) << "step " << k;
    ASSERT_NEAR(g.report().force, c.report().force, 1e-6 * std::fabs(c.report().force) + 1e-15)
        << "step " << k;
  }
  std::printf("[ measured ] cpu and cuda: %d steps, %d in contact; agree to rounding until step %d; "
              "contact counts differ in %d steps; largest force difference %.3g of the peak\n",
              steps, contact_steps, first_differing, sets_differ, max_force_diff / peak);
  // The whole run, needle on the membrane for most of it.
  EXPECT_TRUE(c.finished());
  EXPECT_GT(contact_steps, steps / 2);
  EXPECT_LE(static_cast<double>(sets_differ), kInjectionContactCountTolerance * steps);
  EXPECT_LE(max_force_diff, kInjectionForceTolerance * peak);
}

// The CPU particle backend with rounding-level noise on what it hands back, as a GPU's results
// differ from the CPU's (sums in another order): each downloaded force component moves by up to
// 2 ulp of itself plus 1e-18 N, each displacement by 2 ulp plus 1e-21 m (pseudo-random,
// reproducible). The forces feed the contact decisions; the displacements reach the dynamics at
// the next upload (every change of the contact set).
class RoundingNoiseBackend final : public Backend {
 public:
  explicit RoundingNoiseBackend(std::unique_ptr<Backend> inner) : inner_(std::move(inner)) {}
  const char* name() const override { return "cpu+rounding-noise"; }
  std::string description() const override {
    std::string d = inner_->description();
    d.append(" + rounding noise");
    return d;
  }
  Status upload(const Model& model, const State& state) override { return inner_->upload(model, state); }
  Status set_prescribed_targets(std::span<const Vec3d> targets) override {
    return inner_->set_prescribed_targets(targets);
  }
  Status set_external_forces(std::span<const Vec3d> forces) override {
    return inner_->set_external_forces(forces);
  }
  StepReport step(int substeps) override { return inner_->step(substeps); }
  Status download(State& state) override {
    Status s = inner_->download(state);
    if (!s) return s;
    for (size_t v = 0; v < state.u.size(); ++v) {
      state.force[v] = jitter(state.force[v], 1e-18);
      state.u[v] = jitter(state.u[v], 1e-21);
    }
    return s;
  }
  Status elastic_forces(std::span<const Vec3d> u, std::span<Vec3d> f) override {
    return inner_->elastic_forces(u, f);
  }
  Result<StateSummary> summarize() override { return inner_->summarize(); }

 private:
  // Uniform in [-1, 1) from a splitmix64 sequence.
  double next() {
    uint64_t z = (state_ += 0x9E3779B97F4A7C15ull);
    z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
    z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
    z ^= z >> 31;
    return static_cast<double>(z >> 11) * 0x1.0p-52 - 1.0;
  }
  Vec3d jitter(Vec3d x, double floor) {
    constexpr double kUlp = std::numeric_limits<double>::epsilon();
    return Vec3d{x.x + (2 * kUlp * std::fabs(x.x) + floor) * next(),
                 x.y + (2 * kUlp * std::fabs(x.y) + floor) * next(),
                 x.z + (2 * kUlp * std::fabs(x.z) + floor) * next()};
  }
  std::unique_ptr<Backend> inner_;
  uint64_t state_ = 0x5EED;
};

// The injection of the CudaParticleSimulation tests without a GPU, its body driven through the CPU
// backend with and without rounding noise on what comes back (the host's tool stage reads the
// noisy positions): the same contact decisions and the same force curve.
TEST(ParticleSimulationRounding, NoiseInTheBackendStateDoesNotChangeTheInjection) {
  Result<Scene> scene = parse_scene(injection_scene(), "rounding_noise.json");
  ASSERT_TRUE(scene.ok()) << scene.error().message;
  SimulationOptions ref_options, noisy_options;
  ref_options.keep_cpu_backend = true;
  ref_options.particle_backend_factory = [](const ParticleModel& pm, std::string* notice) {
    return make_particle_backend(BackendKind::kCpu, pm, BackendOptions{}, notice);
  };
  noisy_options.particle_backend_factory =
      [](const ParticleModel& pm, std::string* notice) -> Result<std::unique_ptr<Backend>> {
    Result<std::unique_ptr<Backend>> cpu = make_particle_backend(BackendKind::kCpu, pm, BackendOptions{}, notice);
    if (!cpu) return cpu;
    return std::unique_ptr<Backend>(std::make_unique<RoundingNoiseBackend>(std::move(*cpu)));
  };
  Result<std::unique_ptr<Simulation>> ref = Simulation::create(*scene, ref_options);
  Result<std::unique_ptr<Simulation>> noisy = Simulation::create(*scene, noisy_options);
  ASSERT_TRUE(ref.ok() && noisy.ok());
  ASSERT_NE((*noisy)->backend_description().find("rounding noise"), std::string::npos);
  Simulation& a = **ref;
  Simulation& b = **noisy;
  int contact_steps = 0, count_differs = 0;
  double sum_a = 0, sum_b = 0, max_diff = 0, peak = 0;
  while (!a.finished() && !b.finished()) {
    a.step();
    b.step();
    if (a.report().contacts > 0) ++contact_steps;
    if (a.report().contacts != b.report().contacts) ++count_differs;
    sum_a += a.report().force;
    sum_b += b.report().force;
    peak = std::max(peak, std::fabs(a.report().force));
    max_diff = std::max(max_diff, std::fabs(a.report().force - b.report().force));
  }
  EXPECT_TRUE(a.finished() && b.finished());
  std::printf("[ measured ] rounding noise: %d steps in contact, contact count differs in %d; "
              "mean force %.9g / %.9g N; largest force difference %.3g of the peak\n",
              contact_steps, count_differs, sum_a / contact_steps, sum_b / contact_steps,
              max_diff / peak);
  // Measured (penalty contact): no step with another contact count, the force within 1.5e-13 of
  // its peak.
  EXPECT_GT(contact_steps, 1000);
  EXPECT_LE(count_differs, contact_steps / 100);
  EXPECT_NEAR(sum_b, sum_a, 1e-4 * sum_a);
  EXPECT_LT(max_diff, 1e-2 * peak);
}

TEST(ParticleBackendFactory, CpuAlwaysAndAutoFallsBackWithANotice) {
  const ParticleModel pm = test_model();
  std::string notice = "stale";
  Result<std::unique_ptr<Backend>> cpu = make_particle_backend(BackendKind::kCpu, pm, {}, &notice);
  ASSERT_TRUE(cpu.ok());
  EXPECT_STREQ((*cpu)->name(), "cpu");
  EXPECT_TRUE(notice.empty());
  Result<std::unique_ptr<Backend>> cuda = make_particle_backend(BackendKind::kCuda, pm, {}, &notice);
  Result<std::unique_ptr<Backend>> any = make_particle_backend(BackendKind::kAuto, pm, {}, &notice);
  ASSERT_TRUE(any.ok());
  if (cuda.ok()) {
    EXPECT_STREQ((*any)->name(), "cuda");
    EXPECT_TRUE(notice.empty());
  } else {
    EXPECT_EQ(cuda.error().message.find('\n'), std::string::npos);
    EXPECT_STREQ((*any)->name(), "cpu");
    EXPECT_NE(notice.find("CPU reference"), std::string::npos) << notice;
  }
}

}  // namespace
}  // namespace zona
