// zona: command-line entry point. Each command group registers itself from apps/cmd_*.cpp.
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <string>
#include <vector>

#include "apps/commands.h"
#include "engine/scene/scene.h"
#include "engine/sim/backend.h"
#include "engine/sim/static_run.h"
#include "build_commit.h"  // generated: ZONA_BUILD_COMMIT

namespace zona::cli {

int& exit_code() {
  static int code = 0;
  return code;
}

void fail(const std::string& message) {
  std::fprintf(stderr, "zona: error: %s\n", message.c_str());
  exit_code() = 1;
}

Result<std::string> find_scene_file(const std::string& name) {
  // ZONA_INSTALLED_SCENES is relative to the installed binary's folder (apps/CMakeLists.txt).
  Result<std::string> path = find_scene(
      name, scene_search_dirs(ZONA_INSTALLED_SCENES, std::string(ZONA_SOURCE_DIR) + "/scenes"));
  if (!path.ok()) return path;
  std::error_code ec;
  const std::filesystem::path absolute = std::filesystem::absolute(*path, ec);
  return ec ? *path : absolute.lexically_normal().string();
}

void add_solver_option(CLI::App* cmd, std::string* solver) {
  cmd->add_option("--solver", *solver,
                  "explicit (dynamics) or static (equilibrium per needle position; "
                  "docs/static.md); default: the scene's solver.method")
      ->check(CLI::IsMember({"explicit", "static"}));
}

std::vector<std::string> with_solver(std::vector<std::string> sets, const std::string& solver) {
  if (!solver.empty()) sets.push_back("solver.method=" + solver);
  return sets;
}

Status static_backend(const Scene& scene, BackendKind* kind) {
  if (scene.solver.method != SolverMethod::kStatic) return {};
  if (Status st = check_static_scene(scene); !st) return st;
  if (*kind == BackendKind::kCuda)
    return make_error("solver.method \"static\" runs on the CPU (its GPU path is not built "
                      "yet): use --backend cpu, or the explicit solver on the GPU");
  *kind = BackendKind::kCpu;
  return {};
}

std::string source_commit() {
  // The build's stamp first (it travels with the binary); the checkout's HEAD otherwise.
  if (const std::string stamp = ZONA_BUILD_COMMIT; !stamp.empty()) return stamp;
  const std::string git = std::string(ZONA_SOURCE_DIR) + "/.git/";
  std::ifstream head(git + "HEAD");
  std::string line;
  if (!std::getline(head, line)) return "";
  if (line.rfind("ref: ", 0) != 0) return line.substr(0, 12);
  const std::string ref = line.substr(5);
  std::ifstream loose(git + ref);
  if (std::getline(loose, line) && line.size() >= 12) return line.substr(0, 12);
  std::ifstream packed(git + "packed-refs");
  while (std::getline(packed, line)) {
    const size_t space = line.find(' ');
    if (space != std::string::npos && line.substr(space + 1) == ref) return line.substr(0, 12);
  }
  return "";
}

namespace {
std::string& invocation_text() {
  static std::string text;
  return text;
}

// "zona run --set 'name=a b'": a word with anything but [A-Za-z0-9_./=:,+-@%] is single-quoted.
void record_invocation(int argc, char** argv) {
  std::string& out = invocation_text();
  for (int i = 0; i < argc; ++i) {
    const std::string word = argv[i];
    const bool plain = !word.empty() && word.find_first_not_of(
                                            "ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz"
                                            "0123456789_./=:,+-@%") == std::string::npos;
    if (i > 0) out += ' ';
    if (plain) {
      out += word;
      continue;
    }
    out += '\'';
    for (char ch : word) out += ch == '\'' ? std::string("'\\''") : std::string(1, ch);
    out += '\'';
  }
}
}  // namespace

const std::string& invocation() { return invocation_text(); }

}  // namespace zona::cli

namespace {

// Every subcommand a command defines (CLI11's get_subcommands() without a filter gives only the
// parsed ones).
std::vector<const CLI::App*> all_subcommands(const CLI::App& app) {
  return app.get_subcommands([](const CLI::App*) { return true; });
}

}  // namespace

int main(int argc, char** argv) {
  zona::cli::record_invocation(argc, argv);
  CLI::App app{"zona: GPU-accelerated deformable simulation of cells under micro-injection"};
  app.require_subcommand(0, 1);
  app.set_version_flag("--version", std::string("zona ") + ZONA_VERSION);
  zona::cli::add_info_command(app);
  zona::cli::add_mesh_commands(app);
  zona::cli::add_run_command(app);
  zona::cli::add_bench_command(app);
  zona::cli::add_forces_command(app);
  zona::cli::add_render_commands(app);
  zona::cli::add_haptics_command(app);
  zona::cli::add_analytic_commands(app);
  zona::cli::add_calibrate_command(app);
  zona::cli::add_study_commands(app);
  zona::cli::add_plot_command(app);
  zona::cli::add_sweep_command(app);
  // A group (mesh, analytic, study) without its subcommand lists them, checked after parsing:
  // CLI11's own "A subcommand is required" does not say which.
  for (CLI::App* group : app.get_subcommands([](CLI::App* c) { return !all_subcommands(*c).empty(); }))
    group->require_subcommand(0, 1);
  try {
    app.parse(argc, argv);
  } catch (const CLI::CallForHelp& e) {
    return app.exit(e);
  } catch (const CLI::CallForAllHelp& e) {
    return app.exit(e);
  } catch (const CLI::CallForVersion& e) {
    return app.exit(e);
  } catch (const CLI::ParseError& e) {
    std::fprintf(stderr, "zona: error: %s\n", e.what());
    return 2;
  }
  // `zona` alone: the usage, as a usage error.
  if (app.get_subcommands().empty()) {
    std::fprintf(stderr, "%s", app.help().c_str());
    return 2;
  }
  for (const CLI::App* group : app.get_subcommands()) {
    const std::vector<const CLI::App*> choices = all_subcommands(*group);
    if (choices.empty() || !group->get_subcommands().empty()) continue;
    // A command that runs on its own and has a subcommand besides (`zona sweep SCENE`, `zona
    // sweep collect DIR`) is not a group.
    if (!group->get_options([](const CLI::Option* o) { return o->get_positional(); }).empty()) continue;
    std::string names;
    for (const CLI::App* c : choices) names += (names.empty() ? "" : ", ") + c->get_name();
    std::fprintf(stderr, "zona: error: 'zona %s' needs a subcommand: %s\n",
                 group->get_name().c_str(), names.c_str());
    for (const CLI::App* c : choices)
      std::fprintf(stderr, "  zona %s %-12s %s\n", group->get_name().c_str(),
                   c->get_name().c_str(), c->get_description().c_str());
    std::fprintf(stderr, "  ('zona %s SUBCOMMAND --help' for its options)\n",
                 group->get_name().c_str());
    return 2;
  }
  return zona::cli::exit_code();
}
