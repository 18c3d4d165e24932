// A whole FEM injection on the GPU against the CPU reference: contact, holding pipette and
// stiffness damping; and the prescribed boundary's host step through the CUDA backend (loads
// that change every step, carried by Backend::set_external_forces). Skips without a usable
// CUDA device.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <nlohmann/json.hpp>

#include "engine/scene/scene.h"
#include "engine/sim/simulation.h"
#include "kernels/backend_factory.h"
#include "kernels/cuda_backend.h"
#include "tests/engine/test_scenes.h"

namespace zona {
namespace {

TEST(CudaSimulation, InjectionWithStiffnessDampingMatchesCpu) {
  {
    Result<std::unique_ptr<Backend>> probe = make_cuda_backend(BackendOptions{});
    if (!probe) GTEST_SKIP() << probe.error().message;
  }
  // tests/engine/sim/simulation_test.cpp runs the same cell on the CPU paths; 4 um of travel here.
  nlohmann::json j = test::small_cell_scene();
  j["needle"]["max_travel"] = "4 um";
  Result<Scene> scene = parse_scene(j, "cuda_simulation.json");
  ASSERT_TRUE(scene.ok()) << scene.error().message;
  ASSERT_GT(scene->integrator.stiffness_damping, 0.0);
  SimulationOptions gpu_options, cpu_options;
  gpu_options.threads = cpu_options.threads = 1;
  gpu_options.backend_factory = [](std::string* notice) {
    return make_backend(BackendKind::kCuda, BackendOptions{}, notice);
  };
  Result<std::unique_ptr<Simulation>> cpu = Simulation::create(*scene, cpu_options);
  Result<std::unique_ptr<Simulation>> gpu = Simulation::create(*scene, gpu_options);
  ASSERT_TRUE(cpu.ok() && gpu.ok());
  ASSERT_NE((*gpu)->backend_description().find("cuda"), std::string::npos);
  const RunResult rc = run_simulation(**cpu), rg = run_simulation(**gpu);
  ASSERT_EQ(rc.samples.size(), rg.samples.size());
  ASSERT_GT(rc.peak_force, 0.0);
  double worst = 0;
  size_t contacts_differ = 0;
  for (size_t i = 0; i < rc.samples.size(); ++i) {
    worst = std::max(worst, std::fabs(rc.samples[i].force - rg.samples[i].force));
    contacts_differ += rc.samples[i].contacts != rg.samples[i].contacts;
  }
  std::printf("[ measured ] cpu vs cuda: peak force %.6g / %.6g N, worst force difference %.3g of "
              "the peak, %zu of %zu samples with other contact counts\n",
              rc.peak_force, rg.peak_force, worst / rc.peak_force, contacts_differ,
              rc.samples.size());
  // float32 element forces on the GPU (4e-7 relative per evaluation): the curves agree to a
  // fraction of a percent of the peak and the contact sets at nearly every sample.
  EXPECT_LT(worst, 5e-3 * rc.peak_force);
  EXPECT_LE(contacts_differ, rc.samples.size() / 20);
  EXPECT_NEAR(rg.peak_deformation, rc.peak_deformation, 1e-3 * rc.peak_deformation);
}

TEST(CudaSimulation, PrescribedBoundaryBlowUpStopsLikeTheCpu) {
  // simulation_test.cpp's unstable stiffness damping on the prescribed boundary's host step (the
  // benchmark ball's indented patch), through the CUDA backend: the energy test (its budget
  // without the damping loads' work) stops the run at the blow-up, before anything is
  // non-finite.
  {
    Result<std::unique_ptr<Backend>> probe = make_cuda_backend(BackendOptions{});
    if (!probe) GTEST_SKIP() << probe.error().message;
  }
  Result<Scene> scene = load_scene(std::string(ZONA_SOURCE_DIR) + "/scenes/bench_ball.json",
                                   {"mesh.generate.vertices=600", "integrator.duration=0.2 ms",
                                    "integrator.stiffness_damping=400 ns"});
  ASSERT_TRUE(scene.ok()) << scene.error().message;
  SimulationOptions options;
  options.backend_factory = [](std::string* notice) {
    return make_backend(BackendKind::kCuda, BackendOptions{}, notice);
  };
  Result<std::unique_ptr<Simulation>> gpu = Simulation::create(*scene, options);
  ASSERT_TRUE(gpu.ok()) << gpu.error().message;
  ASSERT_FALSE((*gpu)->job_mode());
  const RunResult r = run_simulation(**gpu);
  EXPECT_TRUE(r.stopped_early);
  EXPECT_TRUE(r.status & kStepEnergyBlowUp) << r.stop_reason;
  EXPECT_FALSE(r.status & kStepNonFinite) << r.stop_reason;
}

}  // namespace
}  // namespace zona
