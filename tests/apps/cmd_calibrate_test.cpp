// End-to-end tests of `zona calibrate`: the JSON it prints and its one-line errors.
#include <gtest/gtest.h>

#include <cstdio>
#include <filesystem>
#include <fstream>
#include <string>
#include <utility>
#include <vector>

#include <nlohmann/json.hpp>

#include "engine/analysis/calibrate.h"
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

// The engine test's scene (tests/engine/analysis/calibrate_test.cpp): a blunt tip pushed 4 um,
// a smooth curve that pins E; puncture off unless set.
const char* kFitScene = R"({
  "name": "calibrate_fit",
  "mesh": {"generate": {"diameter": "20 um", "vertices": 150}},
  "model": "svk",
  "materials": {"default": {"young": "10 kPa", "poisson": 0.45, "damping": "50 1/s"}},
  "integrator": {"target_dt": "20 us", "mass_scaling_mode": "selective", "dt_safety": 0.25,
                 "stiffness_damping": "100 us"},
  "needle": {"tip_radius": "6 um", "standoff": "0.5 um", "speed": "0.5 mm/s", "max_travel": "4 um"},
  "holding_pipette": {"mode": "fixed", "inner_radius": "5 um"},
  "output": {"frames": 0, "sample_interval": "0.1 ms"}
})";

TEST(CmdCalibrate, PrintsFittedValuesHistoryAndHonestCountsAsJson) {
  const fs::path scene = temp_path("scene.json"), data = temp_path("data.csv");
  std::ofstream(scene) << kScene;
  // A stiff, made-up curve of two points: the fit goes to the top of the range, the error stays
  // large, and two points are two points (nothing added past them, no puncture assumed).
  std::ofstream(data) << "deformation_m,force_N\n1e-6,1e-6\n2e-6,2e-6\n";
  const CliRun r = run_zona("calibrate " + scene.string() + " --data " + data.string() +
                            " --fit materials.default.young=5kPa..20kPa --max-evaluations 8 --jobs 2 --json");
  ASSERT_EQ(r.exit_code, 0) << r.err;
  const nlohmann::json j = nlohmann::json::parse(r.out);
  const double young = j["fitted"]["materials.default.young"].get<double>();
  EXPECT_NEAR(young, 20e3, 20.0);  // the stiffest end is the closest to a too-stiff curve
  EXPECT_GT(j["relative_error"].get<double>(), 0.1);
  EXPECT_EQ(j["points"]["loading_points"], 2);
  EXPECT_EQ(j["points"]["residuals"], 2);
  EXPECT_EQ(j["points"]["puncture_forces"], 0);
  EXPECT_TRUE(j["parameters"][0]["interval"].is_null());  // one curve: no interval
  // The history: every run, the scan first, as many as "evaluations", at most the budget.
  const nlohmann::json& h = j["history"];
  EXPECT_EQ(h.size(), j["evaluations"].get<size_t>());
  EXPECT_LE(h.size(), 8u);
  EXPECT_EQ(h[0]["role"], "scan");
  EXPECT_EQ(h[0]["values"]["materials.default.young"].get<double>(), 5e3);
  // One line per run on stderr.
  size_t lines = 0;
  for (size_t p = r.err.find("zona calibrate: run"); p != std::string::npos;
       p = r.err.find("zona calibrate: run", p + 1))
    ++lines;
  EXPECT_EQ(lines, h.size());
  fs::remove(scene);
  fs::remove(data);
}

// Rows of zona's force.csv on its loading branch as (deformation, force), every `stride`-th.
std::vector<std::pair<double, double>> loading_rows(const fs::path& force_csv, int stride) {
  zona::Result<zona::ForceCurve> c = zona::read_force_curve_csv(force_csv.string());
  EXPECT_TRUE(c.ok()) << c.error().message;
  std::vector<std::pair<double, double>> out;
  for (size_t i = 0; c.ok() && i < c->deformation.size(); i += static_cast<size_t>(stride))
    out.push_back({c->deformation[i], c->force[i]});
  return out;
}

TEST(CmdCalibrate, FitsItsOwnForceCsvAndRecoversAKnownModulusInsideItsInterval) {
  const fs::path scene = temp_path("scene.json"), truth = temp_path("truth");
  std::ofstream(scene) << kFitScene;
  // The truth: the scene at E = 13 kPa, zona's own force.csv.
  CliRun r = run_zona("run " + scene.string() + " --set materials.default.young=13kPa --out " + truth.string() +
                      " --quiet --no-frames --no-plot --threads 1");
  ASSERT_EQ(r.exit_code, 0) << r.err;
  // zona's force.csv as it is (its rows at 0 and after the end are left out, and counted).
  r = run_zona("calibrate " + scene.string() + " --data " + (truth / "force.csv").string() +
               " --fit materials.default.young=4kPa..40kPa --jobs 2 --threads 1");
  ASSERT_EQ(r.exit_code, 0) << r.err;
  const std::vector<std::pair<double, double>> all = loading_rows(truth / "force.csv", 1);
  EXPECT_NE(r.out.find("data: 1 curve, " + std::to_string(all.size()) + " points on the loading branch"),
            std::string::npos)
      << r.out;
  EXPECT_NE(r.out.find("over " + std::to_string(all.size()) + " residuals"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("interval: one curve"), std::string::npos) << r.out;
  // Four "cells": the truth's curve scaled by -6, -2, +3 and +5 % (cell-to-cell spread) with
  // every 3rd point, fitted jointly; the bootstrap over the curves gives E an interval that holds
  // 13 kPa.
  std::string data_args;
  const double spread[] = {-0.06, -0.02, 0.03, 0.05};
  for (int c = 0; c < 4; ++c) {
    const fs::path f = temp_path("cell" + std::to_string(c) + ".csv");
    std::ofstream out(f);
    out << "deformation_m,force_N\n";
    for (const auto& [d, force] : loading_rows(truth / "force.csv", 3)) out << d << "," << force * (1 + spread[c]) << "\n";
    data_args += " --data " + f.string();
  }
  r = run_zona("calibrate " + scene.string() + data_args +
               " --fit materials.default.young=4kPa..40kPa --jobs 2 --threads 1 --json");
  ASSERT_EQ(r.exit_code, 0) << r.err;
  const nlohmann::json j = nlohmann::json::parse(r.out);
  const nlohmann::json& p = j["parameters"][0];
  const double lo = p["interval"][0].get<double>(), hi = p["interval"][1].get<double>();
  EXPECT_LT(lo, 13e3);
  EXPECT_GT(hi, 13e3);
  EXPECT_LT(hi - lo, 0.2 * 13e3);  // the spread of the cells, not the whole range
  EXPECT_GT(hi - lo, 0.005 * 13e3);
  EXPECT_NEAR(p["value"].get<double>(), 13e3, 0.03 * 13e3);
  EXPECT_EQ(j["interval"]["replicates"], 200);
  EXPECT_EQ(j["points"]["curves"], 4);
  EXPECT_EQ(j["correlation"]["curvature"].size(), 1u);
  EXPECT_TRUE(j["converged"].get<bool>()) << j["stop_reason"];
  for (int c = 0; c < 4; ++c) fs::remove(temp_path("cell" + std::to_string(c) + ".csv"));
  fs::remove_all(truth);
  fs::remove(scene);
}

TEST(CmdCalibrate, APuncturedForceCsvAddsOnePunctureForce) {
  const fs::path scene = temp_path("scene.json"), truth = temp_path("truth");
  std::ofstream(scene) << kFitScene;
  CliRun r = run_zona("run " + scene.string() + " --set puncture.criterion=force --set puncture.threshold=0.08uN --out " +
                      truth.string() + " --quiet --no-frames --no-plot --threads 1");
  ASSERT_EQ(r.exit_code, 0) << r.err;
  ASSERT_NE(r.out.find("puncture: t"), std::string::npos) << r.out;
  r = run_zona("calibrate " + scene.string() + " --set puncture.criterion=force --data " +
               (truth / "force.csv").string() +
               " --fit puncture.threshold=0.04uN..0.16uN --max-evaluations 12 --json");
  ASSERT_EQ(r.exit_code, 0) << r.err;
  const nlohmann::json j = nlohmann::json::parse(r.out);
  EXPECT_TRUE(j["data"][0]["punctured"].get<bool>());
  EXPECT_GT(j["data"][0]["rows_after_puncture"].get<int>(), 0);
  EXPECT_EQ(j["points"]["puncture_forces"], 1);
  EXPECT_EQ(j["points"]["residuals"].get<int>(), j["points"]["loading_points"].get<int>() + 1);
  EXPECT_NEAR(j["fitted"]["puncture.threshold"].get<double>(), 0.08e-6, 0.08e-6 * 0.1);
  fs::remove_all(truth);
  fs::remove(scene);
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
