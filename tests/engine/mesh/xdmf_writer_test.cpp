// Tests for engine/mesh/xdmf_writer.cpp: the .xdmf of a two-frame series (a Temporal collection
// of whole grids, whole XML after each frame), the .h5 beside it, arrays refused before anything
// is written, and a build without HDF5 refusing with its reason. The .h5's contents are read
// back, against the VTU frames of the same run, by tests/python/test_xdmf.py (h5py, meshio).
#include "engine/mesh/xdmf_writer.h"

#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>
#include <vector>

namespace zona {
namespace {

namespace fs = std::filesystem;

std::string temp_dir() {
  const auto* info = ::testing::UnitTest::GetInstance()->current_test_info();
  const fs::path dir = fs::temp_directory_path() / (std::string("zona_xdmf_") + info->name());
  fs::remove_all(dir);
  fs::create_directories(dir);
  return dir.string();
}

std::string slurp(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  std::ostringstream s;
  s << in.rdbuf();
  return s.str();
}

size_t count(const std::string& text, const std::string& what) {
  size_t n = 0;
  for (size_t at = text.find(what); at != std::string::npos; at = text.find(what, at + 1)) ++n;
  return n;
}

// Two tetrahedra sharing a face, two regions (one named).
Mesh two_tets() {
  Mesh m;
  m.rest_positions = {{0, 0, 0}, {1e-6, 0, 0}, {0, 1e-6, 0}, {0, 0, 1e-6}, {1e-6, 1e-6, 1e-6}};
  m.tets = {{0, 1, 2, 3}, {1, 2, 3, 4}};
  m.tet_region = {1, 2};
  m.regions = {{2, "nucleus"}};
  return m;
}

std::vector<VtkField> point_fields(double scale) {
  return {{"displacement", 3, std::vector<double>(15, scale)},
          {"stress", 9, std::vector<double>(45, 2 * scale)},
          {"von_mises", 1, std::vector<double>(5, 3 * scale)}};
}

std::vector<VtkField> cell_fields() {
  return {{"green_strain", 6, std::vector<double>(12, 0.5)}, {"von_mises_stress", 1, {1, 2}}};
}

TEST(XdmfWriter, TwoFramesMakeATemporalCollectionOfWholeGrids) {
  if (!xdmf_supported()) GTEST_SKIP() << "built without HDF5";
  const std::string dir = temp_dir();
  const std::string xdmf = dir + "/frames.xdmf";
  XdmfOptions options;
  options.field_data = {{"points_at_rest", 1, {1.0}}};
  options.comment = "rest positions -- and a note";
  Result<XdmfWriter> w = XdmfWriter::create(xdmf, two_tets(), options);
  ASSERT_TRUE(w.ok()) << w.error().message;
  EXPECT_EQ(w->h5_path(), dir + "/frames.h5");
  // Whole XML before the first frame too: an empty collection.
  std::string text = slurp(xdmf);
  EXPECT_NE(text.find("CollectionType=\"Temporal\""), std::string::npos);
  EXPECT_EQ(text.substr(text.size() - 8), "</Xdmf>\n");
  ASSERT_TRUE(w->write_frame(0.0, point_fields(0), cell_fields()).ok());
  ASSERT_TRUE(w->write_frame(2.5e-3, point_fields(1e-7), cell_fields()).ok());
  EXPECT_EQ(w->frame_count(), 2u);
  // Readable while the run goes on: each frame leaves the file closed off.
  text = slurp(xdmf);
  EXPECT_EQ(count(text, "<Xdmf Version=\"3.0\">"), 1u);
  EXPECT_EQ(count(text, "</Xdmf>"), 1u);
  EXPECT_EQ(text.substr(text.size() - 8), "</Xdmf>\n");
  EXPECT_EQ(count(text, "GridType=\"Uniform\""), 2u);
  EXPECT_NE(text.find("<Time Value=\"0\"/>"), std::string::npos);
  EXPECT_NE(text.find("<Time Value=\"0.0025\"/>"), std::string::npos);
  // Every grid names the one mesh of the .h5 and its own frame's arrays.
  EXPECT_EQ(count(text, "frames.h5:/mesh/points"), 2u);
  EXPECT_EQ(count(text, "frames.h5:/mesh/tets"), 2u);
  EXPECT_EQ(count(text, "frames.h5:/mesh/region"), 2u);
  EXPECT_NE(text.find("frames.h5:/frames/000001/displacement"), std::string::npos);
  EXPECT_NE(text.find("TopologyType=\"Tetrahedron\" NumberOfElements=\"2\""), std::string::npos);
  EXPECT_NE(text.find("<DataItem Dimensions=\"5 3\" DataType=\"Float\" Precision=\"8\""),
            std::string::npos);
  EXPECT_NE(text.find("Name=\"displacement\" AttributeType=\"Vector\" Center=\"Node\""),
            std::string::npos);
  EXPECT_NE(text.find("Name=\"stress\" AttributeType=\"Tensor\" Center=\"Node\""),
            std::string::npos);
  // Six components in zona's order (xx yy zz xy yz xz) are not XDMF's Tensor6: a Vector of 6.
  EXPECT_NE(text.find("Name=\"green_strain\" AttributeType=\"Vector\" Center=\"Cell\""),
            std::string::npos);
  EXPECT_NE(text.find("<DataItem Dimensions=\"2\" DataType=\"Int\" Precision=\"4\""),
            std::string::npos);
  EXPECT_EQ(count(text, "<Information Name=\"points_at_rest\" Value=\"1\"/>"), 2u);
  EXPECT_EQ(count(text, "<Information Name=\"region:nucleus\" Value=\"2\"/>"), 2u);
  // The note, made fit for an XML comment.
  EXPECT_NE(text.find("<!-- rest positions - - and a note -->"), std::string::npos);
  ASSERT_TRUE(w->close().ok());
  const std::string h5 = slurp(dir + "/frames.h5");
  ASSERT_GE(h5.size(), 8u);
  EXPECT_EQ(h5.substr(0, 8), std::string("\x89HDF\r\n\x1a\n", 8));
  EXPECT_FALSE(w->write_frame(1.0, point_fields(0), cell_fields()).ok());
  fs::remove_all(dir);
}

TEST(XdmfWriter, BadArraysAreRefusedBeforeAnythingIsWritten) {
  if (!xdmf_supported()) GTEST_SKIP() << "built without HDF5";
  const std::string dir = temp_dir();
  Result<XdmfWriter> w = XdmfWriter::create(dir + "/s.xdmf", two_tets());
  ASSERT_TRUE(w.ok()) << w.error().message;
  ASSERT_TRUE(w->write_frame(0.0, point_fields(0), cell_fields()).ok());
  const std::string before = slurp(dir + "/s.xdmf");
  auto refused = [&](const std::vector<VtkField>& points, const std::vector<VtkField>& cells,
                     const std::string& words) {
    const Status s = w->write_frame(1.0, points, cells);
    ASSERT_FALSE(s.ok()) << words;
    EXPECT_NE(s.error().message.find(dir + "/s.xdmf: "), std::string::npos) << s.error().message;
    EXPECT_NE(s.error().message.find(words), std::string::npos) << s.error().message;
    EXPECT_EQ(s.error().message.find('\n'), std::string::npos);
  };
  refused({{"displacement", 3, std::vector<double>(14, 0.0)}}, {}, "has 14 values, expected 5 x 3");
  refused({}, {{"von_mises_stress", 1, {1, 2, 3}}}, "has 3 values, expected 2 x 1");
  refused({{"a/b", 1, std::vector<double>(5, 0.0)}}, {}, "\"a/b\" cannot be written");
  refused({{"h5:x", 1, std::vector<double>(5, 0.0)}}, {}, "\"h5:x\" cannot be written");
  refused({{"x", 1, std::vector<double>(5, 0.0)}}, {{"x", 1, {1, 2}}}, "\"x\" given twice");
  refused({}, {{"region", 1, {1, 2}}}, "\"region\" given twice");
  EXPECT_EQ(w->frame_count(), 1u);
  EXPECT_EQ(slurp(dir + "/s.xdmf"), before);
  fs::remove_all(dir);
}

TEST(XdmfWriter, UnwritablePlacesAndBadMeshesAreOneLineErrors) {
  if (!xdmf_supported()) GTEST_SKIP() << "built without HDF5";
  const Result<XdmfWriter> nowhere = XdmfWriter::create("/nonexistent/dir/f.xdmf", two_tets());
  ASSERT_FALSE(nowhere.ok());
  EXPECT_EQ(nowhere.error().message.rfind("/nonexistent/dir/f.h5: HDF5: cannot create", 0), 0u)
      << nowhere.error().message;
  Mesh bad = two_tets();
  bad.tets[1][3] = 9;
  const std::string dir = temp_dir();
  const Result<XdmfWriter> out_of_range = XdmfWriter::create(dir + "/bad.xdmf", bad);
  ASSERT_FALSE(out_of_range.ok());
  EXPECT_NE(out_of_range.error().message.find("bad.xdmf"), std::string::npos);
  EXPECT_FALSE(fs::exists(dir + "/bad.h5"));
  fs::remove_all(dir);
}

TEST(XdmfWriter, WithoutHdf5TheBuildSaysSo) {
  if (xdmf_supported()) GTEST_SKIP() << "built with HDF5";
  const Result<XdmfWriter> w = XdmfWriter::create("/tmp/zona_xdmf_none/frames.xdmf", two_tets());
  ASSERT_FALSE(w.ok());
  EXPECT_NE(w.error().message.find("built without it"), std::string::npos) << w.error().message;
}

}  // namespace
}  // namespace zona
