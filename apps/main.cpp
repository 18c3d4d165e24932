// zona: command-line entry point. Each command group registers itself from apps/cmd_*.cpp.
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <string>

#include "apps/commands.h"
#include "engine/scene/scene.h"
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

}  // namespace zona::cli

int main(int argc, char** argv) {
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
  return zona::cli::exit_code();
}
