// Local worker processes (engine/analysis/worker_pool.h): fork + exec, a slot per child,
// waitpid for the first to end.
#include "engine/analysis/worker_pool.h"

#include <fcntl.h>
#include <signal.h>
#include <sys/prctl.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <chrono>
#include <cstring>
#include <filesystem>
#include <map>

extern char** environ;

namespace zona {
namespace {

// The environment of a child: the parent's with `extra` entries replacing those of the same
// name. Built before fork: after it, only async-signal-safe calls are allowed.
std::vector<std::string> child_environment(const std::vector<std::string>& extra) {
  std::map<std::string, std::string> by_name;
  std::vector<std::string> order;
  auto put = [&](const std::string& entry) {
    const std::string name = entry.substr(0, entry.find('='));
    if (!by_name.count(name)) order.push_back(name);
    by_name[name] = entry;
  };
  for (char** e = environ; e && *e; ++e) put(*e);
  for (const std::string& entry : extra) put(entry);
  std::vector<std::string> out;
  out.reserve(order.size());
  for (const std::string& name : order) out.push_back(by_name[name]);
  return out;
}

struct Running {
  size_t index = 0;
  int slot = 0;
  std::chrono::steady_clock::time_point start;
};

}  // namespace

std::string self_executable() {
  std::error_code ec;
  const std::filesystem::path p = std::filesystem::read_symlink("/proc/self/exe", ec);
  return ec ? std::string() : p.string();
}

std::string describe_outcome(const WorkerOutcome& o) {
  if (!o.started) return "not started: " + o.error;
  if (o.signal != 0) {
    const char* name = strsignal(o.signal);
    return "signal " + std::to_string(o.signal) + " (" + (name ? name : "?") + ")";
  }
  return "exit " + std::to_string(o.exit_code);
}

size_t run_worker_pool(std::span<const WorkerJob> jobs, const WorkerPoolOptions& options,
                       const std::function<void(size_t, const WorkerOutcome&)>& finished) {
  const int workers = std::max(1, options.workers);
  std::map<pid_t, Running> running;
  std::vector<bool> slot_busy(static_cast<size_t>(workers), false);
  const pid_t parent = getpid();
  bool stop_sent = false;
  size_t next = 0;
  auto stopping = [&] { return options.stop && options.stop->load(std::memory_order_relaxed); };

  while (next < jobs.size() || !running.empty()) {
    // Start jobs while a slot is free.
    while (next < jobs.size() && static_cast<int>(running.size()) < workers && !stopping()) {
      int slot = 0;
      while (slot_busy[static_cast<size_t>(slot)]) ++slot;
      const WorkerJob& job = jobs[next];
      WorkerOutcome failed;
      failed.slot = slot;
      std::vector<std::string> extra;
      if (options.slot_env) extra = options.slot_env(slot);
      extra.insert(extra.end(), job.env.begin(), job.env.end());
      const std::vector<std::string> env = child_environment(extra);
      std::vector<char*> envp, argv;
      for (const std::string& e : env) envp.push_back(const_cast<char*>(e.c_str()));
      envp.push_back(nullptr);
      for (const std::string& a : job.argv) argv.push_back(const_cast<char*>(a.c_str()));
      argv.push_back(nullptr);
      const char* log = job.log_path.empty() ? "/dev/null" : job.log_path.c_str();
      const int log_fd = open(log, O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0644);
      const int null_fd = open("/dev/null", O_RDONLY | O_CLOEXEC);
      if (job.argv.empty() || log_fd < 0 || null_fd < 0) {
        failed.error = job.argv.empty() ? "empty command" : std::string(log) + ": " + std::strerror(errno);
        if (log_fd >= 0) close(log_fd);
        if (null_fd >= 0) close(null_fd);
        finished(next++, failed);
        continue;
      }
      const auto start = std::chrono::steady_clock::now();
      const pid_t pid = fork();
      if (pid == 0) {
        // The child: async-signal-safe calls only. It dies with the pool (a killed sweep leaves
        // no orphan writing into a folder that the resumed sweep will rerun).
        prctl(PR_SET_PDEATHSIG, SIGTERM);
        if (getppid() != parent) _exit(127);
        dup2(null_fd, STDIN_FILENO);
        dup2(log_fd, STDOUT_FILENO);
        dup2(log_fd, STDERR_FILENO);
        execve(argv[0], argv.data(), envp.data());
        static const char message[] = "zona: worker: exec failed\n";
        (void)!write(STDERR_FILENO, message, sizeof message - 1);
        _exit(127);
      }
      close(log_fd);
      close(null_fd);
      if (pid < 0) {
        failed.error = std::string("fork: ") + std::strerror(errno);
        finished(next++, failed);
        continue;
      }
      slot_busy[static_cast<size_t>(slot)] = true;
      running[pid] = Running{next++, slot, start};
    }
    if (running.empty()) break;  // stopped with nothing left running
    if (stopping() && !stop_sent) {
      for (const auto& [pid, r] : running) kill(pid, SIGTERM);
      stop_sent = true;
    }
    // Wait for a child to end; a signal (EINTR) goes round the loop to look at `stop`.
    int status = 0;
    const pid_t pid = waitpid(-1, &status, 0);
    if (pid < 0) {
      if (errno == EINTR) continue;
      break;  // ECHILD: nothing left to wait for
    }
    const auto it = running.find(pid);
    if (it == running.end()) continue;  // not one of ours
    WorkerOutcome o;
    o.started = true;
    o.slot = it->second.slot;
    o.wall_seconds =
        std::chrono::duration<double>(std::chrono::steady_clock::now() - it->second.start).count();
    if (WIFEXITED(status)) o.exit_code = WEXITSTATUS(status);
    if (WIFSIGNALED(status)) o.signal = WTERMSIG(status);
    const size_t index = it->second.index;
    slot_busy[static_cast<size_t>(it->second.slot)] = false;
    running.erase(it);
    finished(index, o);
  }
  return jobs.size() - next;
}

}  // namespace zona
