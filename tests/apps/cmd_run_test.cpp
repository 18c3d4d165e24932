// End-to-end tests of `zona run`: the files it writes, their columns and keys, its errors, and
// a run stopped by a signal.
#include <gtest/gtest.h>

#include <algorithm>
#include <chrono>
#include <csignal>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <string>
#include <thread>
#include <tuple>
#include <vector>

#include <nlohmann/json.hpp>

#include "engine/analysis/plot.h"
#include "engine/mesh/xdmf_writer.h"
#include "engine/sim/recorder.h"
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
  std::string schema, header, line;
  std::getline(csv, schema);
  EXPECT_EQ(schema.rfind("# zona force.csv schema ", 0), 0u) << schema;
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
  // Provenance: what ran, where, when, from which build.
  EXPECT_EQ(j["schema_version"], 7);
  EXPECT_EQ(j["solver"], "explicit");
  EXPECT_EQ(j["backend_kind"], "cpu");
  const nlohmann::json& p = j["provenance"];
  EXPECT_EQ(p["command"].get<std::string>(),
            std::string(ZONA_CLI_PATH) + " run " + scene.string() + " --headless --out " +
                out.string());
  EXPECT_EQ(p["date_utc"].get<std::string>().size(), 20u);
  EXPECT_TRUE(p["commit"].is_string());
  EXPECT_FALSE(p["zona_version"].get<std::string>().empty());
  EXPECT_FALSE(p["machine"]["hostname"].get<std::string>().empty());
  EXPECT_FALSE(p["machine"]["cpu_model"].get<std::string>().empty());
  EXPECT_TRUE(p["machine"]["gpu"].is_null());
}

// The frames of the run hold the rest positions: a frame is a mesh zona reads again, as the
// scene's mesh.file, and gives the run the generated mesh gives.
TEST(CmdRun, AFrameIsAMeshForTheNextRun) {
  TempDir dir;
  const fs::path scene = dir.path / "tiny.json";
  std::ofstream(scene) << kScene;
  const fs::path out = dir.path / "first";
  const CliRun a = run_zona("run " + scene.string() + " --quiet --out " + out.string(), dir.path);
  ASSERT_EQ(a.exit_code, 0) << a.err;
  const fs::path msh = dir.path / "generated.msh";
  const CliRun g = run_zona("mesh generate --scene " + scene.string() + " --out " + msh.string(), dir.path);
  ASSERT_EQ(g.exit_code, 0) << g.err;
  std::vector<nlohmann::json> summaries;
  for (const fs::path& file : {out / "frames_000003.vtu", msh}) {
    nlohmann::json next = nlohmann::json::parse(kScene);
    next["mesh"] = {{"file", file.string()}, {"unit", "m"}};
    const fs::path scene2 = dir.path / "from_file.json";
    std::ofstream(scene2) << next.dump(2);
    const fs::path out2 = dir.path / ("from_" + file.extension().string().substr(1));
    const CliRun b = run_zona("run " + scene2.string() + " --quiet --out " + out2.string(), dir.path);
    ASSERT_EQ(b.exit_code, 0) << b.err;
    std::ifstream js(out2 / "summary.json");
    summaries.push_back(nlohmann::json::parse(js));
  }
  std::ifstream j1(out / "summary.json");
  const nlohmann::json first = nlohmann::json::parse(j1);
  EXPECT_EQ(summaries[0]["mesh"], first["mesh"]);
  // The same rest shape as the generated mesh's, to the last bit (a deformed frame would not be).
  EXPECT_EQ(summaries[0]["cell_diameter_m"], summaries[1]["cell_diameter_m"]);
  EXPECT_EQ(summaries[0]["peak_force_N"], summaries[1]["peak_force_N"]);
}

// A rerun into the same folder: zona's earlier outputs go, the user's files stay.
TEST(CmdRun, RerunRemovesItsOwnEarlierOutputsOnly) {
  TempDir dir;
  const fs::path scene = dir.path / "tiny.json";
  std::ofstream(scene) << kScene;
  const fs::path out = dir.path / "out";
  const std::string base = "run " + scene.string() + " --quiet --out " + out.string();
  CliRun r = run_zona(base + " --frame-count 10", dir.path);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  ASSERT_TRUE(fs::exists(out / "frames_000009.vtu"));
  for (const char* user : {"notes.txt", "frames_mine.vtu", "force.csv.bak"})
    std::ofstream(out / user) << "mine\n";
  fs::create_directories(out / "plots");
  std::ofstream(out / "plots" / "force.csv") << "mine\n";

  auto frame_files = [&out] {
    std::vector<std::string> names;
    for (const auto& e : fs::directory_iterator(out)) {
      const std::string n = e.path().filename().string();
      if (n.rfind("frames_0", 0) == 0) names.push_back(n);
    }
    std::sort(names.begin(), names.end());
    return names;
  };
  auto user_files_intact = [&out] {
    for (const char* user : {"notes.txt", "frames_mine.vtu", "force.csv.bak"})
      EXPECT_TRUE(fs::exists(out / user)) << user;
    EXPECT_TRUE(fs::exists(out / "plots" / "force.csv"));
  };

  r = run_zona(base + " --frame-count 3", dir.path);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_EQ(frame_files(), (std::vector<std::string>{"frames_000000.vtu", "frames_000001.vtu",
                                                     "frames_000002.vtu"}));
  std::ifstream pvd(out / "frames.pvd");
  const std::string collection((std::istreambuf_iterator<char>(pvd)), std::istreambuf_iterator<char>());
  EXPECT_EQ(collection.find("frames_000003.vtu"), std::string::npos);
  user_files_intact();

  r = run_zona(base + " --no-frames", dir.path);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_TRUE(frame_files().empty());
  EXPECT_FALSE(fs::exists(out / "frames.pvd"));
  EXPECT_TRUE(fs::exists(out / "summary.json"));
  user_files_intact();
}

// Frames as an XDMF + HDF5 series: the two files instead of the VTU series (both with vtu+xdmf);
// a rerun with VTU frames removes them; a format the build cannot write is refused up front.
TEST(CmdRun, OutputFormatXdmfWritesTheSeriesAndRerunsRemoveIt) {
  TempDir dir;
  const fs::path scene = dir.path / "tiny.json";
  std::ofstream(scene) << kScene;
  const fs::path out = dir.path / "out";
  const std::string base = "run " + scene.string() + " --quiet --frame-count 3 --out " + out.string();
  CliRun r = run_zona(base + " --output-format bogus", dir.path);
  EXPECT_NE(r.exit_code, 0);
  EXPECT_NE(r.err.find("--output-format: \"bogus\" is not one of: vtu, xdmf, vtu+xdmf"),
            std::string::npos) << r.err;
  if (!zona::xdmf_supported()) {
    r = run_zona(base + " --output-format xdmf", dir.path);
    EXPECT_NE(r.exit_code, 0);
    EXPECT_NE(r.err.find("built without it"), std::string::npos) << r.err;
    r = run_zona(base + " --set output.format=xdmf", dir.path);
    EXPECT_NE(r.exit_code, 0);
    EXPECT_NE(r.err.find("output.format: XDMF output needs HDF5"), std::string::npos) << r.err;
    EXPECT_FALSE(fs::exists(out / "force.csv"));
    return;
  }
  r = run_zona(base + " --output-format xdmf", dir.path);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_TRUE(fs::exists(out / "frames.xdmf"));
  EXPECT_TRUE(fs::exists(out / "frames.h5"));
  EXPECT_FALSE(fs::exists(out / "frames.pvd"));
  EXPECT_FALSE(fs::exists(out / "frames_000000.vtu"));
  std::ifstream xdmf(out / "frames.xdmf");
  const std::string text((std::istreambuf_iterator<char>(xdmf)), std::istreambuf_iterator<char>());
  size_t grids = 0;
  for (size_t at = text.find("GridType=\"Uniform\""); at != std::string::npos;
       at = text.find("GridType=\"Uniform\"", at + 1))
    ++grids;
  EXPECT_EQ(grids, 3u);
  EXPECT_NE(text.find("REST positions"), std::string::npos);
  const nlohmann::json resolved = nlohmann::json::parse(std::ifstream(out / "scene.json"));
  EXPECT_EQ(resolved["output"]["format"], "xdmf");

  // Both: the same three frames in each series.
  r = run_zona(base + " --set output.format=vtu+xdmf", dir.path);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_TRUE(fs::exists(out / "frames.xdmf"));
  EXPECT_TRUE(fs::exists(out / "frames_000002.vtu"));

  // Back to VTU: the earlier series goes; a user's .h5 stays.
  std::ofstream(out / "mine.h5") << "mine\n";
  r = run_zona(base, dir.path);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_FALSE(fs::exists(out / "frames.xdmf"));
  EXPECT_FALSE(fs::exists(out / "frames.h5"));
  EXPECT_TRUE(fs::exists(out / "frames.pvd"));
  EXPECT_TRUE(fs::exists(out / "mine.h5"));
}

TEST(CmdRun, AFastNeedleOnAMassScaledCellIsNotAResult) {
  // The mouse cell on its suction holder, 1500 vertices, puncturing at 2 uN. At 0.1 mm/s it is
  // quasi-static and punctures; at 1 mm/s the mass-scaled cell's inertia carries the load (the
  // holder does not): the run warns when it happens, records no puncture, writes its outputs and
  // exits non-zero.
  TempDir dir;
  const std::string base = "run mouse_oocyte --no-frames --quiet --set mesh.generate.vertices=1500 "
                           "--set needle.max_travel=20um --set puncture.threshold=2uN ";
  const fs::path slow = dir.path / "slow", fast = dir.path / "fast";
  const CliRun a = run_zona(base + "--out " + slow.string(), dir.path);
  ASSERT_EQ(a.exit_code, 0) << a.err;
  EXPECT_NE(a.out.find("puncture: t "), std::string::npos) << a.out;
  std::ifstream sj(slow / "summary.json");
  const nlohmann::json s = nlohmann::json::parse(sj);
  EXPECT_EQ(s["quasi_static"], true);
  EXPECT_LT(s["quasi_static_check"]["worst_imbalance"].get<double>(), 0.2);

  const CliRun b = run_zona(base + "--set needle.speed=1mm/s --out " + fast.string(), dir.path);
  EXPECT_EQ(b.exit_code, 1) << b.err;
  EXPECT_NE(b.out.find("puncture: none"), std::string::npos) << b.out;
  EXPECT_NE(b.err.find("zona run: warning: not quasi-static from step"), std::string::npos) << b.err;
  EXPECT_NE(b.err.find("zona: error: the run was not quasi-static"), std::string::npos) << b.err;
  std::ifstream fj(fast / "summary.json");
  const nlohmann::json f = nlohmann::json::parse(fj);
  EXPECT_EQ(f["quasi_static"], false);
  EXPECT_FALSE(f["puncture"]["punctured"].get<bool>());
  EXPECT_GT(f["quasi_static_check"]["worst_imbalance"].get<double>(), 0.5);
  // The needle did push past the threshold force: only the check kept it from a puncture.
  EXPECT_GT(f["peak_force_N"].get<double>(), 2e-6);
}

TEST(CmdRun, BenchBallRunsThroughItsIndentation) {
  // The benchmark ball (an undamped 10 mm/s indentation) runs to its end without a blow-up.
  TempDir dir;
  const fs::path out = dir.path / "ball";
  const CliRun r = run_zona("run bench_ball --no-frames --quiet --set mesh.generate.vertices=1000 "
                            "--out " + out.string(),
                            dir.path);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  std::ifstream js(out / "summary.json");
  const nlohmann::json j = nlohmann::json::parse(js);
  EXPECT_FALSE(j["numerics"]["stopped_early"].get<bool>());
  EXPECT_NEAR(j["numerics"]["simulated_time_s"].get<double>(), 1e-3, 1e-6);
  EXPECT_GT(j["peak_force_N"].get<double>(), 0.0);  // the patch pressed into the ball
  EXPECT_TRUE(j["quasi_static"].is_null());          // no needle: nothing to judge
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

TEST(CmdRun, EndsWithTheNeedleWhenTheDurationIsForAHapticSession) {
  // mouse_oocyte_haptic keeps 3600 s for `zona haptics`; scripted, its needle stops after
  // max_travel / speed (2 um at 0.1 mm/s: 0.02 s) and `zona run` ends there, saying so.
  TempDir dir;
  const fs::path out = dir.path / "haptic";
  CliRun r = run_zona("run mouse_oocyte_haptic --no-frames --quiet --set needle.max_travel=2um "
                      "--out " + out.string(),
                      dir.path);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_NE(r.err.find("integrator.duration is 3600 s but the needle stops at 0.02 s"),
            std::string::npos)
      << r.err;
  std::ifstream js(out / "summary.json");
  const nlohmann::json j = nlohmann::json::parse(js);
  EXPECT_NEAR(j["numerics"]["simulated_time_s"].get<double>(), 0.02, 2e-4);
  // --full-duration simulates all of it (1.1 s here, past the 0.001 s of needle travel).
  const fs::path full = dir.path / "full";
  r = run_zona("run mouse_oocyte_haptic --no-frames --quiet --full-duration "
               "--set needle.max_travel=0.1um --set integrator.duration=1.1s --out " +
                   full.string(),
               dir.path);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_EQ(r.err.find("needle stops"), std::string::npos) << r.err;
  std::ifstream fjs(full / "summary.json");
  const nlohmann::json fj = nlohmann::json::parse(fjs);
  EXPECT_NEAR(fj["numerics"]["simulated_time_s"].get<double>(), 1.1, 2e-4);
}

TEST(CmdRun, MeshFileInTheWrongUnitIsAUnitError) {
  // The two-box fixture's coordinates are micrometre-sized numbers (0..3): read as metres the
  // "cell" is 3 m across. The error is about the unit, not a tool that does not fit.
  TempDir dir;
  nlohmann::json scene = nlohmann::json::parse(kScene);
  scene["mesh"] = {{"file", std::string(ZONA_TEST_DATA_DIR) + "/box2_v41_ascii.msh"}, {"unit", "m"}};
  const fs::path path = dir.path / "unit.json";
  std::ofstream(path) << scene.dump();
  const CliRun r = run_zona("run " + path.string() + " --out " + (dir.path / "o").string(), dir.path);
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_EQ(std::count(r.err.begin(), r.err.end(), '\n'), 1) << r.err;
  EXPECT_NE(r.err.find("mesh.unit: "), std::string::npos) << r.err;
  EXPECT_NE(r.err.find("micrometres"), std::string::npos) << r.err;
  EXPECT_EQ(r.err.find("holding"), std::string::npos) << r.err;
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
  // A scene nested 100,000 deep: one line naming the file, not a stack overflow.
  const fs::path deep = dir.path / "deep.json";
  std::ofstream(deep) << std::string(100000, '[') << std::string(100000, ']');
  r = run_zona("run " + deep.string() + " --out " + (dir.path / "d").string(), dir.path);
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_EQ(r.err, "zona: error: " + deep.string() +
                       ": nested deeper than 64 levels (line 1, column 65)\n");
}

// The lines of a file as it is on disk now.
std::vector<std::string> lines_of(const fs::path& path) {
  std::ifstream in(path);
  std::vector<std::string> lines;
  for (std::string line; std::getline(in, line);) lines.push_back(line);
  return lines;
}

// SIGTERM / SIGINT end the run at the next step: force.csv (streamed) holds the curve up to
// there, summary.json says interrupted, one line on stderr, exit 128 + the signal.
TEST(CmdRun, SignalStopsTheRunAndKeepsItsOutputs) {
  TempDir dir;
  const fs::path scene = dir.path / "tiny.json";
  std::ofstream(scene) << kScene;
  for (const auto& [sig, code, name] :
       {std::tuple{SIGTERM, 143, "SIGTERM"}, std::tuple{SIGINT, 130, "SIGINT"}}) {
    const fs::path out = dir.path / name;
    // 10 s of simulated time at 20 us steps: far longer than the test waits.
    zona::test::CliProcess p = zona::test::start_zona(
        "run " + scene.string() + " --out " + out.string() +
            " --no-frames --quiet --full-duration --set 'integrator.duration=10 s'",
        dir.path);
    ASSERT_GT(p.pid, 0);
    // Rows appear while the run goes: the header, the start, and a row flushed later.
    const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(120);
    size_t lines = 0;
    while (std::chrono::steady_clock::now() < deadline && !zona::test::has_exited(p)) {
      lines = lines_of(out / "force.csv").size();
      if (lines >= 4) break;
      std::this_thread::sleep_for(std::chrono::milliseconds(10));
    }
    ASSERT_GE(lines, 4u) << name << ": force.csv did not grow while the run went";
    ASSERT_EQ(::kill(p.pid, sig), 0);
    const CliRun r = zona::test::wait_zona(p, 60);
    EXPECT_EQ(r.exit_code, code) << r.err;
    EXPECT_NE(r.err.find(std::string("zona run: interrupted by ") + name), std::string::npos)
        << r.err;
    EXPECT_EQ(r.err.find("interrupted by"), r.err.rfind("interrupted by")) << r.err;  // once
    EXPECT_EQ(r.err.find("zona: error"), std::string::npos) << r.err;
    // force.csv: the header and whole rows, at least as many as were seen before the signal.
    const std::vector<std::string> csv = lines_of(out / "force.csv");
    ASSERT_GE(csv.size(), lines);
    ASSERT_GE(csv.size(), 2u);
    EXPECT_EQ(csv[0].rfind("# zona force.csv schema ", 0), 0u) << csv[0];
    EXPECT_EQ(csv[1].rfind("time_s,needle_travel_m,deformation_m,force_N", 0), 0u) << csv[1];
    // Whole rows: as many fields as the header.
    const auto header_commas = std::count(csv[1].begin(), csv[1].end(), ',');
    EXPECT_EQ(static_cast<size_t>(header_commas) + 1, zona::force_csv_columns().size());
    for (size_t i = 2; i < csv.size(); ++i)
      EXPECT_EQ(std::count(csv[i].begin(), csv[i].end(), ','), header_commas) << i << ": " << csv[i];
    // summary.json: whole, interrupted, its numbers up to the stop.
    std::ifstream js(out / "summary.json");
    const nlohmann::json j = nlohmann::json::parse(js, nullptr, /*allow_exceptions=*/false);
    ASSERT_FALSE(j.is_discarded());
    EXPECT_TRUE(j["interrupted"].get<bool>());
    EXPECT_EQ(j["numerics"]["samples"].get<size_t>(), csv.size() - 2);  // schema and header
    EXPECT_LT(j["numerics"]["simulated_time_s"].get<double>(), 10.0);
    EXPECT_FALSE(fs::exists(out / "summary.json.tmp"));
    EXPECT_TRUE(fs::exists(out / "scene.json"));
  }
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

// The plot: PNG and SVG drawn by python/zona_plot.py from the run's files (the scene's name,
// the run's puncture); without Python the built-in PNG, a note, no SVG, and the run succeeds.
TEST(CmdRun, PlotsThePunctureInPngAndSvgOrFallsBackWithoutPython) {
  TempDir dir;
  const fs::path scene = dir.path / "tiny.json";
  std::ofstream(scene) << kScene;
  const fs::path out = dir.path / "out";
  const std::string args = "run " + scene.string() + " --quiet --no-frames --out " + out.string();
  if (zona::test::plot_python_available()) {
    const CliRun r = run_zona(args, dir.path);
    ASSERT_EQ(r.exit_code, 0) << r.err;
    EXPECT_NE(r.out.find("force_deformation.png, force_deformation.svg}"), std::string::npos) << r.out;
    std::ifstream js(out / "summary.json");
    const nlohmann::json p = nlohmann::json::parse(js)["puncture"];
    ASSERT_TRUE(p["punctured"].get<bool>());
    char label[96];
    std::snprintf(label, sizeof label, ">puncture %.1f um, %.2f uN<",
                  p["deformation_m"].get<double>() * 1e6, p["force_N"].get<double>() * 1e6);
    const std::string svg = zona::test::read_text(out / "force_deformation.svg");
    for (const std::string& text : {std::string(label), std::string(">tiny_injection<"),
                                   std::string(">this run (svk)<"), std::string(">deformation [um]<"),
                                   std::string(">needle force [uN]<")})
      EXPECT_NE(svg.find(text), std::string::npos) << text;
  }
  // Without Python: the built-in writer, and the earlier run's SVG goes with its other outputs.
  const CliRun r = zona::test::run_zona_after("ZONA_PYTHON=/nonexistent/python3", args, dir.path);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_NE(r.err.find("plot: ZONA_PYTHON=/nonexistent/python3: no such file"), std::string::npos)
      << r.err;
  EXPECT_EQ(fs::exists(out / "force_deformation.png"), zona::plot_png_available());
  EXPECT_FALSE(fs::exists(out / "force_deformation.svg"));
}

}  // namespace
