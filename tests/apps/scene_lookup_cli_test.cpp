// End-to-end tests of the scene lookup every command shares (apps/main.cpp, find_scene_file):
// ./scenes before $ZONA_SCENES_DIR before the source tree, the file used printed and recorded.
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <string>

#include <nlohmann/json.hpp>

#include "tests/apps/cli_runner.h"

namespace {

namespace fs = std::filesystem;
using zona::test::CliRun;
using zona::test::run_zona_after;
using zona::test::TempDir;

// A scene that is not valid JSON: every command that reads it fails naming the file it found.
void write_broken(const fs::path& path) {
  fs::create_directories(path.parent_path());
  std::ofstream(path) << "{\n  \"version\": 1,\n  oops\n}\n";
}

// The commands that take a scene, each with the scene named "probe".
const char* const kCommands[] = {
    "run probe --out OUT",
    "study convergence probe --vertices 300 --out OUT",
    "calibrate probe --data DATA --fit materials.default.young",
    "haptics probe --device scripted --duration 0.01",
    "mesh generate --scene probe --out OUT/m.msh",
#if defined(ZONA_HAVE_VULKAN)
    "render probe --out OUT/f.png",
    "view probe --close-after 0.01",
#endif
};

std::string with_paths(std::string command, const fs::path& root) {
  for (auto [key, value] : {std::pair<std::string, std::string>{"OUT", (root / "out").string()},
                            {"DATA", (root / "data.csv").string()}}) {
    for (size_t at = command.find(key); at != std::string::npos; at = command.find(key, at + 1))
      command.replace(at, key.size(), value);
  }
  return command;
}

TEST(SceneLookupCli, EveryCommandTakesTheWorkingFoldersScenesFirst) {
  TempDir dir;
  std::ofstream(dir.path / "data.csv") << "deformation_m,force_N\n1e-6,1e-6\n2e-6,2e-6\n";
  write_broken(dir.path / "work/scenes/probe.json");
  write_broken(dir.path / "env/probe.json");
  const std::string local = fs::absolute(dir.path / "work/scenes/probe.json").lexically_normal();
  const std::string prefix =
      "cd " + (dir.path / "work").string() + " && ZONA_SCENES_DIR=" + (dir.path / "env").string();
  for (const char* c : kCommands) {
    const CliRun r = run_zona_after(prefix, with_paths(c, dir.path), dir.path);
    EXPECT_EQ(r.exit_code, 1) << c << "\n" << r.err;
    EXPECT_NE(r.err.find(local + ": line 3"), std::string::npos) << c << "\n" << r.err;
  }
}

TEST(SceneLookupCli, EveryCommandFallsBackToTheEnvironmentFolder) {
  TempDir dir;
  std::ofstream(dir.path / "data.csv") << "deformation_m,force_N\n1e-6,1e-6\n2e-6,2e-6\n";
  fs::create_directories(dir.path / "work");
  write_broken(dir.path / "env/probe.json");
  const std::string env = fs::absolute(dir.path / "env/probe.json").lexically_normal();
  const std::string prefix =
      "cd " + (dir.path / "work").string() + " && ZONA_SCENES_DIR=" + (dir.path / "env").string();
  for (const char* c : kCommands) {
    const CliRun r = run_zona_after(prefix, with_paths(c, dir.path), dir.path);
    EXPECT_EQ(r.exit_code, 1) << c << "\n" << r.err;
    EXPECT_NE(r.err.find(env + ": line 3"), std::string::npos) << c << "\n" << r.err;
  }
}

TEST(SceneLookupCli, ShippedScenesAreFoundOutsideTheClone) {
  // `zona haptics mouse_oocyte` from a folder with no scenes/ (the trainer case): the
  // installed or source-tree scenes give it. A bad --duration after the lookup keeps it short.
  TempDir dir;
  const CliRun r = run_zona_after("cd " + dir.path.string() + " && ZONA_SCENES_DIR=",
                                  "haptics mouse_oocyte_haptic --device scripted --duration 0.05 "
                                  "--set needle.speed=fast",
                                  dir.path);
  EXPECT_EQ(r.exit_code, 1) << r.err;
  EXPECT_NE(r.err.find("scenes/mouse_oocyte_haptic.json"), std::string::npos) << r.err;
  EXPECT_NE(r.err.find("needle.speed"), std::string::npos) << r.err;
}

TEST(SceneLookupCli, RunPrintsAndRecordsTheSceneFileUsed) {
  // An edited copy in ./scenes is the one that runs, named on stdout and in summary.json (also
  // under --quiet).
  TempDir dir;
  std::ifstream shipped(std::string(ZONA_SOURCE_DIR) + "/scenes/bench_ball.json");
  nlohmann::json scene = nlohmann::json::parse(shipped);
  scene["name"] = "edited_ball";
  fs::create_directories(dir.path / "scenes");
  std::ofstream(dir.path / "scenes/bench_ball.json") << scene.dump(2);
  const std::string used = fs::absolute(dir.path / "scenes/bench_ball.json").lexically_normal();
  const fs::path out = dir.path / "out";
  const CliRun r = run_zona_after("cd " + dir.path.string() + " &&",
                                  "run bench_ball --no-frames --quiet "
                                  "--set mesh.generate.vertices=500 --out " + out.string(),
                                  dir.path);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_NE(r.out.find("scene: edited_ball (" + used + ")"), std::string::npos) << r.out;
  std::ifstream js(out / "summary.json");
  const nlohmann::json summary = nlohmann::json::parse(js);
  EXPECT_EQ(summary["scene_file"], used);
  EXPECT_EQ(summary["scene"], "edited_ball");
}

}  // namespace
