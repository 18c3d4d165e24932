// Tests for engine/mesh/mesh_io_vtu_read.cpp: write_vtu's files read back (ascii and base64,
// regions and their names, exact coordinates), a frame's deformed positions, VTU beside the
// other formats (convert through Gmsh), and files it does not support refused in one line.
#include <gtest/gtest.h>

#include <algorithm>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>
#include <vector>

#include "engine/mesh/mesh_io.h"

namespace zona {
namespace {

namespace fs = std::filesystem;

std::string temp_dir() {
  const auto* info = ::testing::UnitTest::GetInstance()->current_test_info();
  const fs::path dir = fs::temp_directory_path() / (std::string("zona_vtu_read_") + info->name());
  fs::remove_all(dir);
  fs::create_directories(dir);
  return dir.string();
}

void spit(const std::string& path, const std::string& text) {
  std::ofstream out(path, std::ios::binary);
  out << text;
}

std::string slurp(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  std::ostringstream s;
  s << in.rdbuf();
  return s.str();
}

// Two regions (one named with characters XML escapes), an unnamed tag, coordinates with no
// short decimal form.
Mesh test_mesh() {
  Mesh m;
  for (int i = 0; i < 12; ++i)
    m.rest_positions.push_back(
        {0.1 * (i % 3) + 1.0 / 7, 0.25 * ((i / 3) % 2), 0.3 * (i / 6) + 1.0 / 3});
  m.tets = {{0, 1, 3, 6}, {1, 2, 4, 7}, {1, 3, 4, 7}, {3, 4, 6, 9},
            {1, 4, 7, 11}, {4, 5, 8, 11}, {0, 3, 9, 10}};
  m.tet_region = {2, 1, 2, 0, 5, 1, 2};
  m.regions = {{1, "cytoplasm"}, {2, "zona <\"pellucida\"> & co"}};
  for (size_t t = 0; t < m.tet_count(); ++t)
    if (tet_rest_volume(m, t) < 0) std::swap(m.tets[t][2], m.tets[t][3]);
  return m;
}

void expect_same(const Mesh& a, const Mesh& b) {
  ASSERT_EQ(a.vertex_count(), b.vertex_count());
  for (size_t v = 0; v < a.vertex_count(); ++v)
    for (int k = 0; k < 3; ++k) EXPECT_EQ(a.rest_positions[v][k], b.rest_positions[v][k]) << v;
  EXPECT_EQ(a.tets, b.tets);
  EXPECT_EQ(a.tet_region, b.tet_region);
  ASSERT_EQ(a.regions.size(), b.regions.size());
  for (size_t r = 0; r < a.regions.size(); ++r) {
    EXPECT_EQ(a.regions[r].tag, b.regions[r].tag);
    EXPECT_EQ(a.regions[r].name, b.regions[r].name);
  }
}

TEST(MeshIoVtuRead, RoundTripAsciiAndBinary) {
  const std::string dir = temp_dir();
  const Mesh original = test_mesh();
  for (bool binary : {false, true}) {
    SCOPED_TRACE(binary ? "binary" : "ascii");
    const std::string path = dir + (binary ? "/b.vtu" : "/a.vtu");
    VtuOptions options;
    options.binary = binary;
    std::vector<double> field(3 * original.vertex_count(), 0.5);
    ASSERT_TRUE(write_vtu(path, original, {{"u", 3, field}}, {}, options).ok());
    Result<Mesh> back = read_mesh(path);
    ASSERT_TRUE(back.ok()) << back.error().message;
    expect_same(*back, original);
    // Without the frame's flag, read_positions takes the points as they are.
    Result<std::vector<Vec3d>> points = read_positions(path);
    ASSERT_TRUE(points.ok()) << points.error().message;
    for (size_t v = 0; v < points->size(); ++v)
      EXPECT_EQ((*points)[v].x, original.rest_positions[v].x);
  }
}

TEST(MeshIoVtuRead, ThroughGmshAndBack) {
  const std::string dir = temp_dir();
  const Mesh original = test_mesh();
  ASSERT_TRUE(write_mesh(dir + "/m.vtu", original).ok());
  Result<Mesh> vtu = read_mesh(dir + "/m.vtu");
  ASSERT_TRUE(vtu.ok()) << vtu.error().message;
  Mesh plain = *vtu;
  for (Region& r : plain.regions) r.name = r.tag == 2 ? "zona" : r.name;  // Gmsh quoting aside
  ASSERT_TRUE(write_mesh(dir + "/m.msh", plain).ok());
  Result<Mesh> msh = read_mesh(dir + "/m.msh");
  ASSERT_TRUE(msh.ok()) << msh.error().message;
  ASSERT_TRUE(write_mesh(dir + "/again.vtu", *msh).ok());
  Result<Mesh> again = read_mesh(dir + "/again.vtu");
  ASSERT_TRUE(again.ok()) << again.error().message;
  expect_same(*again, plain);
}

TEST(MeshIoVtuRead, AFrameGivesItsDeformedPositions) {
  const std::string dir = temp_dir();
  const Mesh m = test_mesh();
  std::vector<double> disp(3 * m.vertex_count());
  for (size_t i = 0; i < disp.size(); ++i) disp[i] = 1e-3 * static_cast<double>(i + 1);
  VtuOptions options;
  options.field_data = {{"TimeValue", 1, {0.25}}, {"points_at_rest", 1, {1.0}}};
  options.comment = "points at rest -- warp by displacement";
  ASSERT_TRUE(write_vtu(dir + "/f.vtu", m, {{"displacement", 3, disp}}, {}, options).ok());
  EXPECT_NE(slurp(dir + "/f.vtu").find("<!-- points at rest - - warp"), std::string::npos);
  Result<Mesh> rest = read_mesh(dir + "/f.vtu");
  ASSERT_TRUE(rest.ok()) << rest.error().message;
  expect_same(*rest, m);
  Result<std::vector<Vec3d>> deformed = read_positions(dir + "/f.vtu");
  ASSERT_TRUE(deformed.ok()) << deformed.error().message;
  ASSERT_EQ(deformed->size(), m.vertex_count());
  for (size_t v = 0; v < m.vertex_count(); ++v) {
    EXPECT_EQ((*deformed)[v].x, m.rest_positions[v].x + disp[3 * v]);
    EXPECT_EQ((*deformed)[v].z, m.rest_positions[v].z + disp[3 * v + 2]);
  }
}

// A minimal ascii file of one tetrahedron, with pieces to replace.
std::string one_tet(const std::string& file_attributes = "byte_order=\"LittleEndian\"",
                     const std::string& types = "10", const std::string& format = "ascii") {
  return "<?xml version=\"1.0\"?>\n<VTKFile type=\"UnstructuredGrid\" version=\"1.0\" " +
         file_attributes +
         ">\n<UnstructuredGrid>\n<Piece NumberOfPoints=\"4\" NumberOfCells=\"1\">\n"
         "<Points><DataArray type=\"Float64\" NumberOfComponents=\"3\" format=\"ascii\">\n"
         "0 0 0 1 0 0 0 1 0 0 0 1</DataArray></Points>\n<Cells>\n"
         "<DataArray type=\"Int64\" Name=\"connectivity\" format=\"" + format +
         "\">0 1 2 3</DataArray>\n"
         "<DataArray type=\"Int64\" Name=\"offsets\" format=\"ascii\">4</DataArray>\n"
         "<DataArray type=\"UInt8\" Name=\"types\" format=\"ascii\">" + types +
         "</DataArray>\n</Cells>\n</Piece>\n</UnstructuredGrid>\n</VTKFile>\n";
}

TEST(MeshIoVtuRead, AHandWrittenTetrahedron) {
  const std::string dir = temp_dir();
  spit(dir + "/t.vtu", one_tet());
  Result<Mesh> m = read_mesh(dir + "/t.vtu");
  ASSERT_TRUE(m.ok()) << m.error().message;
  EXPECT_EQ(m->vertex_count(), 4u);
  EXPECT_EQ(m->tet_count(), 1u);
  EXPECT_EQ(m->tet_region, std::vector<int32_t>{0});
}

TEST(MeshIoVtuRead, UnsupportedFilesAreRefusedInOneLine) {
  const std::string dir = temp_dir();
  std::string binary;
  {
    ASSERT_TRUE(write_vtu(dir + "/ok.vtu", test_mesh()).ok());
    binary = slurp(dir + "/ok.vtu");
  }
  std::string truncated = binary;
  {
    // Cut the Points array's base64 short: its header then claims more than it holds.
    const size_t points = truncated.find("Name=\"Points\"");
    const size_t start = truncated.find('>', points) + 1;
    const size_t stop = truncated.find("</DataArray>", start);
    truncated.erase(start + 40, stop - start - 40);
  }
  std::string poly = one_tet();
  poly.replace(poly.find("UnstructuredGrid"), 16, "PolyData");
  const struct {
    const char* label;
    std::string text;
    const char* what;
  } cases[] = {
      {"compressed", one_tet("compressor=\"vtkZLibDataCompressor\""), "compressed"},
      {"big-endian", one_tet("byte_order=\"BigEndian\""), "BigEndian"},
      {"hexahedron", one_tet("byte_order=\"LittleEndian\"", "12"), "VTK type 12"},
      {"appended", one_tet("byte_order=\"LittleEndian\"", "10", "appended"), "appended"},
      {"poly data", poly, "PolyData"},
      {"not xml", "solid cube\nfacet normal 0 0 1\n", "no <VTKFile>"},
      {"truncated base64", truncated, "header says"},
      {"two pieces", one_tet().insert(one_tet().find("</UnstructuredGrid>"),
                                      "<Piece NumberOfPoints=\"0\" NumberOfCells=\"0\"></Piece>\n"),
       "more than one <Piece>"},
      {"bad number", [] {
         std::string s = one_tet();
         s.replace(s.find("0 0 0 1"), 1, "x");
         return s;
       }(), "expected a number"},
      {"out of range", [] {
         std::string s = one_tet();
         s.replace(s.find("0 1 2 3"), 7, "0 1 2 9");
         return s;
       }(), "point 9"},
  };
  for (const auto& c : cases) {
    SCOPED_TRACE(c.label);
    const std::string path = dir + "/bad.vtu";
    spit(path, c.text);
    Result<Mesh> m = read_mesh(path);
    ASSERT_FALSE(m.ok());
    const std::string& msg = m.error().message;
    EXPECT_EQ(msg.rfind(path + ":", 0), 0u) << msg;
    EXPECT_NE(msg.find(c.what), std::string::npos) << msg;
    EXPECT_EQ(msg.find('\n'), std::string::npos) << msg;
    EXPECT_FALSE(read_positions(path).ok());
  }
  // Every prefix of a real file is refused or read, never a crash.
  for (size_t n = 0; n < binary.size(); n += 37) {
    spit(dir + "/cut.vtu", binary.substr(0, n));
    Result<Mesh> m = read_mesh(dir + "/cut.vtu");
    if (!m.ok()) {
      EXPECT_EQ(m.error().message.find('\n'), std::string::npos);
    }
  }
}

}  // namespace
}  // namespace zona

namespace zona {
namespace {

TEST(MeshIoVtuRead, ReadVtuKeepsEveryArray) {
  // read_vtu gives back every point, cell and field array bit for bit (base64 and ascii),
  // with the points and tetrahedra as written.
  const std::string dir = temp_dir();
  const Mesh m = test_mesh();
  std::vector<double> stress(9 * m.vertex_count()), mises(m.tet_count());
  for (size_t i = 0; i < stress.size(); ++i) stress[i] = 1.0 / static_cast<double>(i + 3);
  for (size_t t = 0; t < mises.size(); ++t) mises[t] = 1e3 * static_cast<double>(t) + 0.1;
  for (bool binary : {false, true}) {
    SCOPED_TRACE(binary ? "binary" : "ascii");
    VtuOptions options;
    options.binary = binary;
    options.field_data = {{"TimeValue", 1, {0.125}}, {"points_at_rest", 1, {1.0}}};
    const std::string path = dir + (binary ? "/b.vtu" : "/a.vtu");
    ASSERT_TRUE(
        write_vtu(path, m, {{"stress", 9, stress}}, {{"von_mises_stress", 1, mises}}, options).ok());
    Result<VtuFile> f = read_vtu(path);
    ASSERT_TRUE(f.ok()) << f.error().message;
    ASSERT_EQ(f->points.size(), m.vertex_count());
    for (size_t v = 0; v < m.vertex_count(); ++v) EXPECT_EQ(f->points[v].y, m.rest_positions[v].y);
    EXPECT_EQ(f->tets, m.tets);
    ASSERT_EQ(f->point_data.size(), 1u);
    EXPECT_EQ(f->point_data[0].name, "stress");
    EXPECT_EQ(f->point_data[0].components, 9);
    EXPECT_EQ(f->point_data[0].values, stress);
    ASSERT_EQ(f->cell_data.size(), 2u);  // the writer's "region" and ours
    bool seen = false;
    for (const VtkField& c : f->cell_data)
      if (c.name == "von_mises_stress") {
        seen = true;
        EXPECT_EQ(c.values, mises);
      }
    EXPECT_TRUE(seen);
    std::vector<std::string> fields;
    for (const VtkField& c : f->field_data) fields.push_back(c.name);
    EXPECT_NE(std::find(fields.begin(), fields.end(), "TimeValue"), fields.end());
    EXPECT_EQ(f->regions.size(), m.regions.size());
  }
}

TEST(MeshIoVtuRead, ReadVtuRefusesAnArrayOfTheWrongLength) {
  const std::string dir = temp_dir();
  std::string text = one_tet();
  text.replace(text.find("</Piece>"), 0,
               "<PointData><DataArray type=\"Float64\" Name=\"p\" format=\"ascii\">1 2 3"
               "</DataArray></PointData>\n");
  spit(dir + "/short.vtu", text);
  Result<VtuFile> f = read_vtu(dir + "/short.vtu");
  ASSERT_FALSE(f.ok());
  EXPECT_NE(f.error().message.find("short.vtu:"), std::string::npos) << f.error().message;
  EXPECT_NE(f.error().message.find("point array 'p' has 3 values for 4 points"), std::string::npos)
      << f.error().message;
  EXPECT_EQ(f.error().message.find('\n'), std::string::npos);
  EXPECT_FALSE(read_vtu(dir + "/missing.vtu").ok());
}

}  // namespace
}  // namespace zona
