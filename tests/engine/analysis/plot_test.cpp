// Tests for engine/plot: a chart becomes a PNG of the asked size; empty charts are refused.
#include "engine/analysis/plot.h"

#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <vector>

namespace zona {
namespace {

uint32_t big_endian(const unsigned char* p) {
  return (uint32_t{p[0]} << 24) | (uint32_t{p[1]} << 16) | (uint32_t{p[2]} << 8) | uint32_t{p[3]};
}

TEST(Plot, WritesAPngOfTheAskedSize) {
  if (!plot_png_available()) GTEST_SKIP() << "built without stb_image_write";
  const std::filesystem::path path = std::filesystem::temp_directory_path() / "zona_plot.png";
  PlotSpec spec;
  spec.title = "force vs deformation";
  spec.x_label = "deformation [um]";
  spec.y_label = "force [uN]";
  spec.width = 640;
  spec.height = 400;
  PlotSeries curve{"svk", {0, 10, 20, 30, 45}, {0, 1, 2.5, 4.5, 7.5}, 0x1f77b4, 2, 0};
  PlotSeries point{"Ladjal et al.", {45}, {7.5}, 0xd62728, 0, 6};
  spec.series = {curve, point};
  ASSERT_TRUE(write_plot_png(path.string(), spec).ok());
  std::ifstream in(path, std::ios::binary);
  std::vector<unsigned char> bytes((std::istreambuf_iterator<char>(in)), {});
  ASSERT_GT(bytes.size(), 33u);
  const unsigned char signature[8] = {0x89, 'P', 'N', 'G', '\r', '\n', 0x1a, '\n'};
  EXPECT_TRUE(std::equal(signature, signature + 8, bytes.begin()));
  EXPECT_EQ(big_endian(&bytes[16]), 640u);  // IHDR width
  EXPECT_EQ(big_endian(&bytes[20]), 400u);  // IHDR height
  std::filesystem::remove(path);
}

TEST(Plot, EmptyChartsAndBadPathsAreRefused) {
  PlotSpec spec;
  EXPECT_FALSE(write_plot_png("/tmp/zona_empty.png", spec).ok());
  spec.series.push_back(PlotSeries{"nan", {NAN}, {1.0}, 0, 1, 0});
  EXPECT_FALSE(write_plot_png("/tmp/zona_empty.png", spec).ok());
  spec.series.push_back(PlotSeries{"ok", {0, 1}, {0, 1}, 0, 1, 0});
  EXPECT_FALSE(write_plot_png("/nonexistent/dir/plot.png", spec).ok());
}

}  // namespace
}  // namespace zona
