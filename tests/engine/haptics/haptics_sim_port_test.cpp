// SimulationHapticPort: the haptic session's simulation side, stepped here without threads so
// that the commands reach the simulation at chosen steps (a session's timing, replayed exactly).
#include "engine/haptics/haptics_sim_port.h"

#include <gtest/gtest.h>

#include <string>

#include "engine/scene/scene.h"
#include "engine/sim/simulation.h"

namespace zona {
namespace {

std::unique_ptr<Simulation> haptic_cell() {
  Result<Scene> scene = load_scene(std::string(ZONA_SOURCE_DIR) + "/scenes/mouse_oocyte_haptic.json");
  EXPECT_TRUE(scene.ok()) << scene.error().message;
  SimulationOptions so;
  so.threads = 1;
  Result<std::unique_ptr<Simulation>> sim = Simulation::create(*scene, so);
  EXPECT_TRUE(sim.ok()) << sim.error().message;
  return std::move(*sim);
}

// Steps the port `steps` times; the hand (at its home, the needle's start) sends its first
// command at step `first_command`. Returns the steps taken before a failure (all: none).
int64_t replay(int64_t first_command, int64_t steps, std::string* failure) {
  std::unique_ptr<Simulation> sim = haptic_cell();
  SimulationHapticPort port(*sim, 20 * sim->scene().needle.speed, false);
  ToolCommand home;
  home.sequence = 1;
  home.tool = sim->needle_script().start;
  HapticSample sample;
  for (int64_t k = 0; k < steps; ++k) {
    const HapticPortStatus s = port.step(k >= first_command ? &home : nullptr, sample);
    if (s != HapticPortStatus::kStepped) {
      *failure = port.failure();
      return k;
    }
  }
  return steps;
}

TEST(SimulationHapticPort, TheHapticSceneRunsOnThePenaltyStep) {
  // One engine (docs/architecture.md): the haptic scene steps through the job's stages (the
  // penalty contact), as every FEM scene with a needle does; the hand's pose enters between
  // step1 and step2 through JobRunner::set_tip.
  std::unique_ptr<Simulation> sim = haptic_cell();
  EXPECT_TRUE(sim->job_mode());
  EXPECT_EQ(sim->scene().contact.model, ContactModel::kPenalty);
}

TEST(SimulationHapticPort, TheHapticScenePuncturesWhereThePenaltyStepPutsIt) {
  // The scene scripted at 0.1 mm/s to its energy criterion (1.5e-10 J). Re-derived when the
  // scene moved from the kinematic contact (41.8 um / 8.7 uN) to the penalty step, measured on
  // this 300-vertex cell: 42.4 um of deformation at 10.2 uN (43.3 um of travel). The penalty
  // contact's pressure acts over the surface triangles the tip covers, so the stretched membrane
  // past 30 um carries more load at the same deformation than the three to five vertices the
  // kinematic contact held (up to 25 % more; the curves agree within 1 uN to 30 um). The band
  // is the run's own point within a few percent (the physics, not the rounding, moves it), and
  // Ladjal et al.'s 45 um must stay within 10 %.
  Result<Scene> scene =
      load_scene(std::string(ZONA_SOURCE_DIR) + "/scenes/mouse_oocyte_haptic.json",
                 {"integrator.duration=0.52s", "output.frames=0"});
  ASSERT_TRUE(scene.ok()) << scene.error().message;
  RunOptions options;
  options.simulation.threads = 1;
  options.stop_after_puncture = 0;
  Result<RunResult> run = run_scene(*scene, options);
  ASSERT_TRUE(run.ok()) << run.error().message;
  ASSERT_FALSE(run->stopped_early) << run->stop_reason;
  ASSERT_TRUE(run->puncture.punctured);
  EXPECT_NEAR(run->puncture.deformation, 42.4e-6, 1.0e-6);
  EXPECT_NEAR(run->puncture.force, 10.2e-6, 0.5e-6);
  EXPECT_NEAR(run->puncture.deformation, 45e-6, 4.5e-6);
  EXPECT_NEAR(run->puncture.energy, 1.5e-10, 0.02e-10);
}

TEST(SimulationHapticPort, TheFirstCommandsTimingDoesNotChangeTheSteps) {
  // Recorded on a loaded machine: about one start in ten to twenty, the haptic thread's first
  // command reached the simulation after step ~100, by when the needle had followed the scene's
  // script through its 1 um standoff onto the membrane; the tip was then pulled back to the
  // hand in one jump and the cell blew up (energy) at the next step. The port now holds the tip
  // at the start until the hand commands, so that session runs through, and its steps do not
  // depend on when the first command came.
  for (const int64_t first : {0, 105, 150, 300}) {
    std::string failure;
    EXPECT_EQ(replay(first, 1500, &failure), 1500) << "first command at step " << first << ": "
                                                   << failure;
  }
}

TEST(SimulationHapticPort, AFailedStepIsReportedWithItsStepAndReason) {
  // A hand command 30 um into the cell taken in one step (no speed limit) blows the cell up.
  std::unique_ptr<Simulation> sim = haptic_cell();
  SimulationHapticPort port(*sim, 1e9, false);
  ToolCommand deep;
  deep.sequence = 1;
  deep.tool = sim->needle_script().start + 30e-6 * sim->needle_script().direction;
  HapticSample sample;
  HapticPortStatus s = HapticPortStatus::kStepped;
  int64_t k = 0;
  for (; k < 200 && s == HapticPortStatus::kStepped; ++k) s = port.step(&deep, sample);
  ASSERT_EQ(s, HapticPortStatus::kFailed);
  EXPECT_EQ(port.steps(), k - 1);
  EXPECT_NE(port.failure().find("the simulation failed at step " + std::to_string(k)),
            std::string::npos)
      << port.failure();
  // Once failed it stays failed: nothing more is stepped or published.
  EXPECT_EQ(port.step(&deep, sample), HapticPortStatus::kFailed);
  EXPECT_EQ(port.steps(), k - 1);
}

}  // namespace
}  // namespace zona
