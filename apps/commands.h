// Registration of the zona command groups; each lives in its own apps/cmd_*.cpp file.
#pragma once

#include <CLI/CLI.hpp>

namespace zona::cli {

/// Exit code set by the command that ran (0 success, 1 error, 2 usage).
int& exit_code();
/// Prints "zona: error: MESSAGE" on one line to stderr and sets the exit code to 1.
void fail(const std::string& message);

void add_info_command(CLI::App& app);
void add_mesh_commands(CLI::App& app);
void add_run_command(CLI::App& app);
void add_bench_command(CLI::App& app);
void add_forces_command(CLI::App& app);

}  // namespace zona::cli
