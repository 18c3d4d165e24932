// End-to-end tests of `zona run`: the files it writes, their columns and keys, and its errors.
#include <gtest/gtest.h>

#include <algorithm>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <string>

#include <nlohmann/json.hpp>

#include "tests/apps/cli_runner.h"

namespace {

using zona::test::CliRun;
using zona::test::run_zona;
using zona::test::TempDir;

namespace fs = std::filesystem;

// A small held cell punctured early: runs in a fraction of a second.
const char* kScene = R"({
  "name": "tiny_injection",
  "mesh": {"generate": {"diameter": "20 um", "vertices": 150}},
  "model": "svk",
  "materials": {"default": {"young": "10 kPa", "poisson": 0.45, "damping": "50 1/s"}},
  "integrator": {"target_dt": "20 us", "mass_scaling_mode": "selective", "dt_safety": 0.25,
                 "stiffness_damping": "100 us"},
  "needle": {"tip_radius": "2 um", "standoff": "0.5 um", "speed": "0.5 mm/s", "max_travel": "5 um"},
  "puncture": {"criterion": "force", "threshold": "0.05 uN", "force_drop": 0.9, "drop_time": "0.1 ms"},
  "holding_pipette": {"mode": "fixed", "inner_radius": "5 um"},
  "output": {"frames": 4, "sample_interval": "0.1 ms"}
})";

TEST(CmdRun, WritesCurveSummaryFramesAndPlot) {
  TempDir dir;
  const fs::path scene = dir.path / "tiny.json";
  std::ofstream(scene) << kScene;
  const fs::path out = dir.path / "out";
  const CliRun r = run_zona("run " + scene.string() + " --headless --out " + out.string(), dir.path);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_NE(r.out.find("puncture: t "), std::string::npos) << r.out;
  EXPECT_NE(r.err.find("zona run: t "), std::string::npos) << r.err;  // progress line
  // force.csv: the documented leading columns and one row per sample.
  std::ifstream csv(out / "force.csv");
  std::string header, line;
  std::getline(csv, header);
  EXPECT_EQ(header.rfind("time_s,needle_travel_m,deformation_m,force_N", 0), 0u) << header;
  int rows = 0;
  while (std::getline(csv, line)) ++rows;
  EXPECT_GT(rows, 50);
  // summary.json: model, puncture, peak force, training metrics, numerics.
  std::ifstream js(out / "summary.json");
  const nlohmann::json j = nlohmann::json::parse(js);
  EXPECT_EQ(j["model"], "svk");
  EXPECT_FALSE(j["interrupted"].get<bool>());
  EXPECT_FALSE(fs::exists(out / "summary.json.tmp"));
  ASSERT_TRUE(j["puncture"]["punctured"].get<bool>());
  for (const char* key : {"time_s", "deformation_m", "force_N"})
    EXPECT_TRUE(j["puncture"].contains(key)) << key;
  EXPECT_GE(j["puncture"]["force_N"].get<double>(), 0.05e-6);
  EXPECT_GT(j["peak_force_N"].get<double>(), 0.0);
  for (const char* key : {"mean_insertion_speed_m_per_s", "deformation_at_puncture_percent_of_diameter",
                          "force_fluctuation_mfar_percent"})
    EXPECT_TRUE(j["training"].contains(key)) << key;
  for (const char* key : {"steps", "dt_s", "mass_scaling", "wall_time_s"})
    EXPECT_TRUE(j["numerics"].contains(key)) << key;
  EXPECT_TRUE(fs::exists(out / "frames.pvd"));
  EXPECT_TRUE(fs::exists(out / "frames_000003.vtu"));
  EXPECT_TRUE(fs::exists(out / "scene.json"));
  EXPECT_TRUE(fs::exists(out / "force_deformation.png"));
}

TEST(CmdRun, SetOverridesAndModelChoice) {
  TempDir dir;
  const fs::path scene = dir.path / "tiny.json";
  std::ofstream(scene) << kScene;
  const fs::path out = dir.path / "linear";
  const CliRun r = run_zona("run " + scene.string() + " --out " + out.string() +
                                   " --set model=linear --set puncture.criterion=none --no-frames --quiet",
                               dir.path);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_EQ(r.err.find("zona run: t "), std::string::npos);  // --quiet
  std::ifstream js(out / "summary.json");
  const nlohmann::json j = nlohmann::json::parse(js);
  EXPECT_EQ(j["model"], "linear");
  EXPECT_FALSE(j["puncture"]["punctured"].get<bool>());
  EXPECT_FALSE(fs::exists(out / "frames.pvd"));
}

TEST(CmdRun, ErrorsAreOneLine) {
  TempDir dir;
  CliRun r = run_zona("run no_such_scene --out " + (dir.path / "x").string(), dir.path);
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_EQ(r.err.rfind("zona: error: ", 0), 0u) << r.err;
  const fs::path scene = dir.path / "tiny.json";
  std::ofstream(scene) << kScene;
  r = run_zona("run " + scene.string() + " --set needle.speed=fast --out " + (dir.path / "y").string(),
               dir.path);
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_NE(r.err.find("needle.speed"), std::string::npos) << r.err;
  r = run_zona("run " + scene.string() + " --backend gpu --out " + (dir.path / "z").string(), dir.path);
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_NE(r.err.find("auto, cpu or cuda"), std::string::npos) << r.err;
}

// --frames DIR renders numbered PNG frames (headless Vulkan) as the run goes; a build or machine
// without the renderer says so in one line instead.
TEST(CmdRun, PngFramesDuringTheRun) {
  TempDir dir;
  const fs::path scene = dir.path / "tiny.json";
  std::ofstream(scene) << kScene;
  const fs::path frames = dir.path / "png";
  const CliRun r =
      run_zona("run " + scene.string() + " --out " + (dir.path / "out").string() + " --frames " +
                   frames.string() + " --frame-count 3 --frame-color stress --quiet",
               dir.path);
#if defined(ZONA_HAVE_VULKAN)
  if (r.exit_code != 0 && r.err.find("Vulkan") != std::string::npos) GTEST_SKIP() << r.err;
  ASSERT_EQ(r.exit_code, 0) << r.err;
  for (const char* name : {"frame_00000.png", "frame_00001.png", "frame_00002.png"}) {
    ASSERT_TRUE(fs::exists(frames / name)) << name;
    EXPECT_GT(fs::file_size(frames / name), 1000u) << name;
  }
  EXPECT_FALSE(fs::exists(frames / "frame_00003.png"));
  // --frame-count also sets the VTU frames.
  EXPECT_TRUE(fs::exists(dir.path / "out" / "frames_000002.vtu"));
#else
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_EQ(std::count(r.err.begin(), r.err.end(), '\n'), 1) << r.err;
  EXPECT_NE(r.err.find("built without the Vulkan renderer"), std::string::npos) << r.err;
#endif
  const CliRun bad = run_zona("run " + scene.string() + " --out " + (dir.path / "b").string() +
                                     " --frame-count -2 --quiet",
                                 dir.path);
  EXPECT_EQ(bad.exit_code, 1);
  EXPECT_NE(bad.err.find("--frame-count"), std::string::npos) << bad.err;
}

}  // namespace
