// End-to-end tests of `zona study convergence`: two small sizes of the mouse oocyte give both
// CSVs (comment lines, header, the right rows) and the plot; bad input is a one-line error.
//
// The sizes are 600 and 1200 vertices: at 300 the mouse scene's 4 um tip passes between the
// surface vertices at the entry and touches none over its whole travel (zero force), which
// would leave a curve empty.
#include <gtest/gtest.h>

#include <algorithm>
#include <chrono>
#include <csignal>
#include <filesystem>
#include <fstream>
#include <map>
#include <set>
#include <string>
#include <thread>
#include <tuple>
#include <vector>

#include "engine/analysis/plot.h"
#include "tests/apps/cli_runner.h"

namespace {

using zona::test::CliRun;
using zona::test::run_zona;
using zona::test::TempDir;

namespace fs = std::filesystem;

// A CSV file: its comment lines, and its other lines split on commas (header first).
struct Csv {
  std::vector<std::string> comments;
  std::vector<std::string> header;
  std::vector<std::map<std::string, std::string>> rows;  // column name -> field
  bool ragged = false;                                   // a row with a different field count
};

Csv read_csv(const fs::path& path) {
  Csv csv;
  std::ifstream in(path);
  std::string line;
  while (std::getline(in, line)) {
    if (!line.empty() && line[0] == '#') {
      csv.comments.push_back(line);
      continue;
    }
    std::vector<std::string> fields;
    for (size_t start = 0; start <= line.size();) {
      const size_t comma = std::min(line.find(',', start), line.size());
      fields.push_back(line.substr(start, comma - start));
      start = comma + 1;
    }
    if (csv.header.empty()) {
      csv.header = fields;
      continue;
    }
    if (fields.size() != csv.header.size()) csv.ragged = true;
    std::map<std::string, std::string> row;
    for (size_t i = 0; i < fields.size() && i < csv.header.size(); ++i)
      row[csv.header[i]] = fields[i];
    csv.rows.push_back(row);
  }
  return csv;
}

bool has_comment(const Csv& csv, const std::string& prefix) {
  return std::any_of(csv.comments.begin(), csv.comments.end(),
                     [&](const std::string& c) { return c.rfind(prefix, 0) == 0; });
}

TEST(CmdStudy, ConvergenceWritesBothCsvsAndThePlot) {
  TempDir dir;
  const fs::path out = dir.path / "study";
  // 5 um of travel and a low force threshold: both sizes puncture within about 4 um (2.5 um
  // is past the holding suction's start-up swing of the cell, which reaches 2 um at 1200).
  const CliRun r = run_zona(
      "study convergence mouse_oocyte --vertices 600,1200 --set "
      "needle.max_travel=5um --set puncture.criterion=force --set "
      "puncture.threshold=0.2uN --deformations 2.5,10 --quiet --out " +
          out.string(),
      dir.path);
  ASSERT_EQ(r.exit_code, 0) << r.err << r.out;
  EXPECT_NE(r.out.find("wrote "), std::string::npos) << r.out;

  // convergence.csv: provenance, header, samples of both sizes.
  const Csv curves = read_csv(out / "convergence.csv");
  for (const char* c :
       {"# command: zona study convergence mouse_oocyte", "# date: ", "# commit: ", "# machine: "})
    EXPECT_TRUE(has_comment(curves, c)) << c;
  EXPECT_EQ(curves.header,
            (std::vector<std::string>{"target_vertices", "vertices", "tets", "time_s", "travel_um",
                                      "deformation_um", "force_un", "punctured"}));
  EXPECT_FALSE(curves.ragged);
  std::map<std::string, int> samples_per_size;
  for (const auto& row : curves.rows) ++samples_per_size[row.at("target_vertices")];
  ASSERT_EQ(samples_per_size.size(), 2u);
  EXPECT_GT(samples_per_size["600"], 10);
  EXPECT_GT(samples_per_size["1200"], 10);

  // convergence_summary.csv: one row per size, in the order asked.
  const Csv summary = read_csv(out / "convergence_summary.csv");
  EXPECT_TRUE(has_comment(summary, "# commit: "));
  EXPECT_FALSE(summary.ragged);
  for (const char* column :
       {"vertices", "tets", "dt_s", "steps", "wall_s", "backend", "puncture_deformation_um",
        "puncture_force_un", "peak_force_un", "force_at_2.5um_un", "force_at_10um_un",
        "rel_diff_at_2.5um", "largest_drop_rel", "inverted_from_um", "step_flags", "stop_reason"})
    EXPECT_NE(std::find(summary.header.begin(), summary.header.end(), column), summary.header.end())
        << column;
  ASSERT_EQ(summary.rows.size(), 2u);
  EXPECT_EQ(summary.rows[0].at("target_vertices"), "600");
  EXPECT_EQ(summary.rows[1].at("target_vertices"), "1200");
  for (const auto& row : summary.rows) {
    EXPECT_GT(std::stoll(row.at("vertices")), 0);
    EXPECT_GT(std::stoll(row.at("tets")), std::stoll(row.at("vertices")));
    EXPECT_GT(std::stod(row.at("dt_s")), 0.0);
    EXPECT_EQ(row.at("punctured"), "1");
    EXPECT_GE(std::stod(row.at("puncture_force_un")), 0.2);
    EXPECT_GT(std::stod(row.at("puncture_deformation_um")), 2.5);
    EXPECT_FALSE(row.at("force_at_2.5um_un").empty());  // reached before puncture
    EXPECT_TRUE(row.at("force_at_10um_un").empty());    // past the puncture: not on the branch
    EXPECT_FALSE(row.at("largest_drop_rel").empty());
    EXPECT_EQ(row.at("stopped_early"), "0") << row.at("stop_reason");
  }
  EXPECT_EQ(std::stod(summary.rows[1].at("rel_diff_at_2.5um")), 0.0);  // the finest
  EXPECT_FALSE(summary.rows[0].at("rel_diff_at_2.5um").empty());
  // The plot: PNG and SVG with a curve per size (matplotlib), else the built-in PNG.
  if (zona::test::plot_python_available()) {
    const std::string svg = zona::test::read_text(out / "convergence.svg");
    for (const auto& row : summary.rows)
      EXPECT_NE(svg.find(">" + row.at("vertices") + " vertices<"), std::string::npos)
          << row.at("vertices");
    EXPECT_NE(r.out.find("convergence.png, convergence.svg}"), std::string::npos) << r.out;
  }
  if (zona::plot_png_available() || zona::test::plot_python_available()) {
    EXPECT_TRUE(fs::exists(out / "convergence.png"));
  }
}

// SIGTERM / SIGINT (a cluster's time limit, Ctrl-C) end the running size at its next step: the
// CSVs keep the finished sizes and the interrupted one's row, one line on stderr says so, and
// the exit status is 128 + the signal. The signal is sent once the second size (4000 vertices,
// several times longer than the first) has started.
TEST(CmdStudy, ASignalEndsTheStudyAndKeepsItsRows) {
  TempDir dir;
  for (const auto& [sig, code, name] :
       {std::tuple{SIGTERM, 143, "SIGTERM"}, std::tuple{SIGINT, 130, "SIGINT"}}) {
    const fs::path out = dir.path / name;
    zona::test::CliProcess p = zona::test::start_zona(
        "study convergence mouse_oocyte --vertices 600,4000,600 --set needle.max_travel=20um "
        "--set puncture.criterion=none --out " +
            out.string(),
        dir.path);
    ASSERT_GT(p.pid, 0);
    const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(120);
    while (std::chrono::steady_clock::now() < deadline && !zona::test::has_exited(p) &&
           zona::test::read_text(p.err_path).find("size 2/3") == std::string::npos)
      std::this_thread::sleep_for(std::chrono::milliseconds(10));
    ASSERT_FALSE(zona::test::has_exited(p)) << name << ": the study ended before the signal";
    ASSERT_EQ(::kill(p.pid, sig), 0);
    const CliRun r = zona::test::wait_zona(p, 120);
    EXPECT_EQ(r.exit_code, code) << r.err;
    EXPECT_NE(r.err.find(std::string("zona study: interrupted by ") + name + ": 2 of 3 sizes run"),
              std::string::npos)
        << r.err;
    EXPECT_EQ(r.err.find("zona: error"), std::string::npos) << r.err;
    const Csv summary = read_csv(out / "convergence_summary.csv");
    EXPECT_FALSE(summary.ragged);
    ASSERT_EQ(summary.rows.size(), 2u);
    EXPECT_EQ(summary.rows[0].at("stopped_early"), "0") << summary.rows[0].at("stop_reason");
    EXPECT_NE(summary.rows[0].at("force_at_10um_un"), "");
    EXPECT_EQ(summary.rows[1].at("target_vertices"), "4000");
    EXPECT_EQ(summary.rows[1].at("stopped_early"), "1");
    EXPECT_EQ(summary.rows[1].at("stop_reason").rfind("interrupted at t ", 0), 0u)
        << summary.rows[1].at("stop_reason");
    // The interrupted size's curve up to the signal is in convergence.csv.
    const Csv curves = read_csv(out / "convergence.csv");
    EXPECT_TRUE(std::any_of(curves.rows.begin(), curves.rows.end(),
                            [](const auto& row) { return row.at("target_vertices") == "4000"; }));
  }
}

TEST(CmdStudy, PrintsAnEstimateFirstAndDefaultsToSizesTheCpuFinishes) {
  // No --vertices on the CPU: the small default sizes, estimated before anything runs (the
  // output folder that cannot be made stops it right after).
  TempDir dir;
  const CliRun r = run_zona("study convergence mouse_oocyte --backend cpu --threads 2 --out /dev/null/x",
                            dir.path);
  EXPECT_EQ(r.exit_code, 1) << r.err;
  EXPECT_EQ(r.out.rfind("estimate (rough, from the job benchmarks): 1e3,2e3,4e3 on the CPU, 2 threads: "
                        "1000 vertices ~",
                        0),
            0u)
      << r.out;
  // mouse_oocyte: 0.46 s of needle travel in 10 us steps, about 0.1 ms per step at 1000
  // vertices on 2 threads: about 5 s; 4000 vertices about 18 s.
  EXPECT_NE(r.out.find("1000 vertices ~5 s, 2000 vertices ~9 s, 4000 vertices ~18 s; total ~32 s"),
            std::string::npos)
      << r.out;
  EXPECT_NE(r.err.find("/dev/null/x"), std::string::npos) << r.err;
}

// One line on stderr, an error exit code.
void expect_one_line_error(const CliRun& r, const std::string& what) {
  EXPECT_NE(r.exit_code, 0) << what;
  EXPECT_EQ(r.err.rfind("zona: error: ", 0), 0u) << what << ": " << r.err;
  EXPECT_EQ(std::count(r.err.begin(), r.err.end(), '\n'), 1) << what << ": " << r.err;
}

TEST(CmdStudy, BadInputIsAOneLineError) {
  TempDir dir;
  const std::string out = " --quiet --out " + (dir.path / "bad").string();
  expect_one_line_error(run_zona("study convergence no_such_scene --vertices 300" + out, dir.path),
                        "unknown scene");
  expect_one_line_error(run_zona("study convergence mouse_oocyte --vertices ''" + out, dir.path),
                        "empty vertex list");
  expect_one_line_error(run_zona("study convergence mouse_oocyte --vertices 300,4" + out, dir.path),
                        "below the mesher's minimum");
  expect_one_line_error(
      run_zona("study convergence mouse_oocyte --vertices 300 --deformations ten" + out, dir.path),
      "bad deformation list");
  expect_one_line_error(
      run_zona("study convergence mouse_oocyte --vertices 300 --set model=nonsense" + out,
               dir.path),
      "bad --set");
  expect_one_line_error(
      run_zona("study convergence mouse_oocyte --vertices 300 --backend gpu" + out, dir.path),
      "unknown backend");
  EXPECT_FALSE(fs::exists(dir.path / "bad"));  // nothing ran, nothing written
}

}  // namespace
