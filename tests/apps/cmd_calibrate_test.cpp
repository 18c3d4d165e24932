// End-to-end tests of `zona calibrate`: the JSON it prints and its one-line errors.
#include <gtest/gtest.h>

#include <cstdio>
#include <filesystem>
#include <fstream>
#include <string>

#include <nlohmann/json.hpp>

#include "tests/apps/cli_runner.h"

namespace {

using zona::test::CliRun;
using zona::test::run_zona;

namespace fs = std::filesystem;

fs::path temp_path(const std::string& name) {
  return fs::temp_directory_path() /
         ("zona_cmd_calibrate_" + std::to_string(::testing::UnitTest::GetInstance()->random_seed()) +
          "_" + ::testing::UnitTest::GetInstance()->current_test_info()->name() + "_" + name);
}

// A small held cell pushed 3 um (a fraction of a second per run). Its contact is the softer
// 100: this 150-vertex cell pushed at 0.5 mm/s on a 20 us step is far from quasi-static, and on
// the default 1000 its surface bounces off the tip (the force drops to zero every other sample),
// which leaves the fit nothing to compare.
const char* kScene = R"({
  "name": "calibrate_cli",
  "mesh": {"generate": {"diameter": "20 um", "vertices": 150}},
  "model": "svk",
  "materials": {"default": {"young": "10 kPa", "poisson": 0.45, "damping": "50 1/s"}},
  "integrator": {"target_dt": "20 us", "mass_scaling_mode": "selective", "dt_safety": 0.25,
                 "stiffness_damping": "100 us"},
  "needle": {"tip_radius": "2 um", "standoff": "0.5 um", "speed": "0.5 mm/s", "max_travel": "3 um"},
  "holding_pipette": {"mode": "fixed", "inner_radius": "5 um"},
  "contact": {"stiffness": 100},
  "output": {"frames": 0, "sample_interval": "0.1 ms"}
})";

TEST(CmdCalibrate, PrintsFittedValuesAndErrorsAsJson) {
  const fs::path scene = temp_path("scene.json"), data = temp_path("data.csv");
  std::ofstream(scene) << kScene;
  // A stiff, made-up curve: the fit goes to the top of the range, the error stays large.
  std::ofstream(data) << "deformation_m,force_N\n1e-6,1e-6\n2e-6,2e-6\n";
  const CliRun r = run_zona("calibrate " + scene.string() + " --data " + data.string() +
                               " --fit materials.default.young=5kPa..20kPa --no-puncture"
                               " --max-evaluations 7 --threads 1 --json");
  ASSERT_EQ(r.exit_code, 0) << r.err;
  const nlohmann::json j = nlohmann::json::parse(r.out);
  EXPECT_EQ(j["evaluations"], 7);  // the 7-point scan only
  EXPECT_FALSE(j["converged"].get<bool>());
  const double young = j["fitted"]["materials.default.young"].get<double>();
  EXPECT_NEAR(young, 20e3, 1.0);  // the stiffest end is the closest to a too-stiff curve
  EXPECT_GT(j["rms_error_N"].get<double>(), 0.0);
  EXPECT_GT(j["relative_error"].get<double>(), 0.1);
  // One line per run on stderr.
  size_t lines = 0;
  for (size_t p = r.err.find("zona calibrate: run"); p != std::string::npos;
       p = r.err.find("zona calibrate: run", p + 1))
    ++lines;
  EXPECT_EQ(lines, 7u);
  fs::remove(scene);
  fs::remove(data);
}

TEST(CmdCalibrate, BadArgumentsAreOneLineErrors) {
  const fs::path scene = temp_path("scene.json"), data = temp_path("data.csv");
  std::ofstream(scene) << kScene;
  std::ofstream(data) << "deformation_m,force_N\n1e-6,1e-6\n2e-6,2e-6\n";
  CliRun r = run_zona("calibrate " + scene.string() + " --data " + data.string() +
                         " --fit materials.default.young=20kPa..5kPa");
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_NE(r.err.find("LO < HI"), std::string::npos) << r.err;
  r = run_zona("calibrate " + scene.string() + " --data /no/such.csv --fit materials.default.young");
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_NE(r.err.find("/no/such.csv"), std::string::npos) << r.err;
  r = run_zona("calibrate " + scene.string() + " --data " + data.string() + " --fit materials.nucleus.young");
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_NE(r.err.find("materials.nucleus.young"), std::string::npos) << r.err;
  // The scene's JSON is read with load_scene's bounds: a file nested 100,000 deep is one line.
  const fs::path deep = temp_path("deep.json");
  std::ofstream(deep) << std::string(100000, '[');
  r = run_zona("calibrate " + deep.string() + " --data " + data.string() +
               " --fit materials.default.young");
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_NE(r.err.find(deep.string() + ": nested deeper than 64 levels"), std::string::npos)
      << r.err;
  fs::remove(deep);
  fs::remove(scene);
  fs::remove(data);
}

}  // namespace
