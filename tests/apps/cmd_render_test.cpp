// End-to-end tests of `zona render`: a PNG of a scene at rest with validation on, one-line
// usage errors, and the answer of a build without the renderer.
#include <gtest/gtest.h>
#include <unistd.h>

#include <algorithm>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <string>

namespace {

struct CliRun {
  int exit_code = -1;
  std::string out, err;
};

// Runs the zona binary with `args`; stdout and stderr go through temp files.
CliRun run_zona(const std::string& args) {
  const std::filesystem::path dir = std::filesystem::temp_directory_path();
  const std::string tag = std::to_string(::getpid()) + "_" +
                          ::testing::UnitTest::GetInstance()->current_test_info()->name();
  const std::string out_path = (dir / ("zona_render_out_" + tag)).string();
  const std::string err_path = (dir / ("zona_render_err_" + tag)).string();
  const std::string cmd =
      std::string(ZONA_CLI_PATH) + " " + args + " >" + out_path + " 2>" + err_path;
  const int status = std::system(cmd.c_str());
  CliRun r;
  r.exit_code = WIFEXITED(status) ? WEXITSTATUS(status) : -1;
  auto slurp = [](const std::string& p) {
    std::ifstream f(p);
    return std::string((std::istreambuf_iterator<char>(f)), std::istreambuf_iterator<char>());
  };
  r.out = slurp(out_path);
  r.err = slurp(err_path);
  std::filesystem::remove(out_path);
  std::filesystem::remove(err_path);
  return r;
}

TEST(CmdRender, WritesAPngOfTheSceneWithValidationClean) {
  const std::string png = (std::filesystem::temp_directory_path() /
                           ("zona_render_" + std::to_string(::getpid()) + ".png"))
                              .string();
  // A coarse ball: the scene mesh is regenerated with few vertices to keep the test fast.
  const CliRun r = run_zona("render bench_ball --set mesh.generate.vertices=400 --out " + png +
                            " --width 96 --height 64 --samples 1 --validate");
#if defined(ZONA_HAVE_VULKAN)
  if (r.exit_code != 0 && (r.err.find("no Vulkan") != std::string::npos ||
                           r.err.find("not installed") != std::string::npos))
    GTEST_SKIP() << r.err;
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_NE(r.out.find("wrote " + png), std::string::npos) << r.out;
  ASSERT_TRUE(std::filesystem::exists(png));
  // A PNG signature and more than a blank image's worth of bytes.
  std::ifstream f(png, std::ios::binary);
  char magic[8] = {};
  f.read(magic, 8);
  EXPECT_EQ(std::string(magic + 1, 3), "PNG");
  EXPECT_GT(std::filesystem::file_size(png), 500u);
  std::filesystem::remove(png);
#else
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_NE(r.err.find("built without the Vulkan renderer"), std::string::npos) << r.err;
#endif
}

TEST(CmdRender, BadOptionsAreOneLineErrors) {
  CliRun r = run_zona("render bench_ball --out x.png --color strain");
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_EQ(std::count(r.err.begin(), r.err.end(), '\n'), 1) << r.err;
#if defined(ZONA_HAVE_VULKAN)
  EXPECT_NE(r.err.find("--color"), std::string::npos) << r.err;
  r = run_zona("render bench_ball --out x.png --time 5kg");
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_NE(r.err.find("--time"), std::string::npos) << r.err;
  r = run_zona("render bench_ball");
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_NE(r.err.find("--out or --frames"), std::string::npos) << r.err;
#endif
}

}  // namespace
