// End-to-end tests of `zona sweep`: a 100-point sweep with 2 local workers and the same sweep
// as a SLURM array whose tasks run by index give the same table; a killed sweep resumes and
// reruns only its unfinished points; bad input is a one-line error.
#include <gtest/gtest.h>

#include <signal.h>

#include <chrono>
#include <filesystem>
#include <fstream>
#include <map>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include "tests/apps/cli_runner.h"

namespace {

using zona::test::CliRun;
using zona::test::read_text;
using zona::test::run_zona;

namespace fs = std::filesystem;

fs::path temp_dir() {
  const fs::path d = fs::temp_directory_path() / ("zona_cmd_sweep_" + zona::test::current_test_tag());
  fs::remove_all(d);
  fs::create_directories(d);
  return d;
}

// A 150-vertex held ball pushed 4 um by a blunt tip: about 0.1 s per run. Its peak force is 0.07-0.18 uN
// over the swept moduli, so the swept force thresholds puncture some points and not others.
const char* kScene = R"({
  "name": "sweep_tiny",
  "mesh": {"generate": {"diameter": "20 um", "vertices": 150}},
  "model": "svk",
  "materials": {"default": {"young": "10 kPa", "poisson": 0.45, "damping": "50 1/s"}},
  "integrator": {"target_dt": "20 us", "mass_scaling_mode": "selective", "dt_safety": 0.25,
                 "stiffness_damping": "100 us"},
  "needle": {"tip_radius": "6 um", "standoff": "0.5 um", "speed": "0.5 mm/s", "max_travel": "4 um"},
  "holding_pipette": {"mode": "fixed", "inner_radius": "5 um"},
  "puncture": {"criterion": "force", "threshold": "0.1 uN"},
  "output": {"frames": 0, "sample_interval": "0.1 ms"}
})";

const std::string kSets =
    " --set materials.default.young=5kPa,6kPa,7kPa,8kPa,9kPa,10kPa,11kPa,12kPa,13kPa,14kPa"
    " --set puncture.threshold=0.02uN,0.04uN,0.06uN,0.08uN,0.1uN,0.12uN,0.14uN,0.16uN,0.18uN,0.2uN"
    " --deformations 1,2,3 --threads 1";

std::vector<std::vector<std::string>> read_csv(const fs::path& p) {
  std::vector<std::vector<std::string>> rows;
  std::istringstream in(read_text(p));
  std::string line;
  while (std::getline(in, line)) {
    std::vector<std::string> cells;
    std::string cell;
    std::istringstream l(line);
    while (std::getline(l, cell, ',')) cells.push_back(cell);
    if (!line.empty() && line.back() == ',') cells.push_back("");
    rows.push_back(cells);
  }
  return rows;
}

// The table without its wall_s column (the one column that differs from run to run).
std::vector<std::vector<std::string>> without_wall(std::vector<std::vector<std::string>> rows) {
  size_t wall = 0;
  while (wall < rows[0].size() && rows[0][wall] != "wall_s") ++wall;
  EXPECT_LT(wall, rows[0].size());
  for (auto& r : rows)
    if (wall < r.size()) r.erase(r.begin() + static_cast<long>(wall));
  return rows;
}

TEST(CmdSweep, HundredPointsLocallyAndAsSlurmArrayGiveTheSameTable) {
  const fs::path d = temp_dir();
  std::ofstream(d / "scene.json") << kScene;
  const std::string scene = (d / "scene.json").string();

  const auto start = std::chrono::steady_clock::now();
  CliRun r = run_zona("sweep " + scene + kSets + " --jobs 2 --quiet --out " + (d / "local").string());
  const double local_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_NE(r.out.find("100 points: 100 ok"), std::string::npos) << r.out;
  const auto local = read_csv(d / "local/sweep.csv");
  ASSERT_EQ(local.size(), 101u);
  EXPECT_EQ(local[0][0], "point");
  EXPECT_EQ(local[0][1], "materials.default.young");
  EXPECT_EQ(local[0][2], "puncture.threshold");
  // Rows in point order, the product's order (the last key fastest), some punctured, some not.
  EXPECT_EQ(local[1][1], "5kPa");
  EXPECT_EQ(local[2][2], "0.04uN");
  EXPECT_EQ(local[100][1], "14kPa");
  int punctured = 0;
  for (size_t i = 1; i < local.size(); ++i) punctured += local[i][5] == "1";
  EXPECT_GT(punctured, 10);
  EXPECT_LT(punctured, 90);
  // Where it punctured, the force reached the threshold it was given (force criterion; the
  // first contact can overshoot a low one); where not, the peak stayed below it.
  for (size_t i = 1; i < local.size(); ++i) {
    const double threshold = std::stod(local[i][2]) * 1e-6;
    if (local[i][5] == "1") EXPECT_GE(std::stod(local[i][7]), 0.99 * threshold) << i;
    else EXPECT_LT(std::stod(local[i][8]), threshold) << i;
  }
  std::fprintf(stderr, "100-point sweep, 2 workers: %.1f s\n", local_s);

  // The same sweep as a SLURM job array: its script run by index, two at a time, then collect.
  r = run_zona("sweep " + scene + kSets + " --slurm --out " + (d / "array").string());
  ASSERT_EQ(r.exit_code, 0) << r.err;
  const std::string script = (d / "array/sweep.sbatch").string();
  EXPECT_NE(read_text(script).find("#SBATCH --array=0-99\n"), std::string::npos);
  const std::string tasks = "seq 0 99 | xargs -P 2 -I{} env SLURM_ARRAY_TASK_ID={} bash " + script +
                            " >" + (d / "tasks.log").string() + " 2>&1";
  ASSERT_EQ(std::system(tasks.c_str()), 0) << read_text(d / "tasks.log");
  r = run_zona("sweep collect " + (d / "array").string());
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_NE(r.out.find("100 points: 100 ok"), std::string::npos) << r.out;
  EXPECT_EQ(without_wall(read_csv(d / "array/sweep.csv")), without_wall(local));
  // A task whose point is done does nothing.
  r = run_zona("sweep --task 7 --out " + (d / "array").string());
  EXPECT_EQ(r.exit_code, 0);
  EXPECT_NE(r.out.find("point 7: already done (ok)"), std::string::npos) << r.out;
  // Without --threads each task takes the cores SLURM gives it (--threads 0 to its runs), not a
  // share of the machine that wrote the script.
  r = run_zona("sweep " + scene + " --set materials.default.young=5kPa,6kPa --slurm --out " +
               (d / "array0").string());
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_NE(read_text(d / "array0/sweep.json").find("\"threads\": 0\n"), std::string::npos)
      << read_text(d / "array0/sweep.json");
  fs::remove_all(d);
}

TEST(CmdSweep, KilledSweepResumesAndRerunsOnlyUnfinishedPoints) {
  const fs::path d = temp_dir();
  std::ofstream(d / "scene.json") << kScene;
  const std::string args = "sweep " + (d / "scene.json").string() +
                           " --set needle.speed=0.2mm/s,0.3mm/s,0.4mm/s,0.5mm/s,0.6mm/s,0.7mm/s,0.8mm/s,0.9mm/s"
                           " --set needle.max_travel=6um --jobs 1 --threads 1 --out " + (d / "sw").string();
  // Killed (SIGKILL, no clean-up) once its first point is done.
  zona::test::CliProcess p = zona::test::start_zona(args, d);
  ASSERT_GT(p.pid, 0);
  const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(60);
  while (!fs::exists(d / "sw/points/00000/point.json") && !zona::test::has_exited(p) &&
         std::chrono::steady_clock::now() < deadline)
    std::this_thread::sleep_for(std::chrono::milliseconds(2));
  ::kill(p.pid, SIGKILL);
  zona::test::wait_zona(p, 30);
  std::map<int, std::string> done;  // markers at the kill, by point
  for (int i = 0; i < 8; ++i) {
    const fs::path m = d / "sw/points" / (std::string(i < 10 ? "0000" : "000") + std::to_string(i)) / "point.json";
    if (fs::exists(m)) done[i] = read_text(m);
  }
  ASSERT_GE(done.size(), 1u);
  // The same command resumes: only the points without a marker run, the others stay as they were.
  CliRun r = run_zona(args);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_NE(r.err.find("8 points, " + std::to_string(done.size()) + " done, " +
                       std::to_string(8 - done.size()) + " to run"),
            std::string::npos)
      << r.err;
  EXPECT_NE(r.out.find("8 points: 8 ok"), std::string::npos) << r.out;
  for (const auto& [i, text] : done)
    EXPECT_EQ(read_text(d / "sw/points" / ("0000" + std::to_string(i)) / "point.json"), text) << i;
  // A point whose marker is gone (killed before writing it) runs again; nothing else does.
  fs::remove(d / "sw/points/00003/point.json");
  r = run_zona(args);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_NE(r.err.find("8 points, 7 done, 1 to run"), std::string::npos) << r.err;
  EXPECT_TRUE(fs::exists(d / "sw/points/00003/point.json"));
  // `--out DIR` alone resumes the folder's own sweep; a different sweep into it is refused.
  r = run_zona("sweep --out " + (d / "sw").string());
  EXPECT_EQ(r.exit_code, 0) << r.err;
  EXPECT_NE(r.err.find("8 points, 8 done, 0 to run"), std::string::npos) << r.err;
  r = run_zona("sweep " + (d / "scene.json").string() + " --set needle.speed=0.1mm/s,0.2mm/s --out " +
               (d / "sw").string());
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_NE(r.err.find("holds a different sweep"), std::string::npos) << r.err;
  fs::remove_all(d);
}

TEST(CmdSweep, BadInputIsAOneLineError) {
  const fs::path d = temp_dir();
  std::ofstream(d / "scene.json") << kScene;
  const std::string scene = (d / "scene.json").string();
  std::ofstream(d / "m.csv") << "needle.speed,needle.max_travel\n0.1mm/s,4um\n0.2mm/s\n";
  CliRun r = run_zona("sweep " + scene + " --manifest " + (d / "m.csv").string() + " --out " + (d / "o").string());
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_NE(r.err.find("m.csv:3: 1 fields, the header has 2"), std::string::npos) << r.err;
  EXPECT_EQ(std::count(r.err.begin(), r.err.end(), '\n'), 1) << r.err;
  r = run_zona("sweep " + scene + " --set materials.default.yung=1kPa,2kPa --out " + (d / "o").string());
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_NE(r.err.find("point 0: "), std::string::npos) << r.err;
  EXPECT_NE(r.err.find("yung"), std::string::npos) << r.err;
  r = run_zona("sweep " + scene + " --set needle.speed=0.1mm/s --out " + (d / "o").string());
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_NE(r.err.find("no parameter to sweep"), std::string::npos) << r.err;
  r = run_zona("sweep --task 3 --out " + (d / "nothing").string());
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_NE(r.err.find("sweep.json"), std::string::npos) << r.err;
  fs::remove_all(d);
}

}  // namespace
