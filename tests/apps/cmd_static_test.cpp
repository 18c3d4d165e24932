// `zona run` with the static solver, end to end on a small held cell: rows exactly at 10 um of
// deformation and at every load step, each converged (its residual column below the stated
// tolerance), the needle's and the holder's forces in balance, the puncture bracketed to the
// stated travel tolerance and its release reached; the breach and the lost holder as errors; and
// the scenes it refuses, with one line.
#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <map>
#include <sstream>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "tests/apps/cli_runner.h"

namespace {

using zona::test::CliRun;
using zona::test::run_zona;
using zona::test::run_zona_after;
using zona::test::TempDir;

namespace fs = std::filesystem;

// A 20 um cell held by suction, punctured at 0.6 uN (about 12.5 um of deformation).
const char* kScene = R"({
  "name": "tiny_static",
  "mesh": {"generate": {"diameter": "20 um", "vertices": 600, "refine_edge_length": "1 um",
                        "refine_radius": "5 um", "refine_at": "needle", "edge_length": "3 um"}},
  "model": "neohookean",
  "volumetric": "nodal",
  "materials": {"default": {"young": "10 kPa", "poisson": 0.45, "density": "1000 kg/m^3"}},
  "solver": {"method": "static", "travel_step": "1 um", "puncture_tolerance": "5 nm"},
  "needle": {"tip_radius": "2 um", "standoff": "0.5 um", "speed": "0.1 mm/s", "max_travel": "13 um"},
  "puncture": {"criterion": "force", "threshold": "0.6 uN", "force_drop": 0.9, "drop_time": "0.2 ms"},
  "holding_pipette": {"mode": "suction", "inner_radius": "4 um", "outer_radius": "12 um",
                      "suction": "2 kPa", "friction": 0.3},
  "output": {"frames": 3}
})";

// force.csv as columns by name.
std::map<std::string, std::vector<double>> read_csv(const fs::path& path) {
  std::ifstream in(path);
  std::string line;
  std::getline(in, line);  // schema
  std::getline(in, line);
  std::vector<std::string> names;
  std::stringstream header(line);
  for (std::string name; std::getline(header, name, ',');) names.push_back(name);
  std::map<std::string, std::vector<double>> columns;
  while (std::getline(in, line)) {
    std::stringstream row(line);
    std::string cell;
    for (size_t i = 0; std::getline(row, cell, ','); ++i) columns[names.at(i)].push_back(std::stod(cell));
  }
  return columns;
}

// kScene written into the test's folder.
fs::path write_tiny_scene(const TempDir& dir) {
  const fs::path scene = dir.path / "tiny_static.json";
  std::ofstream(scene) << kScene;
  return scene;
}

TEST(CmdRunStatic, ConvergedRowsAtSetDeformationsAndABracketedPuncture) {
  TempDir dir;
  const fs::path scene = write_tiny_scene(dir);
  const fs::path out = dir.path / "out";
  const CliRun r = run_zona("run " + scene.string() + " --headless --out " + out.string(), dir.path);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_NE(r.out.find("load steps (static)"), std::string::npos) << r.out;
  // Not the explicit step's time step, which it does not run.
  EXPECT_EQ(r.err.find("critical"), std::string::npos) << r.err;
  EXPECT_NE(r.err.find("static solver on the CPU"), std::string::npos) << r.err;
  auto c = read_csv(out / "force.csv");
  const std::vector<double>& d = c["deformation_m"];
  const std::vector<double>& f = c["force_N"];
  const std::vector<double>& hold = c["holding_force_N"];
  const std::vector<double>& res = c["residual_N"];
  const std::vector<double>& newton = c["newton_iterations"];
  const std::vector<double>& punct = c["punctured"];
  const std::vector<double>& rim = c["holding_contacts"];
  ASSERT_GT(d.size(), 10u);
  // The cell sits on the rim at every row (the seating's rows included).
  for (size_t i = 0; i < rim.size(); ++i) EXPECT_GT(rim[i], 0) << "row " << i;
  // A row at 10 um of deformation, to 1e-4 of it.
  int at10 = 0;
  for (double x : d) at10 += std::fabs(x - 10e-6) <= 1e-4 * 10e-6;
  EXPECT_EQ(at10, 1);
  // Every row converged: the residual at most tolerance x max(needle force, E r^2).
  const double scale = 10e3 * 2e-6 * 2e-6;
  for (size_t i = 1; i < d.size(); ++i) {
    EXPECT_LE(res[i], 1e-5 * std::max(scale, std::fabs(f[i])) * (1 + 1e-9)) << "row " << i;
    EXPECT_GE(newton[i], 1) << "row " << i;
    // Equilibrium: the holder takes the needle's axial load (the regulariser carries ~1e-5).
    if (f[i] > 1e-8) {
      EXPECT_NEAR(-hold[i], f[i], 2e-3 * f[i]) << "row " << i;
    }
  }
  // The loading branch rises; the puncture at 0.6 uN, bracketed to 5 nm of travel.
  nlohmann::json summary = nlohmann::json::parse(std::ifstream(out / "summary.json"));
  EXPECT_EQ(summary["solver"], "static");
  // "auto" on 600 vertices: block Jacobi.
  EXPECT_EQ(summary["static_solver"]["preconditioner"], "jacobi");
  // Nothing of the explicit step's setup: no time step, no mass scaling, no dynamics check.
  EXPECT_TRUE(summary["numerics"]["dt_s"].is_null()) << summary["numerics"].dump();
  EXPECT_TRUE(summary["numerics"]["mass_scaling"].is_null());
  EXPECT_TRUE(summary["quasi_static_check"].is_null());
  EXPECT_EQ(summary["quasi_static"], true);
  for (const auto& note : summary["notes"])
    EXPECT_EQ(note.get<std::string>().find("mass scaling:"), std::string::npos) << note;
  ASSERT_TRUE(summary["puncture"]["punctured"].get<bool>()) << summary.dump();
  const double fp = summary["puncture"]["force_N"].get<double>();
  EXPECT_GE(fp, 0.6e-6);
  EXPECT_LE(fp, 0.6e-6 * 1.01);
  // After it the load is released to 10 % and the run goes on to the end of the travel.
  size_t first = 0;
  while (first < punct.size() && punct[first] == 0) ++first;
  ASSERT_LT(first, punct.size());
  EXPECT_NEAR(f[first], 0.1 * fp, 1e-3 * fp);
  EXPECT_NEAR(c["needle_travel_m"].back(), 13e-6, 1e-12);
  EXPECT_TRUE(fs::exists(out / "frames.pvd"));
}

// force.csv's holding_contacts on the explicit path: the rim's contact vertices, counted by the
// job's tool stage (the same column as the static run's above).
TEST(CmdRunStatic, TheExplicitRunCountsTheRimContactsToo) {
  TempDir dir;
  const fs::path scene = write_tiny_scene(dir);
  const fs::path out = dir.path / "out";
  const CliRun r = run_zona("run " + scene.string() +
                                " --solver explicit --headless --no-frames --quiet "
                                "--set needle.max_travel=1.5um --set needle.speed=2mm/s --out " + out.string(),
                            dir.path);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  auto c = read_csv(out / "force.csv");
  const std::vector<double>& rim = c["holding_contacts"];
  ASSERT_GT(rim.size(), 2u);
  EXPECT_EQ(rim.front(), 0);  // before the suction has drawn the cell onto the rim
  EXPECT_GT(rim.back(), 0);
}

// After the release the needle carries the released load and keeps it (no shaft drag here),
// with the needle's friction on: the release unloads in load steps whose friction is committed
// and lagged as the loading's are. (Friction held from the puncture state through the whole
// unloading left the needle 21 % above the released load one step later.)
TEST(CmdRunStatic, TheReleasedLoadStaysWithTheNeedlesFriction) {
  TempDir dir;
  const fs::path scene = write_tiny_scene(dir);
  const fs::path out = dir.path / "out";
  const CliRun r = run_zona("run " + scene.string() +
                                " --headless --no-frames --set needle.friction=0.3 "
                                "--set needle.max_travel=17um --out " + out.string(),
                            dir.path);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  auto c = read_csv(out / "force.csv");
  const std::vector<double>& f = c["force_N"];
  const std::vector<double>& punct = c["punctured"];
  size_t first = 0;
  while (first < punct.size() && punct[first] == 0) ++first;
  ASSERT_LT(first + 3, punct.size()) << "the travel goes on past the release";
  const double released = f[first];
  EXPECT_NEAR(released, 0.06e-6, 1e-3 * 0.6e-6);
  for (size_t i = first + 1; i < f.size(); ++i)
    EXPECT_NEAR(f[i], released, 0.05 * released) << "row " << i;
}

// The regulariser (the real mass and the medium's drag) holds the cell's spin on the rim and
// nothing else: ten times the viscosity leaves the curve where it was.
TEST(CmdRunStatic, TheRegulariserDoesNotMoveTheCurve) {
  TempDir dir;
  const fs::path scene = write_tiny_scene(dir);
  const std::string base = "run " + scene.string() + " --headless --no-frames --set needle.max_travel=10um";
  const CliRun a = run_zona(base + " --out " + (dir.path / "a").string(), dir.path);
  const CliRun b = run_zona(base + " --set 'solver.medium_viscosity=8.9e-3 Pa*s' --out " +
                                (dir.path / "b").string(),
                            dir.path);
  ASSERT_EQ(a.exit_code, 0) << a.err;
  ASSERT_EQ(b.exit_code, 0) << b.err;
  auto ca = read_csv(dir.path / "a" / "force.csv"), cb = read_csv(dir.path / "b" / "force.csv");
  ASSERT_EQ(ca["force_N"].size(), cb["force_N"].size());
  const double peak = ca["force_N"].back();
  ASSERT_GT(peak, 1e-7);
  for (size_t i = 0; i < ca["force_N"].size(); ++i)
    EXPECT_NEAR(ca["force_N"][i], cb["force_N"][i], 1e-3 * peak) << "row " << i;
}

// --threads sets the static solver's threads (a sweep's local workers and a SLURM task give each
// run its share of the cores), and the thread count does not change a bit of the answer: every
// sum of the solver is taken over fixed chunks in a fixed order.
TEST(CmdRunStatic, ThreadsSetTheSolversThreadsAndLeaveItsAnswer) {
  TempDir dir;
  const fs::path scene = write_tiny_scene(dir);
  auto run = [&](int threads) {
    const std::string n = std::to_string(threads);
    const fs::path out = dir.path / ("threads" + n);
    std::string command = "run " + scene.string();
    command += " --headless --no-frames --no-plot --set needle.max_travel=5um --threads " + n;
    command += " --out " + out.string();
    const CliRun r = run_zona(command, dir.path);
    EXPECT_EQ(r.exit_code, 0) << r.err;
    nlohmann::json s = nlohmann::json::parse(std::ifstream(out / "summary.json"));
    EXPECT_EQ(s["static_solver"]["threads"], threads) << s["static_solver"].dump();
    EXPECT_NE(s["backend"].get<std::string>().find(n + " thread(s)"), std::string::npos)
        << s["backend"];
    return read_csv(out / "force.csv");
  };
  auto one = run(1), three = run(3);
  ASSERT_GT(one["force_N"].size(), 3u);
  for (const char* column : {"force_N", "deformation_m", "holding_force_N", "residual_N",
                             "newton_iterations", "krylov_iterations"})
    EXPECT_EQ(one[column], three[column]) << column;
}

// solver.oracle: every load step solved again from its start by Newton on the direct solver.
// The two solutions differ by what the tolerance leaves (tighter tolerance, smaller difference),
// and at 1e-8 by less than 1e-6 of the largest displacement.
TEST(CmdRunStatic, TheDirectOracleAgreesWithCgToTheTolerance) {
  TempDir dir;
  const fs::path scene = write_tiny_scene(dir);
  auto oracle = [&](const std::string& tolerance) {
    const fs::path out = dir.path / ("tol" + tolerance);
    const CliRun r = run_zona("run " + scene.string() +
                                  " --headless --no-frames --set needle.max_travel=5um "
                                  "--set solver.oracle=true --set solver.tolerance=" +
                                  tolerance + " --out " + out.string(),
                              dir.path);
    EXPECT_EQ(r.exit_code, 0) << r.err;
    EXPECT_NE(r.out.find("direct oracle:"), std::string::npos) << r.out;
    nlohmann::json s = nlohmann::json::parse(std::ifstream(out / "summary.json"));
    const nlohmann::json& o = s["numerics"]["oracle"];
    EXPECT_GE(o["solves"].get<int64_t>(), 5) << o.dump();
    EXPECT_EQ(o["failures"].get<int64_t>(), 0) << o.dump();
    return o["max_relative_difference"].get<double>();
  };
  const double loose = oracle("1e-5"), tight = oracle("1e-8");
  EXPECT_LT(tight, 1e-6);
  EXPECT_LT(tight, loose);
  EXPECT_GE(tight, 0.0);
}

// `zona bench --job --solver static`: one row per size with the run to the puncture measured
// (wall time, the puncture's force), the solver's work, and the explicit step's columns empty.
TEST(CmdRunStatic, JobBenchmarkTimesTheStaticRunToThePuncture) {
  TempDir dir;
  const fs::path scene = write_tiny_scene(dir);
  const fs::path csv = dir.path / "job.csv";
  const CliRun r = run_zona("bench --job --solver static --scene " + scene.string() +
                                " --vertices 600 --out " + csv.string(),
                            dir.path);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  std::ifstream in(csv);
  std::vector<std::vector<std::string>> rows;
  for (std::string line; std::getline(in, line);) {
    if (line.empty() || line[0] == '#') continue;
    std::vector<std::string> cells;
    std::stringstream row(line + ",");  // a trailing empty cell counts
    for (std::string cell; std::getline(row, cell, ',');) cells.push_back(cell);
    rows.push_back(cells);
  }
  ASSERT_EQ(rows.size(), 2u);
  const std::vector<std::string>& head = rows[0];
  ASSERT_EQ(rows[1].size(), head.size());
  std::map<std::string, std::string> row;
  for (size_t i = 0; i < head.size(); ++i) row[head[i]] = rows[1][i];
  EXPECT_EQ(row["solver"], "static");
  EXPECT_EQ(row["status"], "ok");
  EXPECT_EQ(row["puncture_measured"], "1");
  EXPECT_GT(std::stod(row["wall_to_puncture_s"]), 0);
  EXPECT_NEAR(std::stod(row["puncture_force_un"]), 0.6, 0.006);
  EXPECT_GT(std::stoll(row["newton_iterations"]), 0);
  EXPECT_EQ(row["preconditioner"], "jacobi");
  EXPECT_EQ(row["job_ms_median"], "");
  EXPECT_EQ(row["dt_s"], "");
}

// `zona study convergence --solver static`: each size is a static run (its line counts load
// steps, not time steps), and the summary compares the sizes' forces at 10 um.
TEST(CmdRunStatic, ConvergenceStudyRunsTheStaticSolverAtEachSize) {
  TempDir dir;
  const fs::path scene = write_tiny_scene(dir);
  const CliRun r = run_zona("study convergence " + scene.string() +
                                " --solver static --vertices 300,600 --deformations 10 --quiet "
                                "--set needle.max_travel=11um --out " +
                                (dir.path / "study").string(),
                            dir.path);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  size_t lines = 0;
  for (size_t at = r.out.find("load steps (static)"); at != std::string::npos;
       at = r.out.find("load steps (static)", at + 1))
    ++lines;
  EXPECT_EQ(lines, 2u) << r.out;
  EXPECT_EQ(r.out.find("steps of"), std::string::npos) << r.out;
  std::ifstream summary(dir.path / "study" / "convergence_summary.csv");
  ASSERT_TRUE(summary.good());
  std::string line;
  size_t rows = 0;
  while (std::getline(summary, line)) {
    if (line.empty() || line[0] == '#') continue;
    ++rows;
    // target_vertices, vertices, tets, dt_s, steps: a static run has no time step.
    std::vector<std::string> cells;
    std::stringstream row(line);
    for (std::string cell; std::getline(row, cell, ',');) cells.push_back(cell);
    ASSERT_GE(cells.size(), 5u) << line;
    if (rows == 1) {
      EXPECT_EQ(cells[3], "dt_s");
    } else {
      EXPECT_EQ(cells[3], "") << line;
      EXPECT_GT(std::stoll(cells[4]), 0) << line;
    }
  }
  EXPECT_GE(rows, 3u);  // the header and a row per size
}

// A midpoint of the puncture's bisection is a load step from the accepted state; where it does
// not converge the bracket's converged state below the threshold is accepted (or the step
// halved) and the travel goes on, as for any load step, instead of ending the run. The tiny
// scene with 4 Newton iterations a load step meets one (the trace says so); it punctures,
// every row below the threshold, the puncture state above it. (The default scene at 1000
// vertices met one at 34.43 um of travel, which ended its run.)
TEST(CmdRunStatic, ABisectionMidpointThatDoesNotConvergeShortensTheStep) {
  TempDir dir;
  const fs::path scene = write_tiny_scene(dir);
  const fs::path out = dir.path / "out";
  const CliRun r = run_zona_after("ZONA_NEWTON_TRACE=1",
                                  "run " + scene.string() +
                                      " --headless --no-frames --quiet "
                                      "--set solver.max_iterations=4 --out " + out.string(),
                                  dir.path);
  ASSERT_EQ(r.exit_code, 0) << r.err.substr(r.err.size() > 2000 ? r.err.size() - 2000 : 0);
  EXPECT_NE(r.err.find("shortened bisection"), std::string::npos);
  nlohmann::json summary = nlohmann::json::parse(std::ifstream(out / "summary.json"));
  ASSERT_TRUE(summary["puncture"]["punctured"].get<bool>()) << summary.dump();
  const double fp = summary["puncture"]["force_N"].get<double>();
  EXPECT_GE(fp, 0.6e-6);
  EXPECT_LE(fp, 0.6e-6 * 1.01);
  auto c = read_csv(out / "force.csv");
  const std::vector<double>& f = c["force_N"];
  const std::vector<double>& punct = c["punctured"];
  size_t first = 0;
  while (first < punct.size() && punct[first] == 0) ++first;
  ASSERT_LT(first, punct.size());
  ASSERT_GT(first, 1u);
  for (size_t i = 0; i + 1 < first; ++i) EXPECT_LT(f[i], 0.6e-6) << "row " << i;
  // The row before the release is the puncture state, at or above the threshold.
  EXPECT_GE(f[first - 1], 0.6e-6);
  EXPECT_EQ(c["needle_travel_m"][first - 1], summary["puncture"]["needle_travel_m"].get<double>());
}

TEST(CmdRunStatic, ABreachAndALostHolderEndTheRunAsErrors) {
  // The static run's two outcomes that are not results: a contact too soft to hold the membrane
  // lets the tip through the surface before any puncture, and a rim without grip (friction
  // 1e-6) lets every one of its contacts slide while the needle pushes. Each ends the run with
  // one line and exit 1, and summary.json says it stopped early.
  TempDir dir;
  const fs::path scene = write_tiny_scene(dir);
  auto stops = [&](const std::string& name, const std::string& sets, const std::string& words) {
    const fs::path out = dir.path / name;
    const CliRun r = run_zona("run " + scene.string() + " --headless --no-frames --out " +
                                  out.string() + " " + sets,
                              dir.path);
    EXPECT_EQ(r.exit_code, 1) << name << "\n" << r.err;
    EXPECT_NE(r.err.find(words), std::string::npos) << name << "\n" << r.err;
    std::ifstream in(out / "summary.json");
    ASSERT_TRUE(in.good()) << name;
    const nlohmann::json j = nlohmann::json::parse(in);
    EXPECT_TRUE(j["numerics"]["stopped_early"].get<bool>()) << name;
    EXPECT_FALSE(j["puncture"]["punctured"].get<bool>()) << name;
  };
  stops("breach", "--set contact.stiffness=1 --set puncture.criterion=none",
        "the needle went through the cell surface without a puncture");
  stops("lost", "--set holding_pipette.friction=1e-6", "the holder lost the cell");
  // With the rim's grip the same cell is held to its puncture.
  const CliRun held = run_zona("run " + scene.string() + " --headless --no-frames --out " +
                                   (dir.path / "held").string(),
                               dir.path);
  EXPECT_EQ(held.exit_code, 0) << held.err;
}

TEST(CmdRunStatic, RefusesWhatItCannotSolveWithOneLine) {
  TempDir dir;
  const fs::path scene = write_tiny_scene(dir);
  auto one_line_error = [&](const std::string& args, const std::string& words) {
    const CliRun r = run_zona("run " + scene.string() + " --headless --out " +
                                  (dir.path / "o").string() + " " + args,
                              dir.path);
    EXPECT_EQ(r.exit_code, 1) << args << "\n" << r.err;
    EXPECT_NE(r.err.find(words), std::string::npos) << args << "\n" << r.err;
  };
  one_line_error("--set model=svk --set volumetric=element", "spurious collapsed equilibria");
  one_line_error("--set contact.model=kinematic", "'kinematic' was retired");
  one_line_error("--set puncture.criterion=strain --set puncture.threshold=0.1",
                 "puncture.criterion 'strain'");
  one_line_error("--backend cuda", "runs on the CPU");
  one_line_error("--set solver.linear=qr", "solver.linear");
  one_line_error("--set solver.tolerance=0", "solver.tolerance");
  one_line_error("--set solver.linear=direct --set solver.oracle=true", "solver.oracle");
}

}  // namespace
