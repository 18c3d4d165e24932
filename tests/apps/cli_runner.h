// Running the `zona` program from tests (the CLI tests in tests/apps): one helper that captures
// the exit code, stdout and stderr, and a temporary folder per test.
#pragma once

#include <gtest/gtest.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <string>

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

/// Runs `zona ARGS` (ARGS as shell words) and captures its output through two files in `dir`
/// (the temporary folder when empty), removed afterwards.
inline CliRun run_zona(const std::string& args, const std::filesystem::path& dir = {}) {
  const std::filesystem::path folder = dir.empty() ? std::filesystem::temp_directory_path() : dir;
  const std::string tag = current_test_tag();
  const std::string out_path = (folder / ("zona_cli_out_" + tag)).string();
  const std::string err_path = (folder / ("zona_cli_err_" + tag)).string();
  std::string cmd = ZONA_CLI_PATH;
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
