// Tests for engine/scene/scene_find.cpp: the one scene lookup of every command (a path as given,
// ./scenes, $ZONA_SCENES_DIR, the installed scenes, the source tree's scenes, in that order).
#include <gtest/gtest.h>
#include <unistd.h>

#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <string>
#include <vector>

#include "engine/scene/scene.h"

namespace zona {
namespace {

namespace fs = std::filesystem;

// A folder of its own per test, removed afterwards, with $ZONA_SCENES_DIR restored.
struct SceneFind : ::testing::Test {
  fs::path root;
  std::string saved_env;
  bool had_env = false;
  void SetUp() override {
    root = fs::temp_directory_path() /
           ("zona_scene_find_" + std::to_string(::getpid()) + "_" +
            ::testing::UnitTest::GetInstance()->current_test_info()->name());
    fs::create_directories(root);
    if (const char* env = std::getenv("ZONA_SCENES_DIR")) {
      had_env = true;
      saved_env = env;
    }
  }
  void TearDown() override {
    if (had_env)
      ::setenv("ZONA_SCENES_DIR", saved_env.c_str(), 1);
    else
      ::unsetenv("ZONA_SCENES_DIR");
    std::error_code ec;
    fs::remove_all(root, ec);
  }
  std::string put(const std::string& folder, const std::string& file) {
    fs::create_directories(root / folder);
    const fs::path p = root / folder / file;
    std::ofstream(p) << "{}\n";
    return p.string();
  }
};

TEST_F(SceneFind, SearchOrderIsWorkingFolderEnvInstalledSource) {
  ::setenv("ZONA_SCENES_DIR", "/env/scenes", 1);
  const std::vector<std::string> dirs = scene_search_dirs("/opt/zona/share/zona/scenes", "/src/scenes");
  EXPECT_EQ(dirs, (std::vector<std::string>{"scenes", "/env/scenes", "/opt/zona/share/zona/scenes",
                                            "/src/scenes"}));
  ::unsetenv("ZONA_SCENES_DIR");
  EXPECT_EQ(scene_search_dirs("", "/src/scenes"), (std::vector<std::string>{"scenes", "/src/scenes"}));
  EXPECT_EQ(scene_search_dirs(), (std::vector<std::string>{"scenes"}));
}

TEST_F(SceneFind, RelativeInstalledFolderIsTakenFromTheProgramsFolder) {
  // The test binary stands in for the installed zona: bin/../share/zona/scenes.
  const fs::path exe = fs::read_symlink("/proc/self/exe");
  const std::vector<std::string> dirs = scene_search_dirs("../share/zona/scenes");
  ASSERT_EQ(dirs.size(), 2u);
  EXPECT_EQ(dirs[1], (exe.parent_path() / "../share/zona/scenes").lexically_normal().string());
}

TEST_F(SceneFind, FirstFolderHoldingTheNameWins) {
  const std::string local = put("cwd/scenes", "cell.json");
  const std::string env = put("env", "cell.json");
  put("installed", "cell.json");
  const std::string source_only = put("source", "only_in_source.json");
  const std::vector<std::string> dirs = {(root / "cwd/scenes").string(), (root / "env").string(),
                                         (root / "installed").string(), (root / "source").string()};
  Result<std::string> found = find_scene("cell", dirs);
  ASSERT_TRUE(found.ok()) << found.error().message;
  EXPECT_EQ(*found, local);
  // Without the working folder's copy the next folder gives it.
  fs::remove(local);
  found = find_scene("cell.json", dirs);
  ASSERT_TRUE(found.ok()) << found.error().message;
  EXPECT_EQ(*found, env);
  // The source tree comes last but is still searched.
  found = find_scene("only_in_source", dirs);
  ASSERT_TRUE(found.ok()) << found.error().message;
  EXPECT_EQ(*found, source_only);
}

TEST_F(SceneFind, PathAsGivenBeatsEveryFolder) {
  const std::string given = put("given", "cell.json");
  put("scenes", "cell.json");
  Result<std::string> found = find_scene(given, {(root / "scenes").string()});
  ASSERT_TRUE(found.ok());
  EXPECT_EQ(*found, given);
}

TEST_F(SceneFind, EnvironmentFolderIsSearchedByDefault) {
  const std::string env = put("env", "only_in_env.json");
  ::setenv("ZONA_SCENES_DIR", (root / "env").string().c_str(), 1);
  Result<std::string> found = find_scene("only_in_env");
  ASSERT_TRUE(found.ok()) << found.error().message;
  EXPECT_EQ(*found, env);
}

TEST_F(SceneFind, MissingNameListsEveryFolderLookedIn) {
  const std::vector<std::string> dirs = {(root / "a").string(), (root / "b").string()};
  Result<std::string> found = find_scene("nowhere", dirs);
  ASSERT_FALSE(found.ok());
  const std::string& m = found.error().message;
  EXPECT_NE(m.find("nowhere.json"), std::string::npos) << m;
  EXPECT_NE(m.find(dirs[0]), std::string::npos) << m;
  EXPECT_NE(m.find(dirs[1]), std::string::npos) << m;
}

}  // namespace
}  // namespace zona
