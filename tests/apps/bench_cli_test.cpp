// End-to-end tests of `zona bench`: one-line errors for bad options, and a tiny run that writes
// the CSV (comment lines, header, one row) with one notice for an unavailable GPU.
#include <gtest/gtest.h>

#include <sys/wait.h>

#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>
#include <utility>
#include <vector>

#include "kernels/backend_info.h"

#include "tests/apps/cli_runner.h"

namespace {

using zona::test::CliRun;
using zona::test::run_zona;

// Runs the zona binary with `args`, capturing stdout and stderr through temporary files.

int count_lines(const std::string& s) {
  int n = 0;
  for (char c : s) n += c == '\n';
  return n;
}

TEST(BenchCli, BadOptionsAreOneLineErrors) {
  struct Case {
    const char* args;
    const char* named;
  };
  for (const Case& c : {Case{"--vertices abc", "abc"}, Case{"--vertices 1000,,5", "--vertices"},
                        Case{"--backend gpu", "gpu"}, Case{"--model neo", "neo"},
                        Case{"--formulation tensor", "tensor"}, Case{"--repeats 0", "--repeats"},
                        Case{"--steps -3", "--steps"}, Case{"--threads x", "--threads"},
                        Case{"--vertices 5000 --max-vertices 1000", "5000"},
                        Case{"--assembly nope", "--assembly"}}) {
    const CliRun r = run_zona(std::string("bench ") + c.args);
    EXPECT_NE(r.exit_code, 0) << c.args;
    EXPECT_EQ(count_lines(r.err), 1) << c.args << ": " << r.err;
    EXPECT_NE(r.err.find(c.named), std::string::npos) << c.args << ": " << r.err;
    EXPECT_TRUE(r.out.empty()) << c.args;
  }
}

TEST(BenchCli, TinyRunWritesTheCsvAndOneNoticeForAMissingGpu) {
  const std::string path =
      (std::filesystem::temp_directory_path() / "zona_bench_cli_tiny.csv").string();
  const CliRun r = run_zona("bench --backend all --vertices 150 --steps 2 --repeats 1 "
                            "--threads 1 --copy-mib 4 --out " + path);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  std::ifstream f(path);
  std::vector<std::string> comments, rows;
  std::string header, line;
  while (std::getline(f, line)) {
    if (line.rfind("#", 0) == 0)
      comments.push_back(line);
    else if (header.empty())
      header = line;
    else
      rows.push_back(line);
  }
  std::filesystem::remove(path);
  EXPECT_GE(comments.size(), 4u);
  EXPECT_EQ(header.rfind("backend,model,formulation,", 0), 0u) << header;
  std::string notice;
  if (zona::cuda_devices(&notice).empty()) {
    // No GPU: the CPU row only, and exactly one notice naming cuda.
    ASSERT_EQ(rows.size(), 1u);
    EXPECT_EQ(rows[0].rfind("cpu,svk,gradient,1,1,150,", 0), 0u) << rows[0];
    int notices = 0;
    std::istringstream err(r.err);
    while (std::getline(err, line))
      if (line.find("notice") != std::string::npos) {
        ++notices;
        EXPECT_NE(line.find("cuda"), std::string::npos) << line;
      }
    EXPECT_EQ(notices, 1) << r.err;
  } else {
    EXPECT_EQ(rows.size(), 2u);
  }
  // The summary table goes to stdout when the CSV goes to a file.
  EXPECT_NE(r.out.find("step_ms"), std::string::npos);
}

// Output of a shell command (stdout) and its exit status.
std::pair<std::string, int> shell(const std::string& cmd) {
  std::string out;
  FILE* p = popen(cmd.c_str(), "r");
  if (!p) return {out, -1};
  char buf[4096];
  while (size_t n = fread(buf, 1, sizeof buf, p)) out.append(buf, n);
  const int status = pclose(p);
  return {out, WIFEXITED(status) ? WEXITSTATUS(status) : -1};
}

// The header and data rows of a CSV (comment lines skipped); the file is removed.
std::pair<std::string, std::vector<std::string>> read_and_remove_csv(const std::string& path) {
  std::string header, line;
  std::vector<std::string> rows;
  {
    std::ifstream f(path);
    while (std::getline(f, line)) {
      if (line.rfind("#", 0) == 0) continue;
      if (header.empty())
        header = line;
      else
        rows.push_back(line);
    }
  }
  std::filesystem::remove(path);
  return {header, rows};
}

// bench/repeat_bench.sh: every run's rows under one header with the run index and the host's
// steal time in front, and a median / range line per row on stdout; usage errors exit 2.
TEST(BenchCli, RepeatScriptCollectsEveryRunAndSummarises) {
  const std::string script = std::string(ZONA_SOURCE_DIR) + "/bench/repeat_bench.sh";
  const std::string path =
      (std::filesystem::temp_directory_path() / "zona_repeat_bench_tiny.csv").string();
  const auto [out, code] =
      shell("bash " + script + " " + ZONA_CLI_PATH + " 3 0 " + path +
            " --backend cpu --vertices 150 --steps 2 --repeats 1 --threads 1 --copy-mib 4 2>/dev/null");
  ASSERT_EQ(code, 0) << out;
  const auto [header, rows] = read_and_remove_csv(path);
  EXPECT_EQ(header.rfind("run,host_steal_pct,backend,model,formulation,", 0), 0u) << header;
  ASSERT_EQ(rows.size(), 3u);
  for (int i = 0; i < 3; ++i)
    EXPECT_EQ(rows[static_cast<size_t>(i)].rfind(std::to_string(i + 1) + ",", 0), 0u)
        << rows[static_cast<size_t>(i)];
  EXPECT_EQ(out.rfind("cpu 1 threads, ", 0), 0u) << out;  // (the generator's vertex count)
  EXPECT_NE(out.find(" vertices: step_ms_median over 3 runs: median "), std::string::npos) << out;
  EXPECT_EQ(shell("bash " + script + " 2>/dev/null").second, 2);
}

#ifdef ZONA_VCPU_PROBE_PATH
// bench/vcpu_pair_bench, both kernels: one line per round, the combined two-thread rate over the
// one-thread rate consistent with the rates printed; bad options exit 2. (Its value, ~1 to ~2,
// depends on the machine and the minute.)
TEST(BenchCli, VcpuPairProbePrintsConsistentRates) {
  const std::string probe = ZONA_VCPU_PROBE_PATH;
  for (const char* kernel : {"", " --stream-kib 64"}) {
    const auto [out, code] =
        shell(probe + " --iterations 2000000 --rounds 3" + kernel + " 2>&1");
    if (code == 1) GTEST_SKIP() << out;  // no AVX2/FMA on this CPU
    ASSERT_EQ(code, 0) << out;
    std::istringstream lines(out);
    std::string line;
    int rounds = 0;
    while (std::getline(lines, line)) {
      std::istringstream row(line);
      double one = 0, a = 0, b = 0, pair = 0;
      ASSERT_TRUE(row >> one >> a >> b >> pair) << kernel << ": " << line;
      EXPECT_GT(one, 0) << line;
      EXPECT_GT(a, 0) << line;
      EXPECT_GT(b, 0) << line;
      // (No bound on the value itself: a preempted one-thread sample makes it anything.)
      EXPECT_NEAR(pair, (a + b) / one, 0.002 + 1e-3 * pair) << kernel << ": " << line;
      ++rounds;
    }
    EXPECT_EQ(rounds, 3) << kernel;
  }
  EXPECT_EQ(shell(probe + " --rounds 0 2>/dev/null").second, 2);
  EXPECT_EQ(shell(probe + " --stream-kib -1 2>/dev/null").second, 2);
  EXPECT_EQ(shell(probe + " --bogus 2>/dev/null").second, 2);
}

// VCPU_PROBE adds the probe's readings before and after each run as two more leading columns.
TEST(BenchCli, RepeatScriptAddsTheProbeColumns) {
  const std::string script = std::string(ZONA_SOURCE_DIR) + "/bench/repeat_bench.sh";
  const std::string path =
      (std::filesystem::temp_directory_path() / "zona_repeat_bench_probe.csv").string();
  if (shell(std::string(ZONA_VCPU_PROBE_PATH) + " --iterations 1000 --rounds 1 >/dev/null 2>&1")
          .second == 1)
    GTEST_SKIP() << "no AVX2/FMA on this CPU";
  const auto [out, code] =
      shell(std::string("VCPU_PROBE=") + ZONA_VCPU_PROBE_PATH + " bash " + script + " " +
            ZONA_CLI_PATH + " 2 0 " + path +
            " --backend cpu --vertices 150 --steps 2 --repeats 1 --threads 1 --copy-mib 4 2>/dev/null");
  ASSERT_EQ(code, 0) << out;
  const auto [header, rows] = read_and_remove_csv(path);
  EXPECT_EQ(header.rfind("run,host_steal_pct,vcpu_pair_before,vcpu_pair_after,backend,", 0), 0u)
      << header;
  ASSERT_EQ(rows.size(), 2u);
  for (const std::string& row : rows) {
    std::istringstream cells(row);
    std::string run, steal, before, after, backend;
    std::getline(cells, run, ',');
    std::getline(cells, steal, ',');
    std::getline(cells, before, ',');
    std::getline(cells, after, ',');
    std::getline(cells, backend, ',');
    EXPECT_GT(std::stod(before), 0) << row;
    EXPECT_GT(std::stod(after), 0) << row;
    EXPECT_EQ(backend, "cpu") << row;
  }
}
#endif

}  // namespace
