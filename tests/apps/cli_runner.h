// Running the `zona` program from tests (the CLI tests in tests/apps): one helper that captures
// the exit code, stdout and stderr, one that starts it in the background (to signal it), and a
// temporary folder per test.
#pragma once

#include <gtest/gtest.h>
#include <signal.h>
#include <spawn.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <csignal>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <string>
#include <thread>

namespace zona::test {

/// What one run of the CLI gave.
struct CliRun {
  int exit_code = -1;  ///< the exit status, -1 when it did not exit normally
  std::string out;     ///< stdout
  std::string err;     ///< stderr
};

/// The name of the running test, unique within the process.
inline std::string current_test_tag() {
  const ::testing::TestInfo* info = ::testing::UnitTest::GetInstance()->current_test_info();
  std::string tag = std::to_string(::getpid());
  if (info) tag.append("_").append(info->test_suite_name()).append("_").append(info->name());
  return tag;
}

/// Runs `PREFIX zona ARGS` (shell words; PREFIX such as "cd DIR && NAME=value") and captures
/// its output through two files in `dir` (the temporary folder when empty), removed afterwards.
inline CliRun run_zona_after(const std::string& prefix, const std::string& args,
                             const std::filesystem::path& dir = {}) {
  const std::filesystem::path folder = dir.empty() ? std::filesystem::temp_directory_path() : dir;
  const std::string tag = current_test_tag();
  const std::string out_path = (std::filesystem::absolute(folder) / ("zona_cli_out_" + tag)).string();
  const std::string err_path = (std::filesystem::absolute(folder) / ("zona_cli_err_" + tag)).string();
  std::string cmd = prefix + (prefix.empty() ? "" : " ") + ZONA_CLI_PATH;
  cmd.append(" ").append(args).append(" >").append(out_path).append(" 2>").append(err_path);
  const int status = std::system(cmd.c_str());
  CliRun r;
  r.exit_code = WIFEXITED(status) ? WEXITSTATUS(status) : -1;
  auto slurp = [](const std::string& p) {
    std::ifstream f(p);
    return std::string((std::istreambuf_iterator<char>(f)), std::istreambuf_iterator<char>());
  };
  r.out = slurp(out_path);
  r.err = slurp(err_path);
  std::error_code ec;
  std::filesystem::remove(out_path, ec);
  std::filesystem::remove(err_path, ec);
  return r;
}

/// Runs `zona ARGS` (ARGS as shell words) and captures its output through two files in `dir`
/// (the temporary folder when empty), removed afterwards.
inline CliRun run_zona(const std::string& args, const std::filesystem::path& dir = {}) {
  return run_zona_after("", args, dir);
}

/// True when the Python that `zona` draws its plots with (apps/plot_script.h: $ZONA_PYTHON, the
/// source tree's .venv, python3) imports matplotlib. Plot tests that need it skip without it.
inline bool plot_python_available() {
  std::string python = "python3";
  if (const char* env = std::getenv("ZONA_PYTHON"); env && *env)
    python = env;
  else if (std::filesystem::exists(std::string(ZONA_SOURCE_DIR) + "/.venv/bin/python"))
    python = std::string(ZONA_SOURCE_DIR) + "/.venv/bin/python";
  const std::string cmd = "'" + python + "' -c 'import matplotlib' >/dev/null 2>&1";
  return std::system(cmd.c_str()) == 0;
}

/// The whole of a file ("" when it cannot be read).
inline std::string read_text(const std::filesystem::path& path) {
  std::ifstream f(path, std::ios::binary);
  return std::string((std::istreambuf_iterator<char>(f)), std::istreambuf_iterator<char>());
}

/// A `zona` started in the background, for tests that watch its files or signal it.
struct CliProcess {
  pid_t pid = -1;
  std::string out_path, err_path;  ///< its stdout and stderr
  bool reaped = false;
  int status = 0;  ///< waitpid status once reaped
};

/// Starts `zona ARGS` (ARGS as shell words; the shell execs zona, so `pid` is zona's own) with
/// stdout and stderr going to two files in `dir`.
inline CliProcess start_zona(const std::string& args, const std::filesystem::path& dir) {
  CliProcess p;
  const std::string tag = current_test_tag();
  p.out_path = (dir / ("zona_cli_out_" + tag)).string();
  p.err_path = (dir / ("zona_cli_err_" + tag)).string();
  const std::string cmd = std::string("exec ") + ZONA_CLI_PATH + " " + args + " >" + p.out_path +
                          " 2>" + p.err_path;
  const char* argv[] = {"sh", "-c", cmd.c_str(), nullptr};
  // SIGINT and SIGTERM at their defaults, whatever this process inherited (a test runner
  // started in the background ignores SIGINT, and zona keeps a signal its parent ignores).
  posix_spawnattr_t attr;
  ::posix_spawnattr_init(&attr);
  sigset_t defaults;
  sigemptyset(&defaults);
  sigaddset(&defaults, SIGINT);
  sigaddset(&defaults, SIGTERM);
  ::posix_spawnattr_setsigdefault(&attr, &defaults);
  ::posix_spawnattr_setflags(&attr, POSIX_SPAWN_SETSIGDEF);
  if (::posix_spawn(&p.pid, "/bin/sh", nullptr, &attr, const_cast<char* const*>(argv),
                    environ) != 0)
    p.pid = -1;
  ::posix_spawnattr_destroy(&attr);
  return p;
}

/// True once the process has exited (reaps it without blocking).
inline bool has_exited(CliProcess& p) {
  if (!p.reaped && p.pid > 0 && ::waitpid(p.pid, &p.status, WNOHANG) == p.pid) p.reaped = true;
  return p.reaped || p.pid <= 0;
}

/// Waits for the process, killing it (SIGKILL) after `timeout_s`, and returns what it gave
/// (exit_code -1 when it was killed by a signal).
inline CliRun wait_zona(CliProcess& p, double timeout_s) {
  const auto deadline = std::chrono::steady_clock::now() + std::chrono::duration<double>(timeout_s);
  while (!has_exited(p) && std::chrono::steady_clock::now() < deadline)
    std::this_thread::sleep_for(std::chrono::milliseconds(10));
  if (!has_exited(p)) {
    ::kill(p.pid, SIGKILL);
    ::waitpid(p.pid, &p.status, 0);
    p.reaped = true;
  }
  CliRun r;
  r.exit_code = p.pid > 0 && WIFEXITED(p.status) ? WEXITSTATUS(p.status) : -1;
  auto slurp = [](const std::string& path) {
    std::ifstream f(path);
    return std::string((std::istreambuf_iterator<char>(f)), std::istreambuf_iterator<char>());
  };
  r.out = slurp(p.out_path);
  r.err = slurp(p.err_path);
  std::error_code ec;
  std::filesystem::remove(p.out_path, ec);
  std::filesystem::remove(p.err_path, ec);
  return r;
}

/// A temporary folder named after the running test, removed with its contents.
struct TempDir {
  std::filesystem::path path;
  explicit TempDir(const std::string& prefix = "zona_test_") {
    path = std::filesystem::temp_directory_path() / (prefix + current_test_tag());
    std::filesystem::create_directories(path);
  }
  ~TempDir() {
    std::error_code ec;
    std::filesystem::remove_all(path, ec);
  }
  TempDir(const TempDir&) = delete;
  TempDir& operator=(const TempDir&) = delete;
};

}  // namespace zona::test
