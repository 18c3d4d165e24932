// Tests for engine/mesh_io: meshes written by the real Gmsh and TetGen programs, round trips
// through the writers, VTK output, and a table of malformed files that must be refused cleanly.
#include "engine/mesh/mesh_io.h"

#include <gtest/gtest.h>
#include <sys/stat.h>

#include <bit>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <map>
#include <sstream>

namespace zona {
namespace {

namespace fs = std::filesystem;

std::string data_path(const std::string& file) { return std::string(ZONA_TEST_DATA_DIR) + "/" + file; }

std::string slurp(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  std::ostringstream s;
  s << in.rdbuf();
  return s.str();
}

void spit(const std::string& path, std::string_view text) {
  std::ofstream out(path, std::ios::binary);
  out.write(text.data(), static_cast<std::streamsize>(text.size()));
}

// A fresh folder per test, under the system temp folder.
std::string temp_dir() {
  const auto* info = ::testing::UnitTest::GetInstance()->current_test_info();
  std::string name = std::string("zona_mesh_io_") + info->test_suite_name() + "_" + info->name();
  for (char& ch : name)
    if (!std::isalnum(static_cast<unsigned char>(ch)) && ch != '_') ch = '_';
  const fs::path dir = fs::temp_directory_path() / name;
  fs::remove_all(dir);
  fs::create_directories(dir);
  return dir.string();
}

std::map<int32_t, double> region_volumes(const Mesh& m) {
  std::map<int32_t, double> v;
  for (size_t t = 0; t < m.tet_count(); ++t) v[m.tet_region[t]] += tet_rest_volume(m, t);
  return v;
}

// Same mesh; positions equal to `tolerance` (0: bit for bit).
void expect_same_mesh(const Mesh& a, const Mesh& b, double tolerance = 0) {
  ASSERT_EQ(a.vertex_count(), b.vertex_count());
  ASSERT_EQ(a.tet_count(), b.tet_count());
  for (size_t v = 0; v < a.vertex_count(); ++v)
    for (int k = 0; k < 3; ++k) {
      if (tolerance == 0)
        EXPECT_EQ(a.rest_positions[v][k], b.rest_positions[v][k]) << v;
      else
        EXPECT_NEAR(a.rest_positions[v][k], b.rest_positions[v][k], tolerance) << v;
    }
  EXPECT_EQ(a.tets, b.tets);
  EXPECT_EQ(a.tet_region, b.tet_region);
  ASSERT_EQ(a.regions.size(), b.regions.size());
  for (size_t r = 0; r < a.regions.size(); ++r) {
    EXPECT_EQ(a.regions[r].tag, b.regions[r].tag);
    EXPECT_EQ(a.regions[r].name, b.regions[r].name);
  }
}

// ---- fixtures from the real programs (tests/data/README.md says how they were made) ----

// box2.geo: "left" = [0,1]^3 (tag 11), "right" = [1,3]x[0,1]^2 (tag 12), one free point.
class GmshFixture : public ::testing::TestWithParam<const char*> {};

TEST_P(GmshFixture, LoadsWithCountsRegionsAndVolume) {
  std::vector<std::string> warnings;
  Result<Mesh> m = read_mesh(data_path(GetParam()), {}, &warnings);
  ASSERT_TRUE(m.ok()) << m.error().message;
  // Gmsh wrote 96 nodes; the free point's node belongs to no tetrahedron and is dropped.
  EXPECT_EQ(m->vertex_count(), 95u);
  EXPECT_EQ(m->tet_count(), 244u);
  const auto vol = region_volumes(*m);
  ASSERT_EQ(vol.size(), 2u);
  EXPECT_NEAR(vol.at(11), 1.0, 1e-12);
  EXPECT_NEAR(vol.at(12), 2.0, 1e-12);
  EXPECT_EQ(m->region_name(11), "left");
  EXPECT_EQ(m->region_name(12), "right");
  EXPECT_EQ(m->regions.size(), 2u);  // surface and point names are not volume regions
  bool dropped_warning = false;
  for (const std::string& w : warnings)
    dropped_warning = dropped_warning || w.find("dropped") != std::string::npos;
  EXPECT_TRUE(dropped_warning);
  // The free point at (5, 5, 5) must be gone.
  for (const Vec3d& p : m->rest_positions) EXPECT_LE(p.x, 3.0);
}

TEST_P(GmshFixture, MatchesTheAsciiMsh41Reading) {
  Result<Mesh> a = read_mesh(data_path(GetParam()));
  Result<Mesh> b = read_mesh(data_path("box2_v41_ascii.msh"));
  ASSERT_TRUE(a.ok() && b.ok());
  // Gmsh prints 16 significant digits in ASCII, so ASCII and binary differ in the last bit.
  expect_same_mesh(*a, *b, 1e-14);
}

INSTANTIATE_TEST_SUITE_P(MeshIo, GmshFixture,
                         ::testing::Values("box2_v22_ascii.msh", "box2_v22_bin.msh",
                                           "box2_v41_ascii.msh", "box2_v41_bin.msh"));

TEST(MeshIo, TetgenOneBasedAndZeroBasedAgree) {
  // box2.1.*: 1-based, no point attributes; box2z.1.*: 0-based (-z), one point attribute and
  // boundary markers. Same geometry, regions 1 (left, volume 1) and 2 (right, volume 2).
  Result<Mesh> one = read_mesh(data_path("box2.1.node"));
  Result<Mesh> zero = read_mesh(data_path("box2z.1.ele"));  // naming the .ele works too
  ASSERT_TRUE(one.ok()) << one.error().message;
  ASSERT_TRUE(zero.ok()) << zero.error().message;
  EXPECT_EQ(one->vertex_count(), 146u);
  EXPECT_EQ(one->tet_count(), 420u);
  const auto vol = region_volumes(*one);
  ASSERT_EQ(vol.size(), 2u);
  EXPECT_NEAR(vol.at(1), 1.0, 1e-12);
  EXPECT_NEAR(vol.at(2), 2.0, 1e-12);
  expect_same_mesh(*one, *zero);
}

TEST(MeshIo, ScaleMultipliesCoordinates) {
  ReadMeshOptions um;
  um.scale = 1e-6;
  Result<Mesh> m = read_mesh(data_path("box2_v22_bin.msh"), um);
  ASSERT_TRUE(m.ok()) << m.error().message;
  EXPECT_NEAR(mesh_quality(*m).volume, 3e-18, 1e-30);
  um.scale = -1;
  Result<Mesh> bad = read_mesh(data_path("box2_v22_bin.msh"), um);
  ASSERT_FALSE(bad.ok());
  EXPECT_NE(bad.error().message.find("scale"), std::string::npos);
}

TEST(MeshIo, ReadPositionsOfANodeFileAlone) {
  const std::string dir = temp_dir();
  fs::copy_file(data_path("box2.1.node"), dir + "/deformed.node");
  Result<std::vector<Vec3d>> p = read_positions(dir + "/deformed.node");
  ASSERT_TRUE(p.ok()) << p.error().message;
  Result<Mesh> m = read_mesh(data_path("box2.1.node"));
  ASSERT_TRUE(m.ok());
  ASSERT_EQ(p->size(), m->vertex_count());
  for (size_t i = 0; i < p->size(); ++i) EXPECT_EQ((*p)[i].x, m->rest_positions[i].x);
  // read_mesh needs the .ele and says so.
  Result<Mesh> no_ele = read_mesh(dir + "/deformed.node");
  ASSERT_FALSE(no_ele.ok());
  EXPECT_NE(no_ele.error().message.find(".ele"), std::string::npos);
}

TEST(MeshIo, ReadPositionsNumbersLikeReadMesh) {
  ReadMeshOptions mm;
  mm.scale = 1e-3;
  Result<std::vector<Vec3d>> p = read_positions(data_path("box2_v41_bin.msh"), mm);
  Result<Mesh> m = read_mesh(data_path("box2_v41_bin.msh"), mm);
  ASSERT_TRUE(p.ok() && m.ok());
  ASSERT_EQ(p->size(), 95u);  // the unused node is dropped here too
  for (size_t i = 0; i < p->size(); ++i) EXPECT_EQ((*p)[i].z, m->rest_positions[i].z);
}

// ---- hand-built binary files: foreign byte order and 4-byte size_t ----

class BinaryWriter {
 public:
  explicit BinaryWriter(bool swap) : swap_(swap) {}
  void text(std::string_view s) { out_.append(s); }
  void i32(int32_t v) { put(static_cast<uint32_t>(v)); }
  void u32(uint32_t v) { put(v); }
  void f64(double v) { put(std::bit_cast<uint64_t>(v)); }
  const std::string& str() const { return out_; }

 private:
  template <class U>
  void put(U v) {
    if (swap_) {
      if constexpr (sizeof(U) == 4) v = __builtin_bswap32(v);
      else v = __builtin_bswap64(v);
    }
    out_.append(reinterpret_cast<const char*>(&v), sizeof v);
  }
  bool swap_;
  std::string out_;
};

constexpr double kUnitTet[4][3] = {{0, 0, 0}, {1, 0, 0}, {0, 1, 0}, {0, 0, 1}};

std::string msh22_binary_tet(bool swap) {
  BinaryWriter w(swap);
  w.text("$MeshFormat\n2.2 1 8\n");
  w.i32(1);
  w.text("\n$EndMeshFormat\n$Nodes\n4\n");
  for (int i = 0; i < 4; ++i) {
    w.i32(10 + i);  // non-contiguous tags would also work; these start at 10
    for (double c : kUnitTet[i]) w.f64(c);
  }
  w.text("\n$EndNodes\n$Elements\n1\n");
  w.i32(4);  // type
  w.i32(1);  // elements following
  w.i32(2);  // tags
  w.i32(1);  // element id
  w.i32(42);  // physical
  w.i32(1);   // elementary
  for (int i = 0; i < 4; ++i) w.i32(10 + i);
  w.text("\n$EndElements\n");
  return w.str();
}

std::string msh41_binary_size4_tet(bool swap) {
  BinaryWriter w(swap);
  w.text("$MeshFormat\n4.1 1 4\n");
  w.i32(1);
  w.text("\n$EndMeshFormat\n$Entities\n");
  for (uint32_t n : {0u, 0u, 0u, 1u}) w.u32(n);
  w.i32(5);
  for (double c : {0.0, 0.0, 0.0, 1.0, 1.0, 1.0}) w.f64(c);
  w.u32(1);
  w.i32(7);  // physical tag
  w.u32(0);
  w.text("\n$EndEntities\n$Nodes\n");
  for (uint32_t n : {1u, 4u, 1u, 4u}) w.u32(n);
  w.i32(3);
  w.i32(5);
  w.i32(0);
  w.u32(4);
  for (uint32_t t = 1; t <= 4; ++t) w.u32(t);
  for (const auto& p : kUnitTet)
    for (double c : p) w.f64(c);
  w.text("\n$EndNodes\n$Elements\n");
  for (uint32_t n : {2u, 2u, 1u, 2u}) w.u32(n);
  w.i32(2);  // a triangle block, skipped
  w.i32(1);
  w.i32(2);
  w.u32(1);
  for (uint32_t v : {1u, 1u, 2u, 3u}) w.u32(v);
  w.i32(3);
  w.i32(5);
  w.i32(4);
  w.u32(1);
  for (uint32_t v : {2u, 1u, 2u, 3u, 4u}) w.u32(v);
  w.text("\n$EndElements\n");
  return w.str();
}

TEST(MeshIo, BinaryGmshInEitherByteOrder) {
  for (bool swap : {false, true}) {
    Result<Mesh> a = read_gmsh_from_memory(msh22_binary_tet(swap), "a.msh");
    ASSERT_TRUE(a.ok()) << a.error().message;
    EXPECT_EQ(a->tet_count(), 1u);
    EXPECT_EQ(a->tet_region[0], 42);
    EXPECT_NEAR(tet_rest_volume(*a, 0), 1.0 / 6.0, 1e-15);
    Result<Mesh> b = read_gmsh_from_memory(msh41_binary_size4_tet(swap), "b.msh");
    ASSERT_TRUE(b.ok()) << b.error().message;
    EXPECT_EQ(b->tet_count(), 1u);
    EXPECT_EQ(b->tet_region[0], 7);
    EXPECT_EQ(b->rest_positions[3].z, 1.0);
  }
}

TEST(MeshIo, TetgenTenNodeElementsKeepTheCorners) {
  std::string node = "10 3 0 0\n";
  const double pts[10][3] = {{0, 0, 0},     {1, 0, 0},     {0, 1, 0},     {0, 0, 1},
                             {0.5, 0, 0},   {0.5, 0.5, 0}, {0, 0.5, 0},   {0, 0, 0.5},
                             {0.5, 0, 0.5}, {0, 0.5, 0.5}};
  // Appends one piece at a time: GCC 12 -O2 gives a false -Wrestrict on chained operator+.
  for (int i = 0; i < 10; ++i) {
    node += std::to_string(i);
    for (int c = 0; c < 3; ++c) {
      node += ' ';
      node += std::to_string(pts[i][c]);
    }
    node += '\n';
  }
  const std::string ele = "1 10 1\n0  0 1 2 3 4 5 6 7 8 9  3\n";
  std::vector<std::string> warnings;
  Result<Mesh> m = read_tetgen_from_memory(node, ele, "t.node", "t.ele", {}, &warnings);
  ASSERT_TRUE(m.ok()) << m.error().message;
  EXPECT_EQ(m->vertex_count(), 4u);  // mid-edge nodes are unused once dropped
  EXPECT_EQ(m->tet_region[0], 3);
  EXPECT_NEAR(tet_rest_volume(*m, 0), 1.0 / 6.0, 1e-15);
}

// ---- round trips ----

// Regions interleaved, an unnamed tag and tag 0, so the writer's blocks and entities matter.
Mesh two_cubes() {
  Mesh m;
  // A 3 x 2 x 2 grid with coordinates that have no short decimal form (exact round trip).
  for (int i = 0; i < 12; ++i)
    m.rest_positions.push_back(
        {0.1 * (i % 3) + 1.0 / 7, 0.25 * ((i / 3) % 2), 0.3 * (i / 6) + 1.0 / 3});
  m.tets = {{0, 1, 3, 6}, {1, 2, 4, 7}, {1, 3, 4, 7}, {3, 4, 6, 9},
            {1, 4, 7, 11}, {4, 5, 8, 11}, {0, 3, 9, 10}};
  m.tet_region = {2, 1, 2, 0, 5, 1, 2};
  m.regions = {{1, "cytoplasm"}, {2, "zona \"pellucida\""}};
  for (size_t t = 0; t < m.tet_count(); ++t)
    if (tet_rest_volume(m, t) < 0) std::swap(m.tets[t][2], m.tets[t][3]);
  return m;
}

TEST(MeshIo, TwoCubesIsAValidMesh) {
  Mesh m = two_cubes();
  std::vector<std::string> warnings;
  ASSERT_TRUE(validate_mesh(m, "two_cubes", {}, &warnings).ok());
  EXPECT_TRUE(warnings.empty());  // every vertex used, all positive: the round trip is exact
}

TEST(MeshIo, Gmsh41RoundTripAsciiAndBinary) {
  const std::string dir = temp_dir();
  for (const Mesh& original : {two_cubes(), *read_mesh(data_path("box2_v41_ascii.msh"))}) {
    for (bool binary : {false, true}) {
      const std::string path = dir + (binary ? "/b.msh" : "/a.msh");
      ASSERT_TRUE(write_gmsh41(path, original, binary).ok());
      Result<Mesh> back = read_mesh(path);
      ASSERT_TRUE(back.ok()) << back.error().message;
      Mesh expected = original;
      for (Region& r : expected.regions)  // quotes cannot live inside a quoted Gmsh name
        std::replace(r.name.begin(), r.name.end(), '"', '\'');
      expect_same_mesh(*back, expected);
    }
  }
  Mesh negative = two_cubes();
  negative.tet_region[0] = -3;
  Status s = write_gmsh41(dir + "/n.msh", negative);
  ASSERT_FALSE(s.ok());
  EXPECT_NE(s.error().message.find("-3"), std::string::npos);
}

TEST(MeshIo, WriteMeshDispatchesOnExtension) {
  const std::string dir = temp_dir();
  const Mesh m = two_cubes();
  EXPECT_TRUE(write_mesh(dir + "/m.msh", m).ok());
  EXPECT_TRUE(write_mesh(dir + "/m.vtu", m).ok());
  EXPECT_EQ(slurp(dir + "/m.msh").rfind("$MeshFormat\n4.1 0 8\n", 0), 0u);
  EXPECT_NE(slurp(dir + "/m.vtu").find("UnstructuredGrid"), std::string::npos);
  Status bad = write_mesh(dir + "/m.stl", m);
  ASSERT_FALSE(bad.ok());
  EXPECT_NE(bad.error().message.find("m.stl"), std::string::npos);
}

// ---- VTK ----

// Checks that every element closes in order and returns the attributes of the elements named
// `tag`, in document order. Enough XML for our own output (no CDATA, no comments).
std::vector<std::map<std::string, std::string>> xml_elements(const std::string& xml,
                                                             const std::string& tag,
                                                             bool& well_formed) {
  std::vector<std::map<std::string, std::string>> found;
  std::vector<std::string> open;
  well_formed = true;
  for (size_t at = xml.find('<'); at != std::string::npos; at = xml.find('<', at + 1)) {
    const size_t end = xml.find('>', at);
    if (end == std::string::npos) { well_formed = false; break; }
    const std::string body = xml.substr(at + 1, end - at - 1);
    if (body.empty() || body[0] == '?') continue;
    if (body[0] == '/') {
      if (open.empty() || open.back() != body.substr(1)) well_formed = false;
      if (!open.empty()) open.pop_back();
      continue;
    }
    const std::string name = body.substr(0, body.find_first_of(" /"));
    if (name == tag) {
      // Attributes: name="value" pairs after the element name.
      std::map<std::string, std::string> a;
      for (size_t eq = body.find("=\""); eq != std::string::npos; eq = body.find("=\"", eq + 1)) {
        const size_t name_start = body.rfind(' ', eq) + 1;
        const size_t close = body.find('"', eq + 2);
        if (close == std::string::npos) { well_formed = false; break; }
        a[body.substr(name_start, eq - name_start)] = body.substr(eq + 2, close - eq - 2);
        eq = close;
      }
      found.push_back(a);
    }
    if (body.back() != '/') open.push_back(name);
  }
  well_formed = well_formed && open.empty();
  return found;
}

std::string text_of_array(const std::string& xml, const std::string& name) {
  const size_t at = xml.find("Name=\"" + name + "\"");
  const size_t start = xml.find('>', at) + 1;
  return xml.substr(start, xml.find("</DataArray>", start) - start);
}

std::string base64_decode(const std::string& text) {
  std::string out;
  uint32_t acc = 0;
  int bits = 0;
  for (char ch : text) {
    int v;
    if (ch >= 'A' && ch <= 'Z') v = ch - 'A';
    else if (ch >= 'a' && ch <= 'z') v = ch - 'a' + 26;
    else if (ch >= '0' && ch <= '9') v = ch - '0' + 52;
    else if (ch == '+') v = 62;
    else if (ch == '/') v = 63;
    else continue;  // whitespace and padding
    acc = (acc << 6) | static_cast<uint32_t>(v);
    bits += 6;
    if (bits >= 8) {
      bits -= 8;
      out.push_back(static_cast<char>((acc >> bits) & 0xff));
    }
  }
  return out;
}

TEST(MeshIo, VtuAsciiHasTheRightCountsAndValues) {
  const std::string dir = temp_dir();
  const Mesh m = two_cubes();
  std::vector<double> disp(3 * m.vertex_count()), stress(6 * m.tet_count());
  for (size_t i = 0; i < disp.size(); ++i) disp[i] = 0.5 * static_cast<double>(i);
  for (size_t i = 0; i < stress.size(); ++i) stress[i] = -1.0 * static_cast<double>(i);
  VtuOptions ascii;
  ascii.binary = false;
  ASSERT_TRUE(write_vtu(dir + "/a.vtu", m, {{"displacement", 3, disp}},
                        {{"stress <Pa>", 6, stress}}, ascii).ok());
  const std::string xml = slurp(dir + "/a.vtu");
  bool ok = false;
  const auto pieces = xml_elements(xml, "Piece", ok);
  EXPECT_TRUE(ok);
  ASSERT_EQ(pieces.size(), 1u);
  EXPECT_EQ(pieces[0].at("NumberOfPoints"), "12");
  EXPECT_EQ(pieces[0].at("NumberOfCells"), "7");
  const auto arrays = xml_elements(xml, "DataArray", ok);
  std::map<std::string, std::string> components;
  for (const auto& a : arrays)
    components[a.count("Name") ? a.at("Name") : ""] =
        a.count("NumberOfComponents") ? a.at("NumberOfComponents") : "1";
  EXPECT_EQ(components.at("displacement"), "3");
  EXPECT_EQ(components.at("stress &lt;Pa&gt;"), "6");  // names are escaped
  EXPECT_EQ(components.at("region"), "1");
  std::istringstream conn(text_of_array(xml, "connectivity"));
  std::vector<int> ids{std::istream_iterator<int>(conn), std::istream_iterator<int>()};
  ASSERT_EQ(ids.size(), 28u);
  for (size_t t = 0; t < m.tet_count(); ++t)
    for (int k = 0; k < 4; ++k) EXPECT_EQ(ids[4 * t + k], m.tets[t][k]);
  std::istringstream reg(text_of_array(xml, "region"));
  std::vector<int> regions{std::istream_iterator<int>(reg), std::istream_iterator<int>()};
  EXPECT_EQ(regions, std::vector<int>(m.tet_region.begin(), m.tet_region.end()));
}

TEST(MeshIo, VtuBinaryDecodesToTheData) {
  const std::string dir = temp_dir();
  const Mesh m = two_cubes();
  std::vector<Vec3d> moved = m.rest_positions;
  for (Vec3d& p : moved) p.z += 1.0;
  VtuOptions options;
  options.positions = &moved;
  ASSERT_TRUE(write_vtu(dir + "/b.vtu", m, {}, {}, options).ok());
  const std::string xml = slurp(dir + "/b.vtu");
  bool ok = false;
  xml_elements(xml, "DataArray", ok);
  EXPECT_TRUE(ok);
  const std::string raw = base64_decode(text_of_array(xml, "Points"));
  ASSERT_EQ(raw.size(), 8 + 3 * 8 * m.vertex_count());
  uint64_t bytes = 0;
  std::memcpy(&bytes, raw.data(), 8);
  EXPECT_EQ(bytes, 3 * 8 * m.vertex_count());
  for (size_t v = 0; v < m.vertex_count(); ++v) {
    double z = 0;
    std::memcpy(&z, raw.data() + 8 + (3 * v + 2) * 8, 8);
    EXPECT_EQ(z, moved[v].z);
  }
  const std::string types = base64_decode(text_of_array(xml, "types"));
  ASSERT_EQ(types.size(), 8 + m.tet_count());
  for (size_t t = 0; t < m.tet_count(); ++t) EXPECT_EQ(types[8 + t], 10);  // VTK_TETRA
  // Wrong sizes are refused, not written.
  std::vector<double> short_field(5, 0.0);
  Status bad = write_vtu(dir + "/c.vtu", m, {{"u", 3, short_field}}, {});
  ASSERT_FALSE(bad.ok());
  EXPECT_NE(bad.error().message.find("'u'"), std::string::npos);
  EXPECT_FALSE(write_vtu(dir + "/c.vtu", m, {{"u", 2, std::vector<double>(24)}}, {}).ok());
}

TEST(MeshIo, PvdListsTheFramesInOrder) {
  const std::string dir = temp_dir();
  const Mesh m = two_cubes();
  PvdWriter pvd(dir + "/run.pvd");
  ASSERT_TRUE(pvd.write_frame(0.0, m).ok());
  ASSERT_TRUE(pvd.write_frame(2.5e-3, m).ok());
  ASSERT_TRUE(write_vtu(dir + "/extra.vtu", m).ok());
  ASSERT_TRUE(pvd.add_frame(5e-3, dir + "/extra.vtu").ok());
  EXPECT_FALSE(pvd.write_frame(std::nan(""), m).ok());
  EXPECT_EQ(pvd.frame_count(), 3u);
  const std::string xml = slurp(dir + "/run.pvd");
  bool ok = false;
  const auto sets = xml_elements(xml, "DataSet", ok);
  EXPECT_TRUE(ok);
  ASSERT_EQ(sets.size(), 3u);
  EXPECT_EQ(sets[0].at("file"), "run_000000.vtu");
  EXPECT_EQ(sets[1].at("file"), "run_000001.vtu");
  EXPECT_EQ(sets[2].at("file"), "extra.vtu");
  EXPECT_EQ(std::stod(sets[1].at("timestep")), 2.5e-3);
  for (const auto& s : sets) EXPECT_TRUE(fs::exists(dir + "/" + s.at("file")));
}

// ---- malformed input ----

// A valid MSH 2.2 file (one point element, skipped, and one tetrahedron); cases edit it.
constexpr const char* kMsh22 =
    "$MeshFormat\n"         // 1
    "2.2 0 8\n"             // 2
    "$EndMeshFormat\n"      // 3
    "$Nodes\n"              // 4
    "4\n"                   // 5
    "1 0 0 0\n"             // 6
    "2 1 0 0\n"             // 7
    "3 0 1 0\n"             // 8
    "4 0 0 1\n"             // 9
    "$EndNodes\n"           // 10
    "$Elements\n"           // 11
    "2\n"                   // 12
    "1 15 2 0 1 1\n"        // 13
    "2 4 2 7 1 1 2 3 4\n"   // 14
    "$EndElements\n";       // 15

// A valid MSH 4.1 file: a surface entity with a parametric node, a volume entity with
// physical tag 7 named "cell", a triangle block and a tetrahedron block.
constexpr const char* kMsh41 =
    "$MeshFormat\n"             // 1
    "4.1 0 8\n"                 // 2
    "$EndMeshFormat\n"          // 3
    "$PhysicalNames\n"          // 4
    "1\n"                       // 5
    "3 7 \"cell\"\n"            // 6
    "$EndPhysicalNames\n"       // 7
    "$Entities\n"               // 8
    "0 0 1 1\n"                 // 9
    "3 0 0 0 1 1 0 0 0\n"       // 10
    "5 0 0 0 1 1 1 1 7 0\n"     // 11
    "$EndEntities\n"            // 12
    "$Nodes\n"                  // 13
    "2 4 1 4\n"                 // 14
    "2 3 1 1\n"                 // 15
    "1\n"                       // 16
    "0 0 0 0.5 0.5\n"           // 17
    "3 5 0 3\n"                 // 18
    "2\n"                       // 19
    "3\n"                       // 20
    "4\n"                       // 21
    "1 0 0\n"                   // 22
    "0 1 0\n"                   // 23
    "0 0 1\n"                   // 24
    "$EndNodes\n"               // 25
    "$Elements\n"               // 26
    "2 2 1 2\n"                 // 27
    "2 3 2 1\n"                 // 28
    "1 1 2 3\n"                 // 29
    "3 5 4 1\n"                 // 30
    "2 1 2 3 4\n"               // 31
    "$EndElements\n";           // 32

std::string edit(std::string text, const std::string& from, const std::string& to) {
  const size_t at = text.find(from);
  EXPECT_NE(at, std::string::npos) << from;
  if (at != std::string::npos) text.replace(at, from.size(), to);
  return text;
}

struct BadFile {
  const char* label;
  std::string text;
  int line;          // expected "<path>:<line>:"; 0: a byte offset; -1: no location (mesh check)
  const char* what;  // expected in the message
};

void expect_refused(const std::string& path, const Result<Mesh>& m, int line, const char* what,
                    const char* label) {
  ASSERT_FALSE(m.ok()) << label;
  const std::string& msg = m.error().message;
  EXPECT_EQ(msg.find('\n'), std::string::npos) << label << ": " << msg;
  const std::string where = line > 0    ? path + ":" + std::to_string(line) + ": "
                            : line == 0 ? path + ":byte "
                                        : path + ": ";
  EXPECT_EQ(msg.rfind(where, 0), 0u) << label << ": expected '" << where << "' in: " << msg;
  EXPECT_NE(msg.find(what), std::string::npos) << label << ": expected '" << what << "' in: " << msg;
}

TEST(MeshIo, MalformedGmshIsRefusedWithFileAndLine) {
  ASSERT_TRUE(read_gmsh_from_memory(kMsh22, "ok.msh").ok());
  ASSERT_TRUE(read_gmsh_from_memory(kMsh41, "ok.msh").ok());
  const std::string v22 = kMsh22, v41 = kMsh41;
  const std::string bin22 = msh22_binary_tet(false);
  const std::string bin41 = slurp(data_path("box2_v41_bin.msh"));
  std::string bad_marker = bin22;
  bad_marker[bin22.find("8\n") + 2] = 2;  // first byte of the marker: 1 -> 2
  const std::vector<BadFile> cases = {
      {"empty", "", 1, "unexpected end of file"},
      {"not gmsh", "solid cube\nfacet normal 0 0 1\n", 1, "not a Gmsh file"},
      {"version 1", "$NOD\n4\n", 1, "not a Gmsh file"},
      {"version 3.0", edit(v22, "2.2 0 8", "3.0 0 8"), 2, "unsupported MSH version '3.0'"},
      {"version 4.0", edit(v22, "2.2 0 8", "4 0 8"), 2, "unsupported MSH version"},
      {"file type", edit(v22, "2.2 0 8", "2.2 2 8"), 2, "file type"},
      {"too many nodes declared", edit(v22, "$Nodes\n4\n", "$Nodes\n5\n"), 10,
       "expected node tag, got '$EndNodes'"},
      {"too few nodes declared", edit(v22, "$Nodes\n4\n", "$Nodes\n3\n"), 9,
       "expected $EndNodes, got '4'"},
      {"non-numeric", edit(v22, "3 0 1 0", "3 0 abc 0"), 8, "expected node y, got 'abc'"},
      {"nan", edit(v22, "3 0 1 0", "3 0 nan 0"), 8, "node y is not finite"},
      {"overflow", edit(v22, "3 0 1 0", "3 0 1e999 0"), 8, "expected node y"},
      {"node out of range", edit(v22, "1 1 2 3 4", "1 1 2 3 9"), 14, "uses node 9"},
      {"huge count", edit(v22, "$Nodes\n4\n", "$Nodes\n99999999999\n"), 5, "out of range"},
      {"count beyond file", edit(v22, "$Nodes\n4\n", "$Nodes\n2000000000\n"), 5,
       "cannot fit"},
      {"negative count", edit(v22, "$Nodes\n4\n", "$Nodes\n-4\n"), 5, "node count -4"},
      {"huge element count", edit(v22, "$Elements\n2\n", "$Elements\n9000000000000000000\n"),
       12, "cannot fit"},
      {"duplicate node", edit(v22, "3 0 1 0", "2 0 1 0"), 8, "node tag 2 appears twice"},
      {"truncated", v22.substr(0, v22.find("1 15")), 12, "element count 2 cannot fit"},
      {"truncated in a line", v22.substr(0, v22.find("2 4 2 7 1 1 2 3") + 15), 14,
       "unexpected end of file; expected element node"},
      {"no end of section", v22.substr(0, v22.rfind("$EndElements")), 15,
       "expected $EndElements"},
      {"extra fields", edit(v22, "1 1 2 3 4", "1 1 2 3 4 5"), 14, "extra fields"},
      {"unclosed section", edit(v22, "$Nodes\n", "$Comments\nhello\n$Nodes\n"), 4,
       "no $EndComments"},
      {"stray end", edit(v22, "$Nodes\n", "$EndFoo\n$Nodes\n"), 4, "without its opening"},
      {"elements first",
       v22.substr(0, v22.find("$Nodes")) + v22.substr(v22.find("$Elements")), 4,
       "$Elements before $Nodes"},
      {"no nodes", v22.substr(0, v22.find("$Nodes")), 3, "no $Nodes"},
      {"element tag count", edit(v22, "2 4 2 7", "2 4 99999 7"), 14, "element tag count"},
      {"no tetrahedra", edit(edit(v22, "2 4 2 7 1 1 2 3 4", "2 15 2 0 1 1"), "", ""), -1,
       "no tetrahedra"},
      {"flat tetrahedron", edit(v22, "4 0 0 1", "4 1 1 0"), -1, "zero volume"},
      {"repeated vertex", edit(v22, "1 1 2 3 4", "1 1 2 3 3"), -1, "repeats vertex"},
      {"41 node blocks too big", edit(v41, "3 5 0 3", "3 5 0 9"), 18,
       "more than the 4 nodes declared"},
      {"41 node total", edit(v41, "2 4 1 4", "2 5 1 4"), 24, "header declares 5"},
      {"41 entity dimension", edit(v41, "3 5 0 3", "7 5 0 3"), 18, "entity dimension 7"},
      {"41 parametric flag", edit(v41, "3 5 0 3", "3 5 2 3"), 18, "parametric flag 2"},
      {"41 element node", edit(v41, "2 1 2 3 4", "2 1 2 3 9"), 31, "uses node 9"},
      {"41 element total", edit(v41, "2 2 1 2\n", "2 3 1 2\n"), 31, "header declares 3"},
      {"41 physical name", edit(v41, "3 7 \"cell\"", "3 7 cell"), 6, "double quotes"},
      {"41 entity count", edit(v41, "0 0 1 1\n", "0 0 1 99999999\n"), 9, "cannot fit"},
      {"41 negative block", edit(v41, "3 5 4 1", "3 5 4 -1"), 30, "out of range"},
      {"binary truncated", bin41.substr(0, bin41.size() - 15), 0,
       "block element count 144 cannot fit"},
      {"binary end cut", bin41.substr(0, bin41.size() - 5), 0, "expected $EndElements"},
      {"binary marker cut", bin22.substr(0, bin22.find("2.2 1 8\n") + 10), 0,
       "unexpected end of file reading endianness marker"},
      {"binary count beyond file", bin41.substr(0, bin41.size() / 2), 0, "cannot fit"},
      {"binary 22 truncated", bin22.substr(0, bin22.size() - 30), 0, "cannot fit"},
      {"bad endianness marker", bad_marker, 0, "endianness marker"},
      {"binary data size", edit(bin41, "4.1 1 8", "4.1 1 16"), 2, "data size 16"},
  };
  const std::string dir = temp_dir();
  for (size_t i = 0; i < cases.size(); ++i) {
    const std::string path = dir + "/case" + std::to_string(i) + ".msh";
    spit(path, cases[i].text);
    expect_refused(path, read_mesh(path), cases[i].line, cases[i].what, cases[i].label);
  }
}

TEST(MeshIo, MalformedTetgenIsRefusedWithFileAndLine) {
  const std::string node =
      "# four points\n"     // 1
      "4 3 0 0\n"           // 2
      "1 0 0 0\n"           // 3
      "2 1 0 0  # x\n"      // 4
      "\n"                  // 5
      "3 0 1 0\n"           // 6
      "4 0 0 1\n";          // 7
  const std::string ele = "1 4 1\n1 1 2 3 4 5\n";
  // Counts are first checked against the bytes left; a comment makes room so that the
  // record-by-record end-of-file check is reached too.
  const char* kPadding = "# a comment long enough to pass the count check\n";
  const std::string dir = temp_dir();
  {
    spit(dir + "/ok.node", node);
    spit(dir + "/ok.ele", ele);
    Result<Mesh> ok = read_mesh(dir + "/ok.node");
    ASSERT_TRUE(ok.ok()) << ok.error().message;
    EXPECT_EQ(ok->tet_region[0], 5);
  }
  struct TetgenCase {
    const char* label;
    std::string node, ele;
    bool in_ele;  // the error is in the .ele (else the .node)
    int line;
    const char* what;
  };
  const std::vector<TetgenCase> cases = {
      {"empty node", "", ele, false, 1, "empty .node"},
      {"dimension", edit(node, "4 3 0 0", "4 2 0 0"), ele, false, 2, "dimension 2"},
      {"header fields", edit(node, "4 3 0 0", "4 3 0 0 0"), ele, false, 2, "at most 4"},
      {"first index", edit(node, "1 0 0 0", "2 0 0 0"), ele, false, 3, "first point index 2"},
      {"sequence", edit(node, "3 0 1 0", "5 0 1 0"), ele, false, 6, "out of sequence"},
      {"few fields", edit(node, "4 0 0 1", "4 0 0"), ele, false, 7, "has 3 fields"},
      {"extra attribute", edit(node, "3 0 1 0", "3 0 1 0 7"), ele, false, 6,
       "has 5 fields; expected 4"},
      {"non-numeric", edit(node, "2 1 0 0", "2 1 x 0"), ele, false, 4, "expected point y, got 'x'"},
      {"nan", edit(node, "2 1 0 0", "2 nan 0 0"), ele, false, 4, "point x is not finite"},
      {"truncated node", node.substr(0, node.find("4 0 0 1")) + kPadding, ele, false, 8,
       "3 of the 4 points"},
      {"node count beyond file", node.substr(0, node.find("4 0 0 1")), ele, false, 2,
       "point count 4 cannot fit"},
      {"extra point", edit(node, "4 3 0 0", "3 3 0 0"), ele, false, 7, "more point lines"},
      {"huge count", edit(node, "4 3 0 0", "999999999 3 0 0"), ele, false, 2, "cannot fit"},
      {"negative count", edit(node, "4 3 0 0", "-4 3 0 0"), ele, false, 2, "point count -4"},
      {"huge attributes", edit(node, "4 3 0 0", "4 3 99999999999 0"), ele, false, 2,
       "attribute count"},
      {"empty ele", node, "# nothing\n", true, 2, "empty .ele"},
      {"node index", node, "1 4 1\n1 1 2 3 5 5\n", true, 2, "node index 5 out of range [1, 4]"},
      {"zero index in 1-based", node, "1 4 1\n1 0 1 2 3 5\n", true, 2, "node index 0"},
      {"region not integer", node, "1 4 1\n1 1 2 3 4 1.5\n", true, 2, "region attribute '1.5'"},
      {"region nan", node, "1 4 1\n1 1 2 3 4 nan\n", true, 2, "tetrahedron attribute"},
      {"truncated ele", node, std::string("2 4 1\n1 1 2 3 4 5\n") + kPadding, true, 4,
       "1 of the 2 tetrahedra"},
      {"nodes per tet", node, "1 5 1\n1 1 2 3 4 5 5\n", true, 1, "must be 4 or 10"},
      {"ele fields", node, "1 4 0\n1 1 2 3 4 5\n", true, 2, "has 6 fields; expected 5"},
      {"extra tetrahedron", node, "1 4 1\n1 1 2 3 4 5\n2 1 2 3 4 5\n", true, 3,
       "more tetrahedron lines"},
      {"flat", edit(node, "4 0 0 1", "4 1 1 0"), ele, false, -1, "zero volume"},
  };
  for (size_t i = 0; i < cases.size(); ++i) {
    const std::string stem = dir + "/case" + std::to_string(i);
    spit(stem + ".node", cases[i].node);
    spit(stem + ".ele", cases[i].ele);
    expect_refused(stem + (cases[i].in_ele ? ".ele" : ".node"), read_mesh(stem + ".node"),
                   cases[i].line, cases[i].what, cases[i].label);
  }
}

TEST(MeshIo, MissingAndUnknownFiles) {
  const std::string dir = temp_dir();
  Result<Mesh> missing = read_mesh(dir + "/nothing.msh");
  ASSERT_FALSE(missing.ok());
  EXPECT_NE(missing.error().message.find("nothing.msh"), std::string::npos);
  spit(dir + "/x.stl", "solid\n");
  EXPECT_FALSE(read_mesh(dir + "/x.stl").ok());
  fs::create_directories(dir + "/d.msh");
  Result<Mesh> directory = read_mesh(dir + "/d.msh");
  ASSERT_FALSE(directory.ok());
  EXPECT_NE(directory.error().message.find("directory"), std::string::npos);
}

// A path that exists but is not a regular file is named as such, before it is opened: a FIFO
// would block the open (this test would hang), a device would be read forever.
TEST(MeshIo, PathsThatAreNotRegularFiles) {
  const std::string dir = temp_dir();
  ASSERT_EQ(::mkfifo((dir + "/pipe.msh").c_str(), 0600), 0);
  Result<Mesh> fifo = read_mesh(dir + "/pipe.msh");
  ASSERT_FALSE(fifo.ok());
  EXPECT_EQ(fifo.error().message, dir + "/pipe.msh: is not a regular file (FIFO)");
  fs::create_directories(dir + "/d.node");
  Result<std::vector<Vec3d>> directory = read_positions(dir + "/d.node");
  ASSERT_FALSE(directory.ok());
  EXPECT_EQ(directory.error().message, dir + "/d.node: is not a regular file (directory)");
  // A .node whose .ele beside it is a FIFO.
  spit(dir + "/t.node", "1 3 0 0\n1 0 0 0\n");
  ASSERT_EQ(::mkfifo((dir + "/t.ele").c_str(), 0600), 0);
  Result<Mesh> ele = read_mesh(dir + "/t.node");
  ASSERT_FALSE(ele.ok());
  EXPECT_EQ(ele.error().message, dir + "/t.ele: is not a regular file (FIFO)");
  fs::remove_all(dir);
}

// Every prefix of the real files (sampled) is refused or read, never a crash or a hang; run
// under the sanitizer build this also checks for out-of-bounds reads.
TEST(MeshIo, EveryTruncationIsHandled) {
  for (const char* file : {"box2_v22_ascii.msh", "box2_v22_bin.msh", "box2_v41_ascii.msh",
                           "box2_v41_bin.msh"}) {
    const std::string data = slurp(data_path(file));
    int refused = 0;
    for (size_t n = 0; n < data.size(); n += 151) {
      const Result<Mesh> m = read_gmsh_from_memory(std::string_view(data).substr(0, n), file);
      if (!m.ok()) {
        ++refused;
        EXPECT_EQ(m.error().message.rfind(std::string(file) + ":", 0), 0u) << m.error().message;
      }
    }
    EXPECT_GT(refused, 0);
  }
  const std::string node = slurp(data_path("box2z.1.node"));
  const std::string ele = slurp(data_path("box2z.1.ele"));
  const size_t last_line = ele.rfind("\n  419 ");  // cuts before it lose tetrahedra
  ASSERT_NE(last_line, std::string::npos);
  for (size_t n = 0; n < last_line; n += 97) {
    const Result<Mesh> m = read_tetgen_from_memory(node, ele.substr(0, n), "b.node", "b.ele");
    EXPECT_FALSE(m.ok());
  }
}

}  // namespace
}  // namespace zona
