// Runs python/zona_plot.py in a child process: the interpreter and the script are looked up
// once per call, the child's stdout and stderr come back through one pipe, and its last line is
// the message of a failure.
#include "apps/plot_script.h"

#include <spawn.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cerrno>
#include <cstdlib>
#include <cstring>
#include <filesystem>

extern char** environ;

namespace zona::cli {
namespace {

namespace fs = std::filesystem;

// The last non-empty line of the child's output, without the script's "zona plot: " prefix;
// `own` tells whether the line had it (the script's message, not a Python traceback's end).
std::string last_line(const std::string& output, bool* own) {
  *own = false;
  size_t end = output.find_last_not_of(" \t\r\n");
  if (end == std::string::npos) return "";
  const size_t start = output.rfind('\n', end);
  std::string line = output.substr(start == std::string::npos ? 0 : start + 1,
                                   end + 1 - (start == std::string::npos ? 0 : start + 1));
  const std::string prefix = "zona plot: ";
  if (line.rfind(prefix, 0) == 0) {
    line.erase(0, prefix.size());
    *own = true;
  }
  return line;
}

}  // namespace

Result<PlotScript> find_plot_script() {
  PlotScript tool;
  std::error_code ec;
  // The script: the installed copy beside the installed scenes (relative to the binary, as
  // apps/CMakeLists.txt installs it), else the source tree's.
  const fs::path installed = fs::path(ZONA_INSTALLED_PLOT_SCRIPT);
  const fs::path base = zona::program_dir();
  const fs::path source = fs::path(ZONA_SOURCE_DIR) / "python" / "zona_plot.py";
  if (!base.empty() && fs::is_regular_file(base / installed, ec))
    tool.script = (base / installed).lexically_normal().string();
  else if (fs::is_regular_file(source, ec))
    tool.script = source.string();
  else
    return make_error("%s: the plot script is not there (a copied binary without its source "
                      "tree or installed share/zona)",
                      source.c_str());
  // The interpreter: the one asked for, the project's environment (scripts/setup.sh), python3.
  if (const char* env = std::getenv("ZONA_PYTHON"); env && *env) {
    tool.python = env;
    if (tool.python.find('/') != std::string::npos && !fs::exists(tool.python, ec))
      return make_error("ZONA_PYTHON=%s: no such file", env);
    return tool;
  }
  const fs::path venv = fs::path(ZONA_SOURCE_DIR) / ".venv" / "bin" / "python";
  tool.python = fs::exists(venv, ec) ? venv.string() : "python3";
  return tool;
}

Status run_plot_script(const std::vector<std::string>& args) {
  Result<PlotScript> tool = find_plot_script();
  if (!tool) return tool.error();
  std::vector<std::string> words = {tool->python, tool->script};
  words.insert(words.end(), args.begin(), args.end());
  std::vector<char*> argv;
  for (std::string& w : words) argv.push_back(w.data());
  argv.push_back(nullptr);

  // One pipe for stdout and stderr: warnings come first, the script's own line last.
  int fds[2];
  if (pipe(fds) != 0) return make_error("plot: cannot create a pipe: %s", std::strerror(errno));
  posix_spawn_file_actions_t actions;
  posix_spawn_file_actions_init(&actions);
  posix_spawn_file_actions_addclose(&actions, fds[0]);
  posix_spawn_file_actions_adddup2(&actions, fds[1], STDOUT_FILENO);
  posix_spawn_file_actions_adddup2(&actions, fds[1], STDERR_FILENO);
  posix_spawn_file_actions_addclose(&actions, fds[1]);
  pid_t pid = -1;
  const int spawned = posix_spawnp(&pid, tool->python.c_str(), &actions, nullptr, argv.data(), environ);
  posix_spawn_file_actions_destroy(&actions);
  close(fds[1]);
  const std::string cannot_start = tool->python +
                                   ": cannot start the Python interpreter for the plots (bash "
                                   "scripts/setup.sh makes .venv; or set ZONA_PYTHON)";
  if (spawned != 0) {
    close(fds[0]);
    return make_error("%s: %s", cannot_start.c_str(), std::strerror(spawned));
  }
  std::string output;
  char buffer[4096];
  for (;;) {
    const ssize_t n = read(fds[0], buffer, sizeof buffer);
    if (n > 0) output.append(buffer, static_cast<size_t>(n));
    else if (n == 0 || errno != EINTR) break;
  }
  close(fds[0]);
  int status = 0;
  while (waitpid(pid, &status, 0) < 0 && errno == EINTR) {
  }
  if (WIFEXITED(status) && WEXITSTATUS(status) == 0) return Status::ok_status();
  // 127: the shell convention for an exec that failed in the child (posix_spawnp reports it so
  // on some C libraries instead of returning the error).
  if (WIFEXITED(status) && WEXITSTATUS(status) == 127) return make_error("%s", cannot_start.c_str());
  bool own = false;
  std::string line = last_line(output, &own);
  if (own && WIFEXITED(status)) return make_error("%s", line.c_str());
  if (line.empty()) line = WIFSIGNALED(status) ? "killed by a signal" : "no message";
  return make_error("%s: %s", tool->script.c_str(), line.c_str());
}

std::vector<std::string> plot_files(const std::string& stem) { return {stem + ".png", stem + ".svg"}; }

}  // namespace zona::cli
