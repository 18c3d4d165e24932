// A local pool of worker processes: runs a list of commands with at most N at once, each a
// child process of its own (fork + exec), so that a point of a sweep or an evaluation of a
// calibration that crashes, runs out of memory or is killed never takes the others with it.
//
// Why processes and not threads: a run can abort (a failed assert, a CUDA error, the OOM killer),
// and with threads that ends the whole sweep; a process also gets its own environment, which is
// how a worker is given its GPU (CUDA_VISIBLE_DEVICES) without the engine knowing about pools.
// It is not a scheduler: on a cluster, SLURM runs the tasks (docs/sweeps.md).
#pragma once

#include <atomic>
#include <functional>
#include <span>
#include <string>
#include <vector>

namespace zona {

/// One command to run.
struct WorkerJob {
  std::vector<std::string> argv;  ///< argv[0] is the program's path (not looked up in PATH)
  /// "NAME=value" entries set in the child's environment on top of the parent's (and of the
  /// slot's, WorkerPoolOptions::slot_env), (entry count).
  std::vector<std::string> env;
  std::string log_path;  ///< stdout and stderr of the child; "" sends both to /dev/null
};

/// How a job ended.
struct WorkerOutcome {
  bool started = false;     ///< false: fork, exec or the log file failed (see `error`)
  int exit_code = -1;       ///< the exit status when it exited normally, else -1
  int signal = 0;           ///< the signal that ended it, else 0
  int slot = -1;            ///< the worker slot it ran in, [0, workers)
  double wall_seconds = 0;  ///< from start to end [s]
  std::string error;        ///< why it did not start
};

/// Options of run_worker_pool.
struct WorkerPoolOptions {
  int workers = 1;  ///< at most this many children at once, >= 1
  /// "NAME=value" entries for every job that runs in a slot (e.g. CUDA_VISIBLE_DEVICES=slot);
  /// may be empty.
  std::function<std::vector<std::string>(int slot)> slot_env;
  /// Set (e.g. by a signal handler) to stop: no job starts after it, and the running children
  /// get SIGTERM. May be null.
  const std::atomic<bool>* stop = nullptr;
};

/// Runs `jobs` with at most options.workers children at once, in order of the list. Calls
/// `finished(index, outcome)` on the calling thread as each job ends (in the order they end);
/// jobs never started because of `stop` get no call. Children get SIGTERM when this process
/// dies (Linux: PR_SET_PDEATHSIG), so a killed pool leaves no orphan writing into its folders.
/// Returns the number of jobs that were not started because of `stop`.
size_t run_worker_pool(std::span<const WorkerJob> jobs, const WorkerPoolOptions& options,
                       const std::function<void(size_t index, const WorkerOutcome&)>& finished);

/// "exit 1", "signal 9 (Killed)", or the start error: how a job ended, in words.
std::string describe_outcome(const WorkerOutcome& outcome);

/// The path of the running program (/proc/self/exe resolved), for children that run the same
/// binary; "" where it cannot be read.
std::string self_executable();

}  // namespace zona
