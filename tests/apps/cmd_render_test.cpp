// End-to-end tests of `zona render`: a PNG of a scene at rest with validation on, one-line
// usage errors, and the answer of a build without the renderer.
#include <gtest/gtest.h>
#include <unistd.h>

#include <algorithm>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <string>

#include "tests/apps/cli_runner.h"

namespace {

using zona::test::CliRun;
using zona::test::run_zona;

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

TEST(CmdRender, BackendChoiceAndTheCopyPathFallback) {
#if defined(ZONA_HAVE_VULKAN)
  const std::string png = (std::filesystem::temp_directory_path() /
                           ("zona_render_backend_" + std::to_string(::getpid()) + ".png"))
                              .string();
  const std::string base = "render bench_ball --set mesh.generate.vertices=300 --width 64 "
                           "--height 48 --samples 1 --time 20us --out " + png;
  // auto: the GPU with interop where there is one, else the CPU and the copy path; the line
  // says which path drew the frame.
  CliRun r = run_zona(base + " --backend auto");
  if (r.exit_code != 0 && r.err.find("no Vulkan") != std::string::npos) GTEST_SKIP() << r.err;
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_TRUE(r.out.find("interop path") != std::string::npos ||
              r.out.find("copy path") != std::string::npos)
      << r.out;
  // The copy path without an interop notice means the simulation fell back to the CPU: the
  // simulation's note says so, as `zona run` prints it.
  if (r.out.find("copy path") != std::string::npos &&
      r.err.find("interop unavailable") == std::string::npos) {
    EXPECT_NE(r.err.find("zona render: note: "), std::string::npos) << r.err;
  }
  // --copy-path always copies.
  r = run_zona(base + " --backend auto --copy-path");
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_NE(r.out.find("copy path"), std::string::npos) << r.out;
  std::filesystem::remove(png);
  // An unknown backend is a one-line error naming the accepted values.
  r = run_zona(base + " --backend gpu");
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_EQ(std::count(r.err.begin(), r.err.end(), '\n'), 1) << r.err;
  EXPECT_NE(r.err.find("cuda"), std::string::npos) << r.err;
#else
  GTEST_SKIP() << "built without the Vulkan renderer";
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
