// The worker pool: exit codes, signals, start failures, per-slot environments and the stop flag,
// on /bin/sh children.
#include "engine/analysis/worker_pool.h"

#include <gtest/gtest.h>
#include <signal.h>

#include <filesystem>
#include <fstream>
#include <iterator>
#include <set>

namespace zona {
namespace {

namespace fs = std::filesystem;

fs::path temp_dir() {
  const fs::path d = fs::temp_directory_path() /
                     ("zona_worker_pool_" + std::to_string(::getpid()) + "_" +
                      ::testing::UnitTest::GetInstance()->current_test_info()->name());
  fs::remove_all(d);
  fs::create_directories(d);
  return d;
}

std::string slurp(const fs::path& p) {
  std::ifstream in(p);
  return std::string((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
}

WorkerJob shell(const std::string& script, const fs::path& log) {
  return WorkerJob{{"/bin/sh", "-c", script}, {}, log.string()};
}

TEST(WorkerPool, ReportsExitCodesSignalsAndSlots) {
  const fs::path d = temp_dir();
  std::vector<WorkerJob> jobs;
  for (int i = 0; i < 5; ++i) jobs.push_back(shell("echo slot=$POOL_SLOT job=$POOL_JOB; exit " + std::to_string(i), d / ("log" + std::to_string(i))));
  for (int i = 0; i < 5; ++i) jobs[static_cast<size_t>(i)].env = {"POOL_JOB=" + std::to_string(i)};
  jobs.push_back(shell("kill -SEGV $$", d / "segv"));
  jobs.push_back(WorkerJob{{"/no/such/program"}, {}, (d / "noexec").string()});
  jobs.push_back(WorkerJob{{"/bin/true"}, {}, (d / "no/such/folder/log").string()});
  WorkerPoolOptions options;
  options.workers = 2;
  options.slot_env = [](int slot) { return std::vector<std::string>{"POOL_SLOT=" + std::to_string(slot)}; };
  std::vector<WorkerOutcome> outcomes(jobs.size());
  std::vector<int> calls(jobs.size(), 0);
  const size_t left = run_worker_pool(jobs, options, [&](size_t i, const WorkerOutcome& o) {
    outcomes[i] = o;
    ++calls[i];
  });
  EXPECT_EQ(left, 0u);
  for (size_t i = 0; i < jobs.size(); ++i) EXPECT_EQ(calls[i], 1) << i;
  std::set<int> slots;
  for (int i = 0; i < 5; ++i) {
    const WorkerOutcome& o = outcomes[static_cast<size_t>(i)];
    EXPECT_TRUE(o.started);
    EXPECT_EQ(o.exit_code, i);
    EXPECT_EQ(o.signal, 0);
    ASSERT_GE(o.slot, 0);
    ASSERT_LT(o.slot, 2);
    slots.insert(o.slot);
    // The job's own environment and its slot's.
    EXPECT_EQ(slurp(d / ("log" + std::to_string(i))),
              "slot=" + std::to_string(o.slot) + " job=" + std::to_string(i) + "\n");
  }
  EXPECT_EQ(slots.size(), 2u);  // both workers were used
  EXPECT_EQ(outcomes[5].signal, SIGSEGV);
  EXPECT_EQ(outcomes[5].exit_code, -1);
  EXPECT_EQ(describe_outcome(outcomes[5]).rfind("signal 11", 0), 0u) << describe_outcome(outcomes[5]);
  EXPECT_TRUE(outcomes[6].started);  // exec fails in the child: exit 127
  EXPECT_EQ(outcomes[6].exit_code, 127);
  EXPECT_FALSE(outcomes[7].started);  // its log cannot be opened
  EXPECT_NE(outcomes[7].error.find("no/such/folder/log"), std::string::npos) << outcomes[7].error;
  fs::remove_all(d);
}

TEST(WorkerPool, StopStartsNothingMore) {
  const fs::path d = temp_dir();
  std::vector<WorkerJob> jobs = {shell("exit 0", d / "a"), shell("exit 0", d / "b")};
  std::atomic<bool> stop{true};
  WorkerPoolOptions options;
  options.stop = &stop;
  int calls = 0;
  EXPECT_EQ(run_worker_pool(jobs, options, [&](size_t, const WorkerOutcome&) { ++calls; }), 2u);
  EXPECT_EQ(calls, 0);
  fs::remove_all(d);
}

TEST(WorkerPool, SelfExecutableIsThisProgram) {
  const std::string self = self_executable();
  ASSERT_FALSE(self.empty());
  EXPECT_TRUE(fs::exists(self));
  EXPECT_NE(self.find("zona_tests"), std::string::npos) << self;
}

}  // namespace
}  // namespace zona
