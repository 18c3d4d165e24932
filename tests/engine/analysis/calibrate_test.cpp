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

// A simulated curve through the points (deformation, force), punctured after its last or not.
SimulatedCurve simulated(std::initializer_list<std::pair<double, double>> points, bool punctured,
                         double peak = 0) {
  SimulatedCurve c;
  for (const auto& [d, f] : points) {
    c.loading.deformation.push_back(d);
    c.loading.force.push_back(f);
  }
  c.loading.punctured = punctured;
  c.puncture_force = punctured ? c.loading.force.back() : 0.0;
  c.peak_force = peak;
  return c;
}

TEST(Calibrate, ResidualsByHand) {
  ForceCurve data;
  data.deformation = {1.0, 2.0, 3.0};
  data.force = {1.0, 2.0, 3.0};
  const ForceCurve one[] = {data};
  // The same line: no error.
  EXPECT_NEAR(force_curve_error(simulated({{0, 0}, {4, 4}}, false), one).rms, 0.0, 1e-15);
  // Twice as stiff: residuals 1, 2, 3 -> rms sqrt(14 / 3); data rms sqrt(14 / 3): relative 1.
  CurveError e = force_curve_error(simulated({{0, 0}, {4, 8}}, false), one);
  EXPECT_NEAR(e.rms, std::sqrt(14.0 / 3.0), 1e-12);
  EXPECT_NEAR(e.relative, 1.0, 1e-12);
  EXPECT_EQ(e.points, 3);
  EXPECT_EQ(e.puncture_terms, 0);
  // Punctured at 2: the data's point at 3 meets a force of 0 (residual -3), and is counted as
  // past the run's reach; no point is added.
  e = force_curve_error(simulated({{0, 0}, {2, 2}}, true), one);
  EXPECT_EQ(e.points, 3);
  EXPECT_EQ(e.past_reach, 1);
  EXPECT_NEAR(e.rms, std::sqrt(9.0 / 3.0), 1e-12);
  // A run still loading past the data: the data's own points only (no puncture assumed).
  EXPECT_NEAR(force_curve_error(simulated({{0, 0}, {5, 5}}, false, 5), one).rms, 0.0, 1e-15);
  // Told that the data ends at its puncture (force 3): one more residual, the run's peak (it did
  // not puncture) minus 3.
  ForceCurve punctured = data;
  punctured.punctured = true;
  const std::vector<double> r = curve_residuals(simulated({{0, 0}, {5, 5}}, false, 5), punctured);
  ASSERT_EQ(r.size(), 4u);
  EXPECT_NEAR(r[3], 2.0, 1e-15);
  const ForceCurve both[] = {punctured};
  e = force_curve_error(simulated({{0, 0}, {5, 5}}, false, 5), both);
  EXPECT_EQ(e.points, 4);
  EXPECT_EQ(e.puncture_terms, 1);
}

TEST(Calibrate, ReadsZonasOwnForceCsvLoadingBranch) {
  // Rows at 0 before contact, a step back, then the puncture: the branch is the advancing rows
  // before the first punctured one, and the curve knows it ends at a puncture.
  const fs::path f = temp_file("force.csv",
                               "# zona force.csv schema 3 (docs/outputs.md)\n"
                               "time_s,deformation_m,force_N,punctured\n"
                               "0,0,0,0\n0.1,0,0,0\n0.2,1e-6,1e-7,0\n0.3,0.9e-6,0.9e-7,0\n"
                               "0.4,2e-6,2e-7,0\n0.5,3e-6,3e-7,0\n0.6,3.1e-6,0,1\n0.7,3.2e-6,0,1\n");
  Result<ForceCurve> c = read_force_curve_csv(f.string());
  ASSERT_TRUE(c.ok()) << c.error().message;
  EXPECT_EQ(c->deformation, (std::vector<double>{1e-6, 2e-6, 3e-6}));
  EXPECT_TRUE(c->punctured);
  EXPECT_EQ(c->rows, 8);
  EXPECT_EQ(c->after_puncture, 2);
  EXPECT_EQ(c->not_advancing, 3);
  // Without a punctured column, a measured curve's deformation must increase.
  const fs::path m = temp_file("measured.csv", "deformation_m,force_N\n0,0\n0,1e-7\n");
  Result<ForceCurve> bad = read_force_curve_csv(m.string());
  ASSERT_FALSE(bad.ok());
  EXPECT_NE(bad.error().message.find("measured.csv:3: deformation_m must increase"), std::string::npos)
      << bad.error().message;
  fs::remove(f);
  fs::remove(m);
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

// A small held cell pushed 4 um by a blunt tip (a few hundred steps per run).
const char* kScene = R"({
  "name": "calibrate_ball",
  "mesh": {"generate": {"diameter": "20 um", "vertices": 150}},
  "model": "svk",
  "materials": {"default": {"young": "10 kPa", "poisson": 0.45, "damping": "50 1/s"}},
  "integrator": {"target_dt": "20 us", "mass_scaling_mode": "selective", "dt_safety": 0.25,
                 "stiffness_damping": "100 us"},
  "needle": {"tip_radius": "6 um", "standoff": "0.5 um", "speed": "0.5 mm/s", "max_travel": "4 um"},
  "holding_pipette": {"mode": "fixed", "inner_radius": "5 um"},
  "output": {"frames": 0, "sample_interval": "0.1 ms"}
})";

TEST(Calibrate, RecoversTheModulusOfItsOwnCurve) {
  const fs::path scene_path = temp_file("ball.json", kScene);
  // The synthetic measurement: the scene at E = 13 kPa, every 4th sample of its loading curve.
  // A tip wider than the coarse ball's surface edges (about 4 um), which the penalty on the
  // surface triangles then holds up.
  Result<Scene> truth = load_scene(scene_path.string(), {"materials.default.young=13kPa"});
  ASSERT_TRUE(truth.ok()) << truth.error().message;
  Result<RunResult> run = run_scene(*truth);
  ASSERT_TRUE(run.ok()) << run.error().message;
  ForceCurve data;
  data.source = "every 4th sample";
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
  options.tolerance = 5e-3;
  options.grid_points = 5;
  options.run.simulation.threads = 1;
  const ForceCurve curves[] = {data};
  Result<CalibrationResult> r = calibrate(scene_path.string(), {}, {*p}, curves, options);
  ASSERT_TRUE(r.ok()) << r.error().message;
  EXPECT_TRUE(r->converged);
  // Forces scale with E at a given deformation, so the curve pins E: within 2 %.
  EXPECT_NEAR(r->best.values[0], 13e3, 0.02 * 13e3);
  EXPECT_LT(r->best.error.relative, 0.02);
  // The wrong ends of the range are far worse than the fit.
  EXPECT_GT(r->history.front().error.relative, 10 * r->best.error.relative);
  // One curve: no interval (a bootstrap needs whole curves to resample), but a curvature
  // correlation (1 x 1) and a history with its roles.
  EXPECT_TRUE(r->interval_lower.empty());
  EXPECT_NE(r->interval_note.find("one curve"), std::string::npos) << r->interval_note;
  ASSERT_EQ(r->curvature_correlation.size(), 1u);
  EXPECT_EQ(r->history.front().role, "scan");
  fs::remove(scene_path);
}

TEST(Calibrate, BoundTheSceneRejectsIsAnError) {
  const fs::path scene_path = temp_file("reject.json", kScene);
  FitParameter p{"materials.default.poisson", 0.3, 0.7, Dimension{}};
  ForceCurve data;
  data.deformation = {1e-6, 2e-6};
  data.force = {1e-7, 2e-7};
  const ForceCurve curves[] = {data};
  Result<CalibrationResult> r = calibrate(scene_path.string(), {}, {p}, curves);
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.error().message.find("poisson"), std::string::npos) << r.error().message;
  fs::remove(scene_path);
}

}  // namespace
}  // namespace zona
