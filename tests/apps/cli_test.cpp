// End-to-end tests of the `zona` command line: exit codes, one-line errors, JSON outputs.
#include <gtest/gtest.h>

#include <array>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <string>
#include <utility>
#include <vector>

#include <nlohmann/json.hpp>

#include "tests/apps/cli_runner.h"

namespace {

using zona::test::CliRun;
using zona::test::run_zona;

// Runs the zona binary with `args`; stdout and stderr are captured through temp files.

std::string data(const std::string& name) { return std::string(ZONA_TEST_DATA_DIR) + "/" + name; }

int count_lines(const std::string& s) {
  int n = 0;
  for (char c : s) n += c == '\n';
  return n;
}

TEST(Cli, MeshInfoJsonHasTheRequiredKeys) {
  const CliRun r = run_zona("mesh info --json " + data("box2_v41_ascii.msh"));
  ASSERT_EQ(r.exit_code, 0) << r.err;
  const nlohmann::json j = nlohmann::json::parse(r.out);
  for (const char* key : {"vertices", "tets", "boundary_triangles", "volume_m3",
                          "min_dihedral_deg", "max_dihedral_deg", "regions"})
    EXPECT_TRUE(j.contains(key)) << key;
  EXPECT_GT(j["tets"].get<int>(), 0);
  EXPECT_GT(j["min_dihedral_deg"].get<double>(), 0.0);
  EXPECT_LT(j["max_dihedral_deg"].get<double>(), 180.0);
  EXPECT_GE(j["regions"].size(), 2u);  // the fixture has two physical volumes
}

TEST(Cli, MissingFileIsOneLineErrorNamingIt) {
  const CliRun r = run_zona("mesh info /nonexistent/cell.msh");
  EXPECT_NE(r.exit_code, 0);
  EXPECT_EQ(count_lines(r.err), 1) << r.err;
  EXPECT_NE(r.err.find("/nonexistent/cell.msh"), std::string::npos) << r.err;
  EXPECT_TRUE(r.out.empty());
}

TEST(Cli, BrokenFileIsOneLineErrorWithLine) {
  const std::string path =
      (std::filesystem::temp_directory_path() / "zona_cli_broken.msh").string();
  {
    std::ofstream f(path);
    f << "$MeshFormat\n4.1 0 8\n$EndMeshFormat\n$Nodes\n1 2 1 x\n";
  }
  const CliRun r = run_zona("mesh info " + path);
  std::filesystem::remove(path);
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_EQ(count_lines(r.err), 1) << r.err;
  EXPECT_NE(r.err.find("zona_cli_broken.msh:5"), std::string::npos) << r.err;
}

TEST(Cli, GenerateThenInfoRoundTrip) {
  const std::string path =
      (std::filesystem::temp_directory_path() / "zona_cli_gen.msh").string();
  const CliRun g = run_zona("mesh generate --diameter 56um --vertices 2000 --json --out " + path);
  ASSERT_EQ(g.exit_code, 0) << g.err;
  const nlohmann::json jg = nlohmann::json::parse(g.out);
  const CliRun i = run_zona("mesh info --json " + path);
  std::filesystem::remove(path);
  ASSERT_EQ(i.exit_code, 0) << i.err;
  const nlohmann::json ji = nlohmann::json::parse(i.out);
  EXPECT_EQ(jg["vertices"], ji["vertices"]);
  EXPECT_EQ(jg["tets"], ji["tets"]);
  EXPECT_NEAR(ji["vertices"].get<double>(), 2000.0, 200.0);
  // A 56 um ball: 4/3 pi (28 um)^3 = 9.195e-14 m^3, within 3 %.
  EXPECT_NEAR(ji["volume_m3"].get<double>(), 9.1952e-14, 0.03 * 9.1952e-14);
  EXPECT_GE(ji["min_dihedral_deg"].get<double>(), 10.0);
}

// zona reads the .vtu it writes: info of the converted mesh equals info of the original, and
// converting back to Gmsh keeps it.
TEST(Cli, MeshInfoAndConvertReadVtu) {
  const std::filesystem::path dir = std::filesystem::temp_directory_path() / "zona_cli_vtu";
  std::filesystem::create_directories(dir);
  const std::string vtu = (dir / "box2.vtu").string(), msh = (dir / "back.msh").string();
  ASSERT_EQ(run_zona("mesh convert " + data("box2_v41_ascii.msh") + " " + vtu).exit_code, 0);
  const CliRun convert = run_zona("mesh convert " + vtu + " " + msh);
  ASSERT_EQ(convert.exit_code, 0) << convert.err;
  const CliRun original = run_zona("mesh info --json " + data("box2_v41_ascii.msh"));
  ASSERT_EQ(original.exit_code, 0) << original.err;
  const nlohmann::json jo = nlohmann::json::parse(original.out);
  for (const std::string& path : {vtu, msh}) {
    const CliRun r = run_zona("mesh info --json " + path);
    ASSERT_EQ(r.exit_code, 0) << r.err;
    const nlohmann::json j = nlohmann::json::parse(r.out);
    for (const char* key : {"vertices", "tets", "boundary_triangles", "regions"})
      EXPECT_EQ(j[key], jo[key]) << path << " " << key;
    EXPECT_NEAR(j["volume_m3"].get<double>(), jo["volume_m3"].get<double>(),
                1e-12 * jo["volume_m3"].get<double>());
  }
  // A VTU zona does not read: one line naming the file and what is unsupported.
  std::ofstream(dir / "zipped.vtu")
      << "<VTKFile type=\"UnstructuredGrid\" compressor=\"vtkZLibDataCompressor\">\n";
  const CliRun bad = run_zona("mesh info " + (dir / "zipped.vtu").string());
  std::filesystem::remove_all(dir);
  EXPECT_EQ(bad.exit_code, 1);
  EXPECT_EQ(count_lines(bad.err), 1) << bad.err;
  EXPECT_NE(bad.err.find("zipped.vtu:1: compressed data"), std::string::npos) << bad.err;
}

TEST(Cli, GenerateRejectsBadUnit) {
  const CliRun r = run_zona("mesh generate --diameter 56kPa --vertices 100 --out /tmp/x.msh");
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_EQ(count_lines(r.err), 1) << r.err;
  EXPECT_NE(r.err.find("--diameter"), std::string::npos) << r.err;
}

TEST(Cli, InfoJsonListsBackends) {
  const CliRun r = run_zona("info --json");
  ASSERT_EQ(r.exit_code, 0) << r.err;
  const nlohmann::json j = nlohmann::json::parse(r.out);
  ASSERT_TRUE(j["backends_compiled"].is_array());
  EXPECT_EQ(j["backends_compiled"][0], "cpu");
  EXPECT_TRUE(j["devices"].is_array());
}

TEST(Cli, EveryCommandHasHelp) {
  for (const char* cmd : {"", "info", "mesh", "mesh info", "mesh generate", "mesh convert"}) {
    const CliRun r = run_zona(std::string(cmd) + " --help");
    EXPECT_EQ(r.exit_code, 0) << cmd;
    EXPECT_NE(r.out.find("Usage"), std::string::npos) << cmd << ": " << r.out;
  }
}

}  // namespace

TEST(Cli, ZonaAlonePrintsUsageAndExits2) {
  const CliRun r = run_zona("");
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_NE(r.err.find("Usage:"), std::string::npos) << r.err;
  for (const char* command : {"run", "mesh", "study", "haptics"})
    EXPECT_NE(r.err.find(command), std::string::npos) << command;
}

TEST(Cli, GroupsWithoutASubcommandListTheirSubcommands) {
  const std::pair<const char*, std::vector<const char*>> groups[] = {
      {"mesh", {"info", "generate", "convert"}},
      {"analytic", {"maxwell", "membrane", "modulus"}},
      {"study", {"convergence"}}};
  for (const auto& [group, subcommands] : groups) {
    const CliRun r = run_zona(group);
    EXPECT_EQ(r.exit_code, 2) << group;
    EXPECT_NE(r.err.find(std::string("'zona ") + group + "' needs a subcommand"), std::string::npos)
        << r.err;
    for (const char* s : subcommands)
      EXPECT_NE(r.err.find(std::string("zona ") + group + " " + s), std::string::npos) << r.err;
  }
}

TEST(Cli, MeshInfoPrintsBoundingBoxAndCentre) {
  // The fixture's two boxes span [0,3] x [0,1] x [0,1] file units; read in um.
  const CliRun r = run_zona("mesh info --unit um " + data("box2_v41_ascii.msh"));
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_NE(r.out.find("bounding box        0 .. 3e-06, 0 .. 1e-06, 0 .. 1e-06 m"), std::string::npos)
      << r.out;
  EXPECT_NE(r.out.find("centre              1.5e-06, 5e-07, 5e-07 m"), std::string::npos) << r.out;
  EXPECT_EQ(r.err.find("not a cell's size"), std::string::npos) << r.err;  // cell-sized: no unit warning
  const CliRun j = run_zona("mesh info --json --unit um " + data("box2_v41_ascii.msh"));
  const nlohmann::json js = nlohmann::json::parse(j.out);
  EXPECT_NEAR(js["centre_m"][0].get<double>(), 1.5e-6, 1e-12);
  EXPECT_NEAR(js["size_m"][0].get<double>(), 3e-6, 1e-12);
}

TEST(Cli, MeshInfoWarnsWhenTheSizeLooksLikeTheWrongUnit) {
  // Micrometre coordinates read as metres: a 3 m "cell".
  CliRun r = run_zona("mesh info --unit m " + data("box2_v41_ascii.msh"));
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_NE(r.err.find("warning: "), std::string::npos) << r.err;
  EXPECT_NE(r.err.find("read with --unit m: the mesh is 3 m across"), std::string::npos) << r.err;
  EXPECT_NE(r.err.find("micrometres"), std::string::npos) << r.err;
  // Metre coordinates (a generated 56 um cell) read as micrometres.
  const std::string path = (std::filesystem::temp_directory_path() / "zona_cli_unit.msh").string();
  ASSERT_EQ(run_zona("mesh generate --diameter 56um --vertices 300 --out " + path).exit_code, 0);
  r = run_zona("mesh info --unit um " + path);
  std::filesystem::remove(path);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_NE(r.err.find("not a cell's size"), std::string::npos) << r.err;
}
