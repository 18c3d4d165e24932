// Scene lookup shared by every command: a path as given, then ./scenes, $ZONA_SCENES_DIR, the
// installed scenes and the source tree's scenes, so that `zona run NAME` and `zona haptics NAME`
// always read the same file.
#include <cstdlib>
#include <filesystem>
#include <string>
#include <vector>

#include "engine/scene/scene.h"

namespace zona {
namespace fs = std::filesystem;

std::vector<std::string> scene_search_dirs(const std::string& installed_dir,
                                           const std::string& source_dir) {
  // ./scenes first: a user's edited copy in the working folder is what they mean to run.
  std::vector<std::string> dirs{"scenes"};
  if (const char* env = std::getenv("ZONA_SCENES_DIR"); env && *env) dirs.emplace_back(env);
  if (!installed_dir.empty()) {
    fs::path installed(installed_dir);
    if (installed.is_relative()) {
      const fs::path base = zona::program_dir();
      if (!base.empty()) dirs.push_back((base / installed).lexically_normal().string());
    } else {
      dirs.push_back(installed.string());
    }
  }
  if (!source_dir.empty()) dirs.push_back(source_dir);
  return dirs;
}

Result<std::string> find_scene(const std::string& name, const std::vector<std::string>& search_dirs) {
  if (name.empty()) return make_error("empty scene name");
  std::error_code ec;
  if (fs::is_regular_file(name, ec)) return name;
  if (name.find('/') != std::string::npos) {
    // A path: one that exists but is a directory, device or FIFO says so.
    const std::string kind = file_kind(name);
    if (kind.empty()) return make_error("%s: scene file not found", name.c_str());
    return make_error("%s: is not a regular file (%s)", name.c_str(), kind.c_str());
  }
  const std::vector<std::string> dirs = search_dirs.empty() ? scene_search_dirs() : search_dirs;
  const bool has_extension = fs::path(name).extension() == ".json";
  std::string looked;
  for (const std::string& dir : dirs) {
    const fs::path candidate = fs::path(dir) / (has_extension ? name : name + ".json");
    if (fs::is_regular_file(candidate, ec)) return candidate.string();
    looked += (looked.empty() ? "" : ", ") + dir;
  }
  return make_error("scene '%s' not found: not a file, and no %s%s in: %s", name.c_str(),
                    name.c_str(), has_extension ? "" : ".json", looked.c_str());
}

}  // namespace zona
