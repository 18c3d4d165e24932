// The device-resident injection step on the GPU against the CPU runner: a whole mouse injection
// to puncture (force curve, contacts, puncture step), the blow-up stop, and the step path
// without allocation. Skips without a usable CUDA device.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>

#include <nlohmann/json.hpp>

#include "engine/scene/scene.h"
#include "engine/sim/simulation.h"
#include "kernels/backend_factory.h"
#include "kernels/cuda_backend.h"
#include "tests/engine/allocation_counter.h"
#include "tests/engine/test_scenes.h"

namespace zona {
namespace {

bool have_device(std::string* why) {
  Result<std::unique_ptr<Backend>> probe = make_cuda_backend(BackendOptions{});
  if (!probe) *why = probe.error().message;
  return probe.ok();
}

SimulationOptions gpu_options() {
  SimulationOptions o;
  o.backend_factory = [](std::string* notice) {
    return make_backend(BackendKind::kCuda, BackendOptions{}, notice);
  };
  return o;
}

Scene mouse_scene() {
  Result<Scene> scene = load_scene(std::string(ZONA_SOURCE_DIR) + "/scenes/mouse_oocyte.json",
                                   {"output.frames=0"});
  EXPECT_TRUE(scene.ok()) << (scene.ok() ? "" : scene.error().message);
  return *scene;
}

// `scene` run to its end on the CPU and as the GPU's job; false, with the failure reported,
// where either could not be built or stopped early.
struct CpuGpuRuns {
  std::unique_ptr<Simulation> cpu, gpu;
  RunResult on_cpu, on_gpu;
};
bool run_on_both(const Scene& scene, CpuGpuRuns* out) {
  Result<std::unique_ptr<Simulation>> cpu = Simulation::create(scene);
  Result<std::unique_ptr<Simulation>> gpu = Simulation::create(scene, gpu_options());
  EXPECT_TRUE(cpu.ok() && gpu.ok());
  if (!cpu.ok() || !gpu.ok()) return false;
  EXPECT_TRUE((*gpu)->job_mode());
  out->cpu = std::move(*cpu);
  out->gpu = std::move(*gpu);
  out->on_cpu = run_simulation(*out->cpu);
  out->on_gpu = run_simulation(*out->gpu);
  EXPECT_FALSE(out->on_cpu.stopped_early) << out->on_cpu.stop_reason;
  EXPECT_FALSE(out->on_gpu.stopped_early) << out->on_gpu.stop_reason;
  return !out->on_cpu.stopped_early && !out->on_gpu.stopped_early;
}

TEST(CudaJob, MouseInjectionToPunctureMatchesCpu) {
  std::string why;
  if (!have_device(&why)) GTEST_SKIP() << why;
  const Scene scene = mouse_scene();
  Result<std::unique_ptr<Simulation>> cpu = Simulation::create(scene);
  Result<std::unique_ptr<Simulation>> gpu = Simulation::create(scene, gpu_options());
  ASSERT_TRUE(cpu.ok() && gpu.ok());
  ASSERT_TRUE((*gpu)->job_mode());
  ASSERT_NE((*gpu)->backend_description().find("device-resident"), std::string::npos);
  RunOptions ro;
  ro.stop_after_puncture = 1e-3;
  const RunResult rc = run_simulation(**cpu, ro), rg = run_simulation(**gpu, ro);
  ASSERT_FALSE(rc.stopped_early) << rc.stop_reason;
  ASSERT_FALSE(rg.stopped_early) << rg.stop_reason;
  ASSERT_TRUE(rc.puncture.punctured && rg.puncture.punctured);
  // Before the puncture the curves agree: the force averaged over each 2 um of deformation
  // (float32 element forces on the GPU and contact onsets a step apart make single samples
  // differ; the curve does not), up to 28 um. Past 30 um SVK elements under the tip reach their
  // compression clamp and the force jitters by 10-15 % from sample to sample: there two CPU runs
  // that differ only in the summation order of the needle's quadrature points differ by 12-14 %
  // (measured), so the bins there compare rounding, not backends.
  // The holding force (the rim with its damper, and the suction) the same way.
  constexpr int kBins = 14;
  double sum_c[kBins] = {}, sum_g[kBins] = {}, hold_c[kBins] = {}, hold_g[kBins] = {};
  int n_c[kBins] = {}, n_g[kBins] = {};
  auto bin = [](const RunResult& r, double* sum, double* hold, int* n) {
    for (const ForceSample& s : r.samples) {
      if (s.punctured) break;
      const int b = static_cast<int>(s.deformation / 2e-6);
      if (b >= 0 && b < kBins) {
        sum[b] += s.force;
        hold[b] += s.holding_force;
        ++n[b];
      }
    }
  };
  bin(rc, sum_c, hold_c, n_c);
  bin(rg, sum_g, hold_g, n_g);
  double worst = 0, worst_hold = 0;
  int compared = 0;
  for (int b = 0; b < kBins; ++b) {
    if (n_c[b] < 5 || n_g[b] < 5) continue;
    worst = std::max(worst, std::fabs(sum_c[b] / n_c[b] - sum_g[b] / n_g[b]));
    worst_hold = std::max(worst_hold, std::fabs(hold_c[b] / n_c[b] - hold_g[b] / n_g[b]));
    ++compared;
  }
  std::printf("[ measured ] cpu vs cuda: puncture at step %lld / %lld, deformation %.3g / %.3g um, "
              "%.4g / %.4g uN; worst 2 um-binned force difference %.3g of the peak over %d bins, "
              "holding force %.3g\n",
              static_cast<long long>(rc.puncture.step), static_cast<long long>(rg.puncture.step),
              rc.puncture.deformation * 1e6, rg.puncture.deformation * 1e6,
              rc.puncture.force * 1e6, rg.puncture.force * 1e6, worst / rc.peak_force, compared,
              worst_hold / rc.peak_force);
  EXPECT_GT(compared, 8);
  EXPECT_LT(worst, 0.05 * rc.peak_force);
  EXPECT_LT(worst_hold, 0.05 * rc.peak_force);
  // The same puncture: deformation within 5 %. The force at that instant carries the curve's
  // ripple (past 30 um SVK elements reach their compression clamp and the filtered force swings
  // by +-10-15 % from sample to sample; two CPU runs that differ only in summation order fired at
  // 4.85 and 4.04 uN): the GPU's puncture force must be one the CPU's own curve takes within
  // 2 um of deformation before its puncture.
  EXPECT_NEAR(rg.puncture.deformation, rc.puncture.deformation, 0.05 * rc.puncture.deformation);
  double lo = rc.puncture.force, hi = rc.puncture.force;
  for (const ForceSample& s : rc.samples) {
    if (s.punctured || s.deformation < rc.puncture.deformation - 2e-6) continue;
    lo = std::min(lo, s.force);
    hi = std::max(hi, s.force);
  }
  std::printf("[ measured ] cpu force within 2 um before its puncture: %.4g .. %.4g uN\n", lo * 1e6,
              hi * 1e6);
  EXPECT_GE(rg.puncture.force, 0.95 * lo);
  EXPECT_LE(rg.puncture.force, 1.05 * hi);
}

TEST(CudaJob, BlowUpStopsWithoutAPuncture) {
  std::string why;
  if (!have_device(&why)) GTEST_SKIP() << why;
  Result<Scene> scene = parse_scene(test::small_cell_scene(), "small_cell");
  ASSERT_TRUE(scene.ok());
  scene->integrator.stiffness_damping = 400e-6;  // unstable lagged damping (job_test.cpp)
  scene->puncture.criterion = PunctureCriterion::kForce;
  scene->puncture.threshold = 1e-6;
  Result<std::unique_ptr<Simulation>> gpu = Simulation::create(*scene, gpu_options());
  ASSERT_TRUE(gpu.ok());
  const RunResult run = run_simulation(**gpu);
  EXPECT_TRUE(run.stopped_early);
  EXPECT_NE(run.stop_reason.find("step "), std::string::npos) << run.stop_reason;
  EXPECT_FALSE(run.puncture.punctured);
}

TEST(CudaJob, NeedleThroughTheSurfaceStopsLikeTheCpu) {
  // The contact far too soft for the load (job_test.cpp's CPU case): the device's depth
  // reduction halts the job, with no puncture, at about the CPU's step.
  std::string why;
  if (!have_device(&why)) GTEST_SKIP() << why;
  Result<Scene> scene = parse_scene(test::small_cell_scene(), "small_cell");
  ASSERT_TRUE(scene.ok());
  scene->contact.stiffness = 1;
  scene->puncture.criterion = PunctureCriterion::kForce;
  scene->puncture.threshold = 1.0;  // never met
  Result<std::unique_ptr<Simulation>> cpu = Simulation::create(*scene);
  Result<std::unique_ptr<Simulation>> gpu = Simulation::create(*scene, gpu_options());
  ASSERT_TRUE(cpu.ok() && gpu.ok());
  const RunResult rc = run_simulation(**cpu);
  const RunResult rg = run_simulation(**gpu);
  ASSERT_TRUE(rc.stopped_early);
  ASSERT_TRUE(rg.stopped_early);
  EXPECT_NE(rg.stop_reason.find("went through the cell surface"), std::string::npos)
      << rg.stop_reason;
  EXPECT_FALSE(rg.puncture.punctured);
  EXPECT_NEAR(static_cast<double>(rg.steps), static_cast<double>(rc.steps),
              0.05 * static_cast<double>(rc.steps));
}

TEST(CudaJob, FastNeedleRaisesMassesWithoutAddingEnergy) {
  // job_test.cpp's fast needle on the 10k fine cell: the device's mass raise keeps the momentum
  // as the CPU's does, so the run goes its 3 ms without a blow-up, like the CPU's.
  std::string why;
  if (!have_device(&why)) GTEST_SKIP() << why;
  Result<Scene> scene =
      load_scene(std::string(ZONA_SOURCE_DIR) + "/scenes/mouse_oocyte_fine.json",
                 {"mesh.generate.vertices=10000", "needle.speed=10mm/s", "integrator.duration=3ms",
                  "output.frames=0"});
  ASSERT_TRUE(scene.ok()) << scene.error().message;
  Result<std::unique_ptr<Simulation>> cpu = Simulation::create(*scene);
  Result<std::unique_ptr<Simulation>> gpu = Simulation::create(*scene, gpu_options());
  ASSERT_TRUE(cpu.ok() && gpu.ok());
  const RunResult rc = run_simulation(**cpu), rg = run_simulation(**gpu);
  ASSERT_FALSE(rc.stopped_early) << rc.stop_reason;
  EXPECT_FALSE(rg.stopped_early) << rg.stop_reason;
  EXPECT_GT(rg.mass_raises, 0);
  EXPECT_NEAR(rg.peak_force, rc.peak_force, 0.1 * rc.peak_force);
}

TEST(CudaJob, NodalPressureInjectionMatchesCpu) {
  // The fine scene's physics with nodal pressure on a 3000-vertex cell, 15 um of travel: the
  // device's two element passes per step against the CPU's, with the scene's drift damping
  // (the momentum summed over the device's blocks, the load applied by the vertex kernel).
  std::string why;
  if (!have_device(&why)) GTEST_SKIP() << why;
  Result<Scene> scene =
      load_scene(std::string(ZONA_SOURCE_DIR) + "/scenes/mouse_oocyte_fine.json",
                 {"mesh.generate.vertices=3000", "volumetric=nodal", "needle.max_travel=15um",
                  "puncture.criterion=none", "output.frames=0"});
  ASSERT_TRUE(scene.ok()) << scene.error().message;
  CpuGpuRuns runs;
  ASSERT_TRUE(run_on_both(*scene, &runs));
  const RunResult &rc = runs.on_cpu, &rg = runs.on_gpu;
  ASSERT_GT(rc.peak_force, 0);
  std::printf("[ measured ] nodal-pressure job peak force cpu %.4g uN gpu %.4g uN\n",
              rc.peak_force * 1e6, rg.peak_force * 1e6);
  EXPECT_NEAR(rg.peak_force, rc.peak_force, 0.02 * rc.peak_force);
  EXPECT_NEAR(rg.peak_deformation, rc.peak_deformation, 0.02 * rc.peak_deformation);
}

TEST(CudaJob, TheStepPathDoesNotAllocate) {
  std::string why;
  if (!have_device(&why)) GTEST_SKIP() << why;
  if (test::allocation_count() < 0) GTEST_SKIP() << "no allocation count in this build";
  Result<Scene> scene = parse_scene(test::small_cell_scene(), "small_cell");
  ASSERT_TRUE(scene.ok());
  Result<std::unique_ptr<Simulation>> gpu = Simulation::create(*scene, gpu_options());
  ASSERT_TRUE(gpu.ok());
  // The first steps capture the graphs: steps handed over one at a time go out in eights, at
  // step indices 0, 4 and 8 modulo 12; a long run in 48s.
  for (int i = 0; i < 100; ++i) (*gpu)->step();
  ASSERT_TRUE((*gpu)->job()->advance(96).ok());
  for (int i = 0; i < 100; ++i) (*gpu)->step();
  const long long before = test::allocation_count();
  for (int i = 0; i < 300; ++i) (*gpu)->step();
  EXPECT_EQ(test::allocation_count() - before, 0);
  ASSERT_TRUE((*gpu)->sync_state().ok());
}

// The strain criterion and a scripted path on the GPU against the CPU: the small cell pushed
// along a path that bends sideways part way, punctured where the stretch around the tip reaches
// 4 %. The stretch comes from the same function on both (float32 displacements on the GPU): the
// puncture lands within a few steps and at the same strain.
TEST(CudaJob, StrainCriterionOnAPathMatchesCpu) {
  std::string why;
  if (!have_device(&why)) GTEST_SKIP() << why;
  const std::string path = ::testing::TempDir() + "zona_cuda_path.csv";
  {
    std::FILE* f = std::fopen(path.c_str(), "w");
    ASSERT_NE(f, nullptr);
    // The small cell's needle starts 0.5 um off the surface at -12.5 um on x, moving +x.
    std::fprintf(f, "time_s,x_m,y_m,z_m\n0,-12.5e-6,0,0\n0.015,-9.5e-6,0,0\n0.03,-7e-6,1e-6,0\n");
    std::fclose(f);
  }
  nlohmann::json j = test::small_cell_scene();
  j["model"] = "neohookean";
  j["needle"]["trajectory"] = path;
  j["integrator"]["duration"] = "30 ms";
  j["puncture"] = {{"criterion", "strain"}, {"threshold", 0.04}, {"force_drop", 0.5}};
  Result<Scene> scene = parse_scene(j, "small_cell_path");
  ASSERT_TRUE(scene.ok()) << scene.error().message;
  CpuGpuRuns runs;
  ASSERT_TRUE(run_on_both(*scene, &runs));
  const RunResult &rc = runs.on_cpu, &rg = runs.on_gpu;
  ASSERT_TRUE(rc.puncture.punctured && rg.puncture.punctured);
  EXPECT_NEAR(rg.puncture.time, rc.puncture.time, 5 * runs.cpu->model().dt);
  EXPECT_GE(rg.puncture.max_strain, 0.04);
  EXPECT_NEAR(rg.puncture.max_strain, rc.puncture.max_strain, 0.002);
  EXPECT_NEAR(rg.puncture.force, rc.puncture.force, 0.03 * rc.puncture.force);
  // Both followed the path: the CPU's last record is the run's end, the GPU's latest published
  // one a few steps before it, each with the path's tip at its time.
  auto path_y = [](double t) { return t <= 0.015 ? 0.0 : 1e-6 * std::min(1.0, (t - 0.015) / 0.015); };
  EXPECT_NEAR(runs.cpu->report().tip.y, 1e-6, 1e-12);
  EXPECT_GT(runs.gpu->report().time, 0.025);
  EXPECT_NEAR(runs.gpu->report().tip.y, path_y(runs.gpu->report().time), 1e-12);
  std::remove(path.c_str());
}

TEST(CudaJob, AHandedInTipIsFollowedStepByStep) {
  // The haptic path: a hand 10 um ahead, handed over every step. The device takes the pose up
  // from its mailbox every few steps; the job's tip follows it at the speed limit one step at a
  // time, as on the CPU, never in jumps: after 480 steps the travel is the limit's, less the
  // few steps before the mailbox was first read, and every record moved it by at most v dt.
  std::string why;
  if (!have_device(&why)) GTEST_SKIP() << why;
  Result<Scene> scene =
      load_scene(std::string(ZONA_SOURCE_DIR) + "/scenes/mouse_oocyte_fine.json",
                 {"mesh.generate.vertices=3000", "output.frames=0"});
  ASSERT_TRUE(scene.ok()) << scene.error().message;
  SimulationOptions options = gpu_options();
  options.external_tip_max_speed = 1e-3;
  Result<std::unique_ptr<Simulation>> gpu = Simulation::create(*scene, options);
  ASSERT_TRUE(gpu.ok()) << gpu.error().message;
  Simulation& s = **gpu;
  ASSERT_TRUE(s.job_mode());
  const Vec3d start = s.needle_script().start, axis = s.needle_script().direction;
  const int steps = 480;
  const double v = 1e-3;
  double time = -1, travel = 0;
  int records = 0;
  for (int i = 0; i < steps; ++i) {
    s.step1();
    s.set_needle_tip(start + 10e-6 * axis);
    ASSERT_FALSE(s.step2() & kStepFailed);
    // Each record the host sees (the latest, however many steps apart) moved the tip by at
    // most the limit over its time.
    const NeedleReport& r = s.report();
    if (r.time > time) {
      if (time >= 0) {
        ASSERT_LE(r.travel - travel, v * (r.time - time) * (1 + 1e-6) + 1e-15) << "step " << i;
        ++records;
      }
      time = r.time;
      travel = r.travel;
    }
  }
  ASSERT_TRUE(s.sync_state().ok());
  const double dt = s.model().dt;
  EXPECT_GT(records, 10);
  EXPECT_LE(s.report().travel, steps * v * dt * (1 + 1e-9));
  EXPECT_GE(s.report().travel, (steps - 32) * v * dt);
}

}  // namespace
}  // namespace zona
