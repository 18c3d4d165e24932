// Tests for engine/convergence_study: the loading branch, forces at fixed deformations on
// hand-made curves, the force-drop metric, relative differences, the argument lists, the CSV
// text, and a two-size study of a small cell (a failing size is a row, not an error; a stop
// ends the running size and the study).
#include "engine/analysis/convergence_study.h"

#include <gtest/gtest.h>

#include <atomic>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>
#include <vector>

#include "tests/engine/test_scenes.h"

namespace zona {
namespace {

// A sample at deformation d [um] and force f [uN].
ForceSample sample(double d_um, double f_un, bool punctured = false) {
  ForceSample s;
  s.deformation = d_um * 1e-6;
  s.force = f_un * 1e-6;
  s.punctured = punctured;
  return s;
}

PunctureRecord puncture_at(double d_um, double f_un) {
  PunctureRecord p;
  p.punctured = true;
  p.deformation = d_um * 1e-6;
  p.force = f_un * 1e-6;
  return p;
}

// Lines of a CSV text that are not comments, split on commas.
std::vector<std::vector<std::string>> csv_rows(const std::string& text) {
  std::vector<std::vector<std::string>> rows;
  std::istringstream in(text);
  std::string line;
  while (std::getline(in, line)) {
    if (line.empty() || line[0] == '#') continue;
    std::vector<std::string> fields;
    for (size_t start = 0; start <= line.size();) {
      const size_t comma = std::min(line.find(',', start), line.size());
      fields.push_back(line.substr(start, comma - start));
      start = comma + 1;
    }
    rows.push_back(fields);
  }
  return rows;
}

TEST(ConvergenceStudy, LoadingBranchEndsAtPuncture) {
  const std::vector<ForceSample> samples = {sample(0, 0), sample(10, 2), sample(20, 4),
                                            sample(20, 0.4, true), sample(21, 0.3, true)};
  const std::vector<CurvePoint> branch = loading_branch(samples, puncture_at(22, 4.5));
  ASSERT_EQ(branch.size(), 4u);  // three samples, then the puncture point
  EXPECT_DOUBLE_EQ(branch[3].deformation, 22e-6);
  EXPECT_DOUBLE_EQ(branch[3].force, 4.5e-6);
  // Without a puncture: every sample.
  EXPECT_EQ(loading_branch(samples, PunctureRecord{}).size(), 3u);
}

TEST(ConvergenceStudy, LoadingBranchStopsAtANonFiniteSample) {
  const std::vector<ForceSample> samples = {sample(0, 0), sample(5, 1), sample(NAN, NAN),
                                            sample(6, 1.2)};
  const std::vector<CurvePoint> branch = loading_branch(samples, puncture_at(7, 2));
  EXPECT_EQ(branch.size(), 2u);  // the blow-up ends the branch, no puncture point after it
}

TEST(ConvergenceStudy, ForceAtDeformationInterpolatesTheLoadingBranch) {
  const std::vector<ForceSample> samples = {sample(0, 0),        sample(10, 2),
                                            sample(20, 6),       sample(30, 7),
                                            sample(25, 1, true), sample(45, 0.5, true)};
  const std::vector<CurvePoint> branch = loading_branch(samples, puncture_at(32, 7.5));
  EXPECT_NEAR(*force_at_deformation(branch, 5e-6), 1e-6, 1e-18);
  EXPECT_NEAR(*force_at_deformation(branch, 10e-6), 2e-6, 1e-18);  // on a sample
  EXPECT_NEAR(*force_at_deformation(branch, 15e-6), 4e-6, 1e-18);
  EXPECT_NEAR(*force_at_deformation(branch, 31e-6), 7.25e-6, 1e-18);  // towards the puncture point
  // Past the puncture the curve does not count: 40 um lies only on the released part.
  EXPECT_FALSE(force_at_deformation(branch, 40e-6).has_value());
  EXPECT_FALSE(force_at_deformation(branch, 33e-6).has_value());
}

TEST(ConvergenceStudy, ImbalanceIsWhatTheHoldingDoesNotCarry) {
  // The needle's resistance 2 -> 6 uN between 10 and 20 um, the holding pipette's axial force
  // -1 -> -6 uN: at 10 um half the load is carried elsewhere (inertia, damping), at 20 um none.
  const std::vector<CurvePoint> branch = {{0, 0, 0}, {10e-6, 2e-6, -1e-6}, {20e-6, 6e-6, -6e-6}};
  EXPECT_NEAR(*imbalance_at_deformation(branch, 10e-6), 0.5, 1e-12);
  EXPECT_NEAR(*imbalance_at_deformation(branch, 20e-6), 0.0, 1e-12);
  EXPECT_NEAR(*imbalance_at_deformation(branch, 15e-6), (4.0 - 3.5) / 4.0, 1e-12);
  EXPECT_FALSE(imbalance_at_deformation(branch, 25e-6).has_value());
  // No force yet: no ratio.
  EXPECT_FALSE(imbalance_at_deformation(branch, 0.0).has_value());
}

TEST(ConvergenceStudy, ForceAtDeformationTakesTheFirstCrossing) {
  // The deformation goes back once (a ringing membrane): the first time 6 um is reached counts.
  const std::vector<CurvePoint> branch = {{0, 0}, {8e-6, 8e-6}, {4e-6, 5e-6}, {10e-6, 20e-6}};
  EXPECT_NEAR(*force_at_deformation(branch, 6e-6), 6e-6, 1e-18);
  // A branch that starts past the level does not bracket it; an empty branch reaches nothing.
  const std::vector<CurvePoint> late = {{2e-6, 1e-6}, {4e-6, 2e-6}};
  EXPECT_FALSE(force_at_deformation(late, 1e-6).has_value());
  EXPECT_FALSE(force_at_deformation(std::vector<CurvePoint>{}, 1e-6).has_value());
}

TEST(ConvergenceStudy, LargestDropIsRelativeToTheReference) {
  const std::vector<CurvePoint> branch = {{0, 0},       {1e-6, 3e-6},   {2e-6, 2e-6},
                                          {3e-6, 5e-6}, {4e-6, 4.5e-6}, {5e-6, 8e-6}};
  EXPECT_NEAR(largest_force_drop(branch, 8e-6), 1.0 / 8.0, 1e-12);  // 3 -> 2 uN
  const std::vector<CurvePoint> rising = {{0, 0}, {1e-6, 1e-6}, {2e-6, 2e-6}};
  EXPECT_EQ(largest_force_drop(rising, 2e-6), 0.0);
  EXPECT_EQ(largest_force_drop(branch, 0.0), 0.0);  // no reference: no ratio
}

TEST(ConvergenceStudy, SummaryUsesPunctureOrPeakAsTheDropReference) {
  RunResult run;
  run.samples = {sample(0, 0), sample(10, 4), sample(20, 3), sample(30, 6)};
  run.peak_force = 6e-6;
  run.steps = 100;
  const std::vector<double> deformations = {15e-6, 40e-6};
  ConvergenceRun r = summarize_convergence_run(1000, run, deformations);
  EXPECT_FALSE(r.punctured);
  EXPECT_NEAR(r.largest_drop, 1.0 / 6.0, 1e-12);
  ASSERT_EQ(r.force_at.size(), 2u);
  EXPECT_NEAR(*r.force_at[0], 3.5e-6, 1e-18);
  EXPECT_FALSE(r.force_at[1].has_value());
  run.puncture = puncture_at(32, 5);
  r = summarize_convergence_run(1000, run, deformations);
  EXPECT_TRUE(r.punctured);
  EXPECT_NEAR(r.largest_drop, 1.0 / 5.0, 1e-12);  // the fall 6 -> 5 at puncture counts too
}

TEST(ConvergenceStudy, InvertedFromIsTheFirstFlaggedSampleBeforePuncture) {
  RunResult run;
  run.samples = {sample(0, 0), sample(10, 4), sample(20, 3), sample(30, 6)};
  run.peak_force = 6e-6;
  ConvergenceRun r = summarize_convergence_run(1000, run, std::vector<double>{});
  EXPECT_FALSE(r.inverted_from.has_value());
  run.samples[2].status = kStepInvertedElement | kStepCollapsingElement;
  run.samples[3].status = kStepInvertedElement;
  r = summarize_convergence_run(1000, run, std::vector<double>{});
  ASSERT_TRUE(r.inverted_from.has_value());
  EXPECT_NEAR(*r.inverted_from, 20e-6, 1e-18);
  // After puncture it is no longer on the loading branch.
  run.samples[2].status = kStepOk;
  run.samples[3].punctured = true;
  r = summarize_convergence_run(1000, run, std::vector<double>{});
  EXPECT_FALSE(r.inverted_from.has_value());
}

TEST(ConvergenceStudy, RelativeDifferencesAgainstTheMostVertices) {
  ConvergenceStudy study;
  study.deformations = {10e-6, 20e-6};
  ConvergenceRun fine, coarse, failed;
  fine.vertices = 4000;
  fine.force_at = {2e-6, std::nullopt};
  coarse.vertices = 1000;
  coarse.force_at = {2.5e-6, 5e-6};
  failed.vertices = 0;  // setup failed: never the reference
  failed.force_at = {std::nullopt, std::nullopt};
  study.runs = {coarse, fine, failed};
  fill_relative_differences(study);
  EXPECT_NEAR(*study.runs[0].relative_to_finest[0], 0.25, 1e-12);
  EXPECT_FALSE(study.runs[0].relative_to_finest[1].has_value());  // the finest has none
  EXPECT_NEAR(*study.runs[1].relative_to_finest[0], 0.0, 1e-12);
  EXPECT_FALSE(study.runs[2].relative_to_finest[0].has_value());
}

TEST(ConvergenceStudy, ParsesVertexAndDeformationLists) {
  Result<std::vector<int64_t>> v = parse_study_vertices("1e3, 4e3,300");
  ASSERT_TRUE(v.ok()) << v.error().message;
  EXPECT_EQ(*v, (std::vector<int64_t>{1000, 4000, 300}));
  for (const char* bad : {"", "300,", "abc", "2.5", "4", "-10"}) {
    Result<std::vector<int64_t>> r = parse_study_vertices(bad);
    ASSERT_FALSE(r.ok()) << bad;
    EXPECT_EQ(r.error().message.find('\n'), std::string::npos);
  }
  EXPECT_NE(parse_study_vertices("4").error().message.find("[8, "), std::string::npos);
  Result<std::vector<double>> d = parse_study_deformations("10,2.5");
  ASSERT_TRUE(d.ok());
  EXPECT_DOUBLE_EQ((*d)[0], 10e-6);
  EXPECT_DOUBLE_EQ((*d)[1], 2.5e-6);
  for (const char* bad : {"", "10,,20", "ten", "0", "-5", "10um"})
    EXPECT_FALSE(parse_study_deformations(bad).ok()) << bad;
}

TEST(ConvergenceStudy, CsvTextHasCommentsHeaderAndRows) {
  ConvergenceStudy study;
  study.scene_name = "hand";
  study.deformations = {10e-6};
  ConvergenceRun r;
  r.target_vertices = 300;
  r.vertices = 310;
  r.tets = 1200;
  r.dt = 2e-5;
  r.backend = "cpu reference: 2 thread(s), float64";  // a comma, replaced in the CSV
  r.samples = {sample(0, 0), sample(10, 2)};
  r.force_at = {2e-6};
  r.relative_to_finest = {0.0};
  study.runs = {r, r};
  const std::vector<std::string> comments = {"command: test", "date: today"};
  const std::string curves = convergence_csv(study, comments);
  EXPECT_EQ(curves.rfind("# command: test\n# date: today\n", 0), 0u);
  const auto rows = csv_rows(curves);
  ASSERT_EQ(rows.size(), 5u);  // header + 2 sizes x 2 samples
  EXPECT_EQ(rows[0].size(), 8u);
  EXPECT_EQ(rows[2][5], "10");  // deformation_um
  EXPECT_EQ(rows[2][6], "2");   // force_un
  const auto summary = csv_rows(convergence_summary_csv(study, comments));
  ASSERT_EQ(summary.size(), 3u);
  for (const auto& row : summary) EXPECT_EQ(row.size(), summary[0].size());
  EXPECT_EQ(summary[0][12], "force_at_10um_un");
  EXPECT_EQ(summary[0][13], "rel_diff_at_10um");
  EXPECT_EQ(summary[0][14], "imbalance_at_10um");
  EXPECT_EQ(summary[1][7], "cpu reference: 2 thread(s); float64");
  EXPECT_EQ(summary[1][9], "");  // no puncture: empty deformation
}

// A scene file holding test_scenes.h's small cell, in a folder removed afterwards.
struct SceneFile {
  std::filesystem::path dir, path;
  SceneFile() {
    dir = std::filesystem::temp_directory_path() /
          ("zona_convergence_" + std::to_string(::testing::UnitTest::GetInstance()->random_seed()) +
           "_" + ::testing::UnitTest::GetInstance()->current_test_info()->name());
    std::filesystem::create_directories(dir);
    path = dir / "small_cell.json";
    std::ofstream(path) << test::small_cell_scene().dump();
  }
  ~SceneFile() {
    std::error_code ec;
    std::filesystem::remove_all(dir, ec);
  }
};

TEST(ConvergenceStudy, TwoSizesOfASmallCell) {
  SceneFile file;
  const std::vector<int64_t> sizes = {120, 250};
  Result<std::vector<Scene>> scenes = convergence_scenes(file.path.string(), {}, sizes);
  ASSERT_TRUE(scenes.ok()) << scenes.error().message;
  ASSERT_EQ(scenes->size(), 2u);
  EXPECT_EQ((*scenes)[1].mesh.generate.target_vertices, 250);
  EXPECT_EQ((*scenes)[1].output.frames, 0);
  const std::vector<double> deformations = {0.5e-6, 100e-6};
  ConvergenceOptions options;
  options.simulation.threads = 1;
  int finished = 0;
  options.finished = [&](const ConvergenceRun&) { ++finished; };
  const ConvergenceStudy study = run_convergence_study(*scenes, deformations, options);
  EXPECT_EQ(finished, 2);
  ASSERT_EQ(study.runs.size(), 2u);
  for (const ConvergenceRun& r : study.runs) {
    EXPECT_GT(r.vertices, 0);
    EXPECT_GT(r.tets, r.vertices);
    EXPECT_GT(r.steps, 0);
    EXPECT_GT(r.dt, 0);
    EXPECT_FALSE(r.stopped_early) << r.stop_reason;
    EXPECT_FALSE(r.samples.empty());
    EXPECT_TRUE(r.force_at[0].has_value());   // 0.5 um is reached in 6.5 um of travel
    EXPECT_FALSE(r.force_at[1].has_value());  // 100 um is not
    EXPECT_GT(*r.force_at[0], 0.0);
  }
  // The finest is its own reference.
  EXPECT_NEAR(*study.runs[1].relative_to_finest[0], 0.0, 1e-15);
  EXPECT_TRUE(study.runs[0].relative_to_finest[0].has_value());
  const PlotSpec plot = convergence_plot(study);
  ASSERT_GE(plot.series.size(), 2u);
  EXPECT_NE(plot.series[0].label.find(" vertices"), std::string::npos);
}

TEST(ConvergenceStudy, ASizeThatCannotBeBuiltIsARow) {
  SceneFile file;
  const std::vector<int64_t> sizes = {120};
  Result<std::vector<Scene>> scenes = convergence_scenes(file.path.string(), {}, sizes);
  ASSERT_TRUE(scenes.ok()) << scenes.error().message;
  ConvergenceOptions options;
  options.simulation.backend_factory = [](std::string*) -> Result<std::unique_ptr<Backend>> {
    return make_error("no device");
  };
  const std::vector<double> deformations = {1e-6};
  const ConvergenceStudy study = run_convergence_study(*scenes, deformations, options);
  ASSERT_EQ(study.runs.size(), 1u);
  EXPECT_TRUE(study.runs[0].stopped_early);
  EXPECT_NE(study.runs[0].stop_reason.find("no device"), std::string::npos);
  const auto rows = csv_rows(convergence_summary_csv(study, {}));
  ASSERT_EQ(rows.size(), 2u);
  EXPECT_EQ(rows[1].size(), rows[0].size());
}

// options.stop (what `zona study` sets on SIGINT / SIGTERM): the running size ends at its next
// step as a row marked interrupted, and no later size starts. Set here as the second of three
// sizes starts, so that it stops at its first step.
TEST(ConvergenceStudy, AStopEndsTheRunningSizeAndTheStudy) {
  SceneFile file;
  const std::vector<int64_t> sizes = {120, 250, 120};
  Result<std::vector<Scene>> scenes = convergence_scenes(file.path.string(), {}, sizes);
  ASSERT_TRUE(scenes.ok()) << scenes.error().message;
  const std::vector<double> deformations = {0.5e-6};
  std::atomic<bool> stop{false};
  ConvergenceOptions options;
  options.simulation.threads = 1;
  options.stop = &stop;
  int started = 0, finished = 0;
  options.started = [&](const Scene&) {
    if (++started == 2) stop.store(true);
  };
  options.finished = [&](const ConvergenceRun&) { ++finished; };
  const ConvergenceStudy study = run_convergence_study(*scenes, deformations, options);
  EXPECT_EQ(started, 2);
  EXPECT_EQ(finished, 2);
  ASSERT_EQ(study.runs.size(), 2u);
  const ConvergenceRun& whole = study.runs[0];
  EXPECT_FALSE(whole.interrupted);
  EXPECT_FALSE(whole.stopped_early) << whole.stop_reason;
  EXPECT_TRUE(whole.force_at[0].has_value());
  const ConvergenceRun& cut = study.runs[1];
  EXPECT_TRUE(cut.interrupted);
  EXPECT_TRUE(cut.stopped_early);
  EXPECT_EQ(cut.stop_reason.rfind("interrupted at t ", 0), 0u) << cut.stop_reason;
  EXPECT_GT(cut.vertices, 0);
  EXPECT_LT(cut.steps, whole.steps);
  EXPECT_FALSE(cut.force_at[0].has_value());  // stopped before 0.5 um
  // Its row is whole in the summary, with the reason.
  const auto rows = csv_rows(convergence_summary_csv(study, {}));
  ASSERT_EQ(rows.size(), 3u);
  EXPECT_EQ(rows[2].size(), rows[0].size());
}

TEST(ConvergenceStudy, BadScenesAreErrors) {
  SceneFile file;
  const std::vector<int64_t> sizes = {120};
  Result<std::vector<Scene>> bad =
      convergence_scenes(file.path.string(), {"model=nonsense"}, sizes);
  ASSERT_FALSE(bad.ok());
  EXPECT_EQ(bad.error().message.find('\n'), std::string::npos);
  EXPECT_FALSE(convergence_scenes((file.dir / "missing.json").string(), {}, sizes).ok());
}

}  // namespace
}  // namespace zona
