// Registration of the zona command groups; each lives in its own apps/cmd_*.cpp file.
#pragma once

#include <CLI/CLI.hpp>
#include <functional>
#include <string>
#include <vector>

#include "engine/core/base.h"

namespace zona {
class Simulation;
struct Scene;
enum class BackendKind : int32_t;
}

namespace zona::cli {

/// Exit code set by the command that ran (0 success, 1 error, 2 usage).
int& exit_code();
/// Prints "zona: error: MESSAGE" on one line to stderr and sets the exit code to 1.
void fail(const std::string& message);
/// The source revision (12 hex digits), read from the checkout the binary was built from with
/// no git process: HEAD, its branch ref, or packed-refs. Empty when the tree has no .git (a
/// copied tree).
std::string source_commit();
/// The command line this process was started with, words joined by spaces and single-quoted
/// where the shell would split or expand them (summary.json's provenance).
const std::string& invocation();

/// `--solver explicit|static` (the scene key solver.method; docs/static.md) on a command.
void add_solver_option(CLI::App* cmd, std::string* solver);
/// The overrides with solver.method=SOLVER appended when SOLVER is set.
std::vector<std::string> with_solver(std::vector<std::string> sets, const std::string& solver);
/// For a static scene: the backend it runs on (the CPU; "auto" becomes "cpu", "cuda" is
/// refused: the static solver's GPU path is not built) and whether the scene can run static
/// (engine/sim/static_run.h, check_static_scene).
zona::Status static_backend(const zona::Scene& scene, zona::BackendKind* kind);

/// The scene file a command's SCENE argument names, looked up as every command looks it up: a
/// path as given, then ./scenes, $ZONA_SCENES_DIR, the installed scenes, the source tree's
/// scenes (engine/scene/scene.h, scene_search_dirs). The path is absolute, for messages and
/// summary.json.
zona::Result<std::string> find_scene_file(const std::string& name);

void add_info_command(CLI::App& app);
void add_mesh_commands(CLI::App& app);
void add_run_command(CLI::App& app);
void add_bench_command(CLI::App& app);
void add_forces_command(CLI::App& app);
void add_render_commands(CLI::App& app);
void add_haptics_command(CLI::App& app);
void add_analytic_commands(CLI::App& app);
void add_calibrate_command(CLI::App& app);
void add_study_commands(CLI::App& app);
void add_plot_command(CLI::App& app);
void add_sweep_command(CLI::App& app);

/// Writes one PNG frame of a simulation (DIR/frame_00000.png, ...), for `zona run --frames DIR`.
using PngFrameWriter = std::function<zona::Status(const zona::Simulation&)>;
/// A PNG frame writer of `width` x `height` colouring `color` ("displacement", "stress",
/// "none"); an error value when built without the Vulkan renderer or without a Vulkan device.
zona::Result<PngFrameWriter> make_png_frame_writer(const zona::Simulation& simulation,
                                                   const std::string& directory,
                                                   const std::string& color, int width = 1280,
                                                   int height = 720);

}  // namespace zona::cli
