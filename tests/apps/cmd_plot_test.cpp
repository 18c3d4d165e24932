// End-to-end tests of `zona plot` (apps/cmd_plot.cpp, apps/plot_script.cpp, python/zona_plot.py):
// the figures hold the data given (labels, series, the puncture, the branch after it in its own
// panel, axes from the data), and bad input or a missing Python is a one-line error.
#include <gtest/gtest.h>

#include <algorithm>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <regex>
#include <string>
#include <vector>

#include "tests/apps/cli_runner.h"

namespace {

using zona::test::CliRun;
using zona::test::read_text;
using zona::test::run_zona;
using zona::test::run_zona_after;
using zona::test::TempDir;

namespace fs = std::filesystem;

// A run folder as `zona run` leaves it: force.csv (schema 3) loading from 10 to 20 um, the
// puncture at 20 um and 1.05 uN (summary.json), then five rows whose deformation falls back to
// 5 um while the needle goes on.
void write_run(const fs::path& folder, double force_scale) {
  fs::create_directories(folder);
  std::ofstream csv(folder / "force.csv");
  csv << "# zona force.csv schema 3 (docs/outputs.md)\n"
         "time_s,needle_travel_m,deformation_m,force_N,force_x_N,force_y_N,force_z_N,"
         "holding_force_N,contacts,elastic_energy_J,kinetic_energy_J,punctured,raw_force_N,"
         "imbalance,kinetic_share\n";
  for (int i = 0; i <= 10; ++i)
    csv << i * 1e-3 << "," << (11 + i) * 1e-6 << "," << (10 + i) * 1e-6 << ","
        << force_scale * (0.05 + 0.01 * i * i) * 1e-6 << ",0,0,0,0,1,0,0,0,0,0,0\n";
  for (int k = 0; k < 5; ++k)
    csv << (11 + k) * 1e-3 << "," << (22 + k) * 1e-6 << "," << (15 - 2.5 * k) * 1e-6 << ","
        << 0.2e-6 << ",0,0,0,0,1,0,0,1,0,0,0\n";
  std::ofstream(folder / "summary.json")
      << R"({"puncture": {"punctured": true, "deformation_m": 2e-05, "force_N": )"
      << force_scale * 1.05e-6 << R"(, "needle_travel_m": 2.1e-05}})";
}

// The texts of an SVG written with its text as text (svg.fonttype none), in drawing order.
std::vector<std::string> svg_texts(const std::string& svg) {
  std::vector<std::string> out;
  const std::regex text(R"(<text[^>]*>([^<]*)</text>)");
  for (std::sregex_iterator it(svg.begin(), svg.end(), text), end; it != end; ++it)
    out.push_back((*it)[1]);
  return out;
}

int count(const std::vector<std::string>& texts, const std::string& s) {
  return static_cast<int>(std::count(texts.begin(), texts.end(), s));
}

bool is_png(const fs::path& path) { return read_text(path).rfind("\x89PNG\r\n\x1a\n", 0) == 0; }

// The stderr of a failed command: one line, non-empty.
void expect_one_line(const CliRun& r) {
  ASSERT_FALSE(r.err.empty());
  EXPECT_EQ(std::count(r.err.begin(), r.err.end(), '\n'), 1) << r.err;
}

TEST(CmdPlot, OverlaysRunsAndMeasuredDataWithErrorBars) {
  if (!zona::test::plot_python_available()) GTEST_SKIP() << "no Python with matplotlib (scripts/setup.sh)";
  TempDir dir;
  write_run(dir.path / "soft", 1.0);
  write_run(dir.path / "stiff", 1.5);
  const fs::path measured = dir.path / "measured.csv";
  std::ofstream(measured) << "# two cells\ndeformation_um,force_uN,force_std_uN\n"
                             "12,0.1,0.02\n15,0.3,0.05\n18,0.7,0.1\n";
  const fs::path stem = dir.path / "fig";
  const CliRun r = run_zona("plot " + (dir.path / "soft").string() + ":soft " +
                                (dir.path / "stiff" / "force.csv").string() + " --data " +
                                "'" + measured.string() + ":two cells' --reference 19,1.2:paper --title "
                                "overlay --out " + stem.string() + ".png",
                            dir.path);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_NE(r.out.find("wrote " + stem.string() + ".png, " + stem.string() + ".svg"),
            std::string::npos) << r.out;
  EXPECT_TRUE(is_png(stem.string() + ".png"));
  const std::vector<std::string> texts = svg_texts(read_text(stem.string() + ".svg"));
  // One label per quantity; the series and the markers by their legend entries.
  EXPECT_EQ(count(texts, "deformation [um]"), 1);
  EXPECT_EQ(count(texts, "needle force [uN]"), 1);
  EXPECT_EQ(count(texts, "overlay"), 1);
  EXPECT_EQ(count(texts, "soft"), 1);
  EXPECT_EQ(count(texts, "stiff"), 1);  // a force.csv's label: its folder
  EXPECT_EQ(count(texts, "two cells (mean +/- std)"), 1);
  EXPECT_EQ(count(texts, "paper"), 1);
  // Each run's puncture from its summary.json.
  EXPECT_EQ(count(texts, "puncture 20.0 um, 1.05 uN"), 1);
  EXPECT_EQ(count(texts, "puncture 20.0 um, 1.57 uN"), 1);
  // The branch after puncture in a panel of its own, against the needle's travel.
  EXPECT_EQ(count(texts, "needle travel past puncture [um]"), 1);
  // The deformation axis starts at the data (10 um): its tick labels, drawn before its label.
  const auto label = std::find(texts.begin(), texts.end(), "deformation [um]");
  ASSERT_NE(label, texts.begin());
  for (auto it = texts.begin(); it != label; ++it) EXPECT_GE(std::stod(*it), 10.0) << *it;
}

TEST(CmdPlot, DrawsAConvergenceStudysCurves) {
  if (!zona::test::plot_python_available()) GTEST_SKIP() << "no Python with matplotlib (scripts/setup.sh)";
  TempDir dir;
  std::ofstream csv(dir.path / "convergence.csv");
  csv << "# comment\ntarget_vertices,vertices,tets,time_s,travel_um,deformation_um,force_un,"
         "punctured\n";
  for (const int n : {1000, 4000})
    for (int i = 0; i <= 6; ++i)
      csv << n << "," << n << "," << 5 * n << "," << i * 1e-3 << "," << i + 1 << "," << i << ","
          << 0.1 * i * (n == 1000 ? 1.1 : 1.0) << "," << (i >= 5 ? 1 : 0) << "\n";
  csv.close();
  std::ofstream(dir.path / "convergence_summary.csv")
      << "target_vertices,vertices,punctured,puncture_deformation_um,puncture_force_un\n"
         "1000,1000,1,4.5,0.5\n4000,4000,0,,\n";
  const fs::path stem = dir.path / "conv";
  const CliRun r = run_zona("plot --study " + dir.path.string() + " --out " + stem.string(), dir.path);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_TRUE(is_png(stem.string() + ".png"));
  const std::vector<std::string> texts = svg_texts(read_text(stem.string() + ".svg"));
  EXPECT_EQ(count(texts, "1000 vertices"), 1);
  EXPECT_EQ(count(texts, "4000 vertices"), 1);
  EXPECT_EQ(count(texts, "puncture 4.5 um, 0.50 uN"), 1);
  EXPECT_EQ(count(texts, "deformation [um]"), 1);
  EXPECT_EQ(count(texts, "needle force [uN]"), 1);
}

TEST(CmdPlot, BadInputIsOneLineNamingTheFile) {
  TempDir dir;
  const std::string out = " --out " + (dir.path / "fig").string();
  // A run that is not there, a CSV without zona's columns, a measured file without its own.
  // (Without Python the message is about Python: the test below.)
  CliRun r;
  if (zona::test::plot_python_available()) {
    const fs::path missing = dir.path / "nope";
    r = run_zona("plot " + missing.string() + out, dir.path);
    EXPECT_EQ(r.exit_code, 1);
    expect_one_line(r);
    EXPECT_NE(r.err.find(missing.string() + ": not found"), std::string::npos) << r.err;
    const fs::path other = dir.path / "other.csv";
    std::ofstream(other) << "a,b\n1,2\n";
    r = run_zona("plot " + other.string() + out, dir.path);
    EXPECT_EQ(r.exit_code, 1);
    expect_one_line(r);
    EXPECT_NE(r.err.find(other.string() + ": not a zona force.csv"), std::string::npos) << r.err;
    r = run_zona("plot --data " + other.string() + out, dir.path);
    EXPECT_EQ(r.exit_code, 1);
    expect_one_line(r);
    EXPECT_NE(r.err.find(other.string() + ": the header needs deformation_m"), std::string::npos)
        << r.err;
    std::ofstream(other) << "deformation_um,force_uN\n1,x\n";
    r = run_zona("plot --data " + other.string() + out, dir.path);
    EXPECT_EQ(r.exit_code, 1);
    expect_one_line(r);
    EXPECT_NE(r.err.find(other.string() + ": data row 1: force_uN is not a number"), std::string::npos)
        << r.err;
    write_run(dir.path / "run", 1.0);
    r = run_zona("plot " + (dir.path / "run").string() + " --reference 1:x" + out, dir.path);
    EXPECT_EQ(r.exit_code, 1);
    expect_one_line(r);
    EXPECT_NE(r.err.find("--reference: expected DEFORMATION_UM,FORCE_UN"), std::string::npos) << r.err;
  }
  EXPECT_FALSE(fs::exists(dir.path / "fig.png"));
  EXPECT_FALSE(fs::exists(dir.path / "fig.svg"));
  // Nothing to plot, or a study mixed with runs: a usage mistake, said before Python runs.
  r = run_zona("plot" + out, dir.path);
  EXPECT_EQ(r.exit_code, 1);
  expect_one_line(r);
  EXPECT_NE(r.err.find("nothing to plot"), std::string::npos) << r.err;
  r = run_zona("plot a --study b" + out, dir.path);
  EXPECT_EQ(r.exit_code, 1);
  expect_one_line(r);
}

TEST(CmdPlot, WithoutPythonOrMatplotlibSaysSoInOneLine) {
  TempDir dir;
  write_run(dir.path / "run", 1.0);
  const std::string args = "plot " + (dir.path / "run").string() + " --out " + (dir.path / "fig").string();
  // An interpreter that is not there.
  CliRun r = run_zona_after("ZONA_PYTHON=/nonexistent/python3", args, dir.path);
  EXPECT_EQ(r.exit_code, 1);
  expect_one_line(r);
  EXPECT_NE(r.err.find("ZONA_PYTHON=/nonexistent/python3"), std::string::npos) << r.err;
  // One that is there but cannot import matplotlib (-S: no site-packages).
  const fs::path bare = dir.path / "bare_python";
  std::ofstream(bare) << "#!/bin/sh\nexec python3 -S \"$@\"\n";
  fs::permissions(bare, fs::perms::owner_all);
  r = run_zona_after("ZONA_PYTHON=" + bare.string(), args, dir.path);
  EXPECT_EQ(r.exit_code, 1);
  expect_one_line(r);
  EXPECT_NE(r.err.find("matplotlib is not installed"), std::string::npos) << r.err;
  EXPECT_FALSE(fs::exists(dir.path / "fig.png"));
}

}  // namespace
