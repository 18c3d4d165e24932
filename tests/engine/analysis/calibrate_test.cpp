// Calibration: the curve error on hand-made curves, the CSV reader, --fit parsing, and the
// recovery of a known Young's modulus from a curve zona made itself.
#include "engine/analysis/calibrate.h"

#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <fstream>

#include <nlohmann/json.hpp>

#include "engine/scene/scene.h"

namespace zona {
namespace {

namespace fs = std::filesystem;

fs::path temp_file(const std::string& name, const std::string& text) {
  const fs::path p = fs::temp_directory_path() /
                     ("zona_calibrate_" + std::to_string(::testing::UnitTest::GetInstance()->random_seed()) +
                      "_" + name);
  std::ofstream(p) << text;
  return p;
}

RunResult curve_run(std::initializer_list<std::pair<double, double>> points, bool punctured_after) {
  RunResult run;
  for (const auto& [d, f] : points) {
    ForceSample s;
    s.deformation = d;
    s.force = f;
    run.samples.push_back(s);
  }
  if (punctured_after) {
    ForceSample s;
    s.deformation = run.samples.back().deformation * 0.5;
    s.force = 0.1 * run.samples.back().force;
    s.punctured = true;
    run.samples.push_back(s);
    run.puncture.punctured = true;
  }
  return run;
}

TEST(Calibrate, CurveErrorByHand) {
  ForceCurve data{{1.0, 2.0, 3.0}, {1.0, 2.0, 3.0}};
  // The same line: no error.
  EXPECT_NEAR(force_curve_error(curve_run({{0, 0}, {4, 4}}, false), data, false).rms, 0.0, 1e-15);
  // Twice as stiff: residuals 1, 2, 3 -> rms sqrt(14 / 3); data rms sqrt(14 / 3): relative 1.
  CurveError e = force_curve_error(curve_run({{0, 0}, {4, 8}}, false), data, false);
  EXPECT_NEAR(e.rms, std::sqrt(14.0 / 3.0), 1e-12);
  EXPECT_NEAR(e.relative, 1.0, 1e-12);
  EXPECT_EQ(e.points, 3);
  // Punctured at 2: the data's point at 3 meets a force of 0 (residual 3).
  e = force_curve_error(curve_run({{0, 0}, {2, 2}}, true), data, true);
  EXPECT_NEAR(e.rms, std::sqrt(9.0 / 3.0), 1e-12);
  // Still loading past the data's puncture at 3 (spacing 3 / 20): charged its force at 3.15,
  // 3.3, ... 4.95 (13 points of force d).
  e = force_curve_error(curve_run({{0, 0}, {5, 5}}, false), data, true);
  EXPECT_EQ(e.points, 3 + 13);
  double sum = 0;
  for (int k = 1; k <= 13; ++k) sum += (3.0 + 0.15 * k) * (3.0 + 0.15 * k);
  EXPECT_NEAR(e.rms, std::sqrt(sum / 16.0), 1e-9);
  // ... unless the data does not end in a puncture.
  EXPECT_NEAR(force_curve_error(curve_run({{0, 0}, {5, 5}}, false), data, false).rms, 0.0, 1e-15);
}

TEST(Calibrate, ReadsCurveCsvAndNamesBadLines) {
  const fs::path good = temp_file("good.csv", "# digitised\ndeformation_m,force_N\n1e-6,2e-7\n2e-6,5e-7\n");
  Result<ForceCurve> c = read_force_curve_csv(good.string());
  ASSERT_TRUE(c.ok()) << c.error().message;
  ASSERT_EQ(c->deformation.size(), 2u);
  EXPECT_DOUBLE_EQ(c->force[1], 5e-7);
  const fs::path bad = temp_file("bad.csv", "deformation_m,force_N\n1e-6,2e-7\n0.5e-6,x\n");
  Result<ForceCurve> b = read_force_curve_csv(bad.string());
  ASSERT_FALSE(b.ok());
  EXPECT_NE(b.error().message.find(":3:"), std::string::npos) << b.error().message;
  const fs::path header = temp_file("header.csv", "d,f\n1,2\n");
  EXPECT_FALSE(read_force_curve_csv(header.string()).ok());
  fs::remove(good);
  fs::remove(bad);
  fs::remove(header);
}

TEST(Calibrate, ParsesFitRangesAndDefaults) {
  const nlohmann::json scene = nlohmann::json::parse(
      R"({"materials": {"default": {"young": "20 kPa", "poisson": 0.45}}})");
  Result<FitParameter> p = parse_fit_parameter("materials.default.young=10kPa..40kPa", scene);
  ASSERT_TRUE(p.ok()) << p.error().message;
  EXPECT_DOUBLE_EQ(p->lower, 1e4);
  EXPECT_DOUBLE_EQ(p->upper, 4e4);
  EXPECT_EQ(fit_override(*p, 12345.5), "materials.default.young=12345.5 Pa");
  p = parse_fit_parameter("materials.default.young", scene);
  ASSERT_TRUE(p.ok()) << p.error().message;
  EXPECT_DOUBLE_EQ(p->lower, 5e3);
  EXPECT_DOUBLE_EQ(p->upper, 8e4);
  EXPECT_FALSE(parse_fit_parameter("materials.default.young=40kPa..10kPa", scene).ok());
  EXPECT_FALSE(parse_fit_parameter("materials.default.young=1kPa..2um", scene).ok());
  EXPECT_FALSE(parse_fit_parameter("materials.zona.young", scene).ok());
}

// A small held cell pushed 4 um (a few hundred steps per run).
const char* kScene = R"({
  "name": "calibrate_ball",
  "mesh": {"generate": {"diameter": "20 um", "vertices": 150}},
  "model": "svk",
  "materials": {"default": {"young": "10 kPa", "poisson": 0.45, "damping": "50 1/s"}},
  "integrator": {"target_dt": "20 us", "mass_scaling_mode": "selective", "dt_safety": 0.25,
                 "stiffness_damping": "100 us"},
  "needle": {"tip_radius": "2 um", "standoff": "0.5 um", "speed": "0.5 mm/s", "max_travel": "4 um"},
  "holding_pipette": {"mode": "fixed", "inner_radius": "5 um"},
  "contact": {"model": "kinematic"},
  "output": {"frames": 0, "sample_interval": "0.1 ms"}
})";

TEST(Calibrate, RecoversTheModulusOfItsOwnCurve) {
  const fs::path scene_path = temp_file("ball.json", kScene);
  // The synthetic measurement: the scene at E = 13 kPa, every 4th sample of its loading curve.
  // The scene's kinematic contact: this tests the fit, on a curve of a coarse ball that the
  // penalty contact does not resolve (engine/sim/job.h: the surface must resolve the tip).
  Result<Scene> truth = load_scene(scene_path.string(), {"materials.default.young=13kPa"});
  ASSERT_TRUE(truth.ok()) << truth.error().message;
  Result<RunResult> run = run_scene(*truth);
  ASSERT_TRUE(run.ok()) << run.error().message;
  ForceCurve data;
  for (size_t i = 4; i < run->samples.size(); i += 4) {
    const ForceSample& s = run->samples[i];
    if (s.deformation > (data.deformation.empty() ? 0.2e-6 : data.deformation.back() + 1e-9)) {
      data.deformation.push_back(s.deformation);
      data.force.push_back(s.force);
    }
  }
  ASSERT_GE(data.deformation.size(), 5u);

  Result<FitParameter> p = parse_fit_parameter("materials.default.young=4kPa..40kPa", nlohmann::json::object());
  ASSERT_TRUE(p.ok());
  CalibrateOptions options;
  options.data_punctures = false;
  options.tolerance = 5e-3;
  options.grid_points = 5;
  options.run.simulation.threads = 1;
  Result<CalibrationResult> r = calibrate(scene_path.string(), {}, {*p}, data, options);
  ASSERT_TRUE(r.ok()) << r.error().message;
  EXPECT_TRUE(r->converged);
  // Forces scale with E at a given deformation, so the curve pins E: within 2 %.
  EXPECT_NEAR(r->best.values[0], 13e3, 0.02 * 13e3);
  EXPECT_LT(r->best.error.relative, 0.02);
  // The wrong ends of the range are far worse than the fit.
  EXPECT_GT(r->history.front().error.relative, 10 * r->best.error.relative);
  fs::remove(scene_path);
}

TEST(Calibrate, BoundTheSceneRejectsIsAnError) {
  const fs::path scene_path = temp_file("reject.json", kScene);
  FitParameter p{"materials.default.poisson", 0.3, 0.7, Dimension{}};
  ForceCurve data{{1e-6, 2e-6}, {1e-7, 2e-7}};
  Result<CalibrationResult> r = calibrate(scene_path.string(), {}, {p}, data);
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.error().message.find("poisson"), std::string::npos) << r.error().message;
  fs::remove(scene_path);
}

}  // namespace
}  // namespace zona
