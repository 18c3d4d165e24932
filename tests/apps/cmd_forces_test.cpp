// `zona forces`: the CLI's CSV equals the in-process forces; bad inputs fail with one line.
#include <gtest/gtest.h>

#include "tests/apps/cli_runner.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>
#include <vector>

#include "engine/fem/forces_cpu.h"
#include "engine/fem/model.h"
#include "engine/fem/state.h"
#include "engine/mesh/mesh_io.h"
#include "tests/engine/physics_test_meshes.h"

namespace zona {
namespace {

namespace fs = std::filesystem;

// Writes a TetGen mesh (.node/.ele, 0-based) with the given positions.
void write_tetgen(const fs::path& stem, const std::vector<Vec3d>& x, const std::vector<Tet>& tets) {
  std::ofstream node(stem.string() + ".node");
  node.precision(17);
  node << x.size() << " 3 0 0\n";
  for (size_t v = 0; v < x.size(); ++v) node << v << ' ' << x[v].x << ' ' << x[v].y << ' ' << x[v].z << '\n';
  if (tets.empty()) return;
  std::ofstream ele(stem.string() + ".ele");
  ele << tets.size() << " 4 0\n";
  for (size_t t = 0; t < tets.size(); ++t)
    ele << t << ' ' << tets[t][0] << ' ' << tets[t][1] << ' ' << tets[t][2] << ' ' << tets[t][3] << '\n';
}

int run(const std::string& args, std::string* err) {
  const fs::path log = fs::temp_directory_path() / "zona_forces_test_stderr.txt";
  const std::string cmd = std::string(ZONA_CLI_PATH) + " forces " + args + " 2> " + log.string();
  const int rc = std::system(cmd.c_str());
  std::ifstream in(log);
  std::stringstream ss;
  ss << in.rdbuf();
  *err = ss.str();
  return rc;
}

TEST(CmdForces, CsvMatchesTheEngine) {
  for (const char* law : {"svk", "neohookean"}) {
    SCOPED_TRACE(law);
    const fs::path dir = fs::temp_directory_path() / "zona_cmd_forces_test";
    fs::create_directories(dir);
    const Mesh mesh = testing::box_mesh({0, 0, 0}, {2, 1, 1}, 2, 1, 1);  // file units: um
    std::vector<Vec3d> deformed = mesh.rest_positions;
    for (Vec3d& x : deformed) x = Vec3d{1.2 * x.x + 0.1 * x.z, 0.95 * x.y, x.z + 0.05 * x.x * x.y};
    write_tetgen(dir / "rest", mesh.rest_positions, mesh.tets);
    write_tetgen(dir / "moved", deformed, {});  // a bare .node
    std::string err;
    const fs::path csv = dir / "f.csv";
    ASSERT_EQ(
        run((dir / "rest.node").string() + " " + (dir / "moved.node").string() + " --model " + law +
                " --young 2000 --poisson 0.4 --scale 1e-6 --backend cpu --out " + csv.string(),
            &err),
        0)
        << err;
    // The same forces in process.
    Mesh scaled = mesh;
    for (Vec3d& x : scaled.rest_positions) x = 1e-6 * x;
    ModelDesc d;
    d.material.young = 2000;
    d.material.poisson = 0.4;
    d.constitutive =
        std::string(law) == "svk" ? ConstitutiveModel::kSvk : ConstitutiveModel::kStableNeoHookean;
    const Model m = build_model(scaled, d).value();
    State s = make_state(m, 1);
    for (size_t v = 0; v < s.u.size(); ++v) s.u[v] = 1e-6 * deformed[v] - scaled.rest_positions[v];
    compute_elastic_forces(m, s);

    std::ifstream in(csv);
    std::string line;
    std::getline(in, line);
    EXPECT_EQ(line, "vertex,fx,fy,fz");
    size_t rows = 0;
    while (std::getline(in, line)) {
      size_t v;
      double f[3];
      ASSERT_EQ(std::sscanf(line.c_str(), "%zu,%lf,%lf,%lf", &v, &f[0], &f[1], &f[2]), 4) << line;
      EXPECT_EQ(v, rows);
      for (int i = 0; i < 3; ++i) EXPECT_NEAR(f[i], s.force[v][i], 1e-12 * (1e-6 + std::abs(f[i])));
      ++rows;
    }
    EXPECT_EQ(rows, mesh.vertex_count());
  }
}

TEST(CmdForces, SuccessSaysWhatItWroteInOneLine) {
  const fs::path dir = fs::temp_directory_path() / "zona_cmd_forces_test_line";
  fs::create_directories(dir);
  const Mesh mesh = testing::box_mesh({0, 0, 0}, {1, 1, 1}, 1, 1, 1);
  write_tetgen(dir / "rest", mesh.rest_positions, mesh.tets);
  const std::string rest = (dir / "rest.node").string(), csv = (dir / "f.csv").string();
  const test::CliRun r = test::run_zona("forces " + rest + " " + rest +
                                        " --scale 1e-6 --backend cpu --out " + csv);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_EQ(r.out.rfind("wrote " + csv + ": elastic forces on " +
                            std::to_string(mesh.vertex_count()) + " vertices (svk, gradient",
                        0),
            0u)
      << r.out;
  EXPECT_EQ(std::count(r.out.begin(), r.out.end(), '\n'), 1) << r.out;
  EXPECT_NE(r.out.find("largest |f| 0 N"), std::string::npos) << r.out;  // at rest
}

// zona's own VTU files: a rest mesh and a frame (points at rest, displacement beside them) give
// the forces of the frame's deformed configuration.
TEST(CmdForces, ReadsZonasVtuRestMeshAndFrame) {
  const fs::path dir = fs::temp_directory_path() / "zona_cmd_forces_test_vtu";
  fs::create_directories(dir);
  Mesh mesh = testing::box_mesh({0, 0, 0}, {2e-6, 1e-6, 1e-6}, 2, 1, 1);
  std::vector<double> disp(3 * mesh.vertex_count());
  for (size_t v = 0; v < mesh.vertex_count(); ++v) {
    const Vec3d x = mesh.rest_positions[v];
    disp[3 * v] = 0.2 * x.x + 0.1 * x.z;
    disp[3 * v + 1] = -0.05 * x.y;
    disp[3 * v + 2] = 0.05e6 * x.x * x.y;
  }
  ASSERT_TRUE(write_vtu((dir / "rest.vtu").string(), mesh).ok());
  VtuOptions frame;
  frame.field_data = {{"points_at_rest", 1, {1.0}}};
  ASSERT_TRUE(write_vtu((dir / "frame.vtu").string(), mesh, {{"displacement", 3, disp}}, {}, frame).ok());
  std::string err;
  const fs::path csv = dir / "f.csv";
  ASSERT_EQ(run((dir / "rest.vtu").string() + " " + (dir / "frame.vtu").string() +
                    " --model svk --young 2000 --poisson 0.4 --backend cpu --out " + csv.string(),
                &err),
            0)
      << err;
  ModelDesc d;
  d.material.young = 2000;
  d.material.poisson = 0.4;
  const Model m = build_model(mesh, d).value();
  State s = make_state(m, 1);
  for (size_t v = 0; v < s.u.size(); ++v) s.u[v] = Vec3d{disp[3 * v], disp[3 * v + 1], disp[3 * v + 2]};
  compute_elastic_forces(m, s);
  std::ifstream in(csv);
  std::string line;
  std::getline(in, line);
  size_t rows = 0;
  double largest = 0;
  while (std::getline(in, line)) {
    size_t v;
    double f[3];
    ASSERT_EQ(std::sscanf(line.c_str(), "%zu,%lf,%lf,%lf", &v, &f[0], &f[1], &f[2]), 4) << line;
    for (int i = 0; i < 3; ++i) {
      EXPECT_NEAR(f[i], s.force[v][i], 1e-9 * (1e-12 + std::abs(f[i])));
      largest = std::max(largest, std::abs(f[i]));
    }
    ++rows;
  }
  EXPECT_EQ(rows, mesh.vertex_count());
  EXPECT_GT(largest, 1e-12);  // the frame was read deformed, not at rest
  fs::remove_all(dir);
}

TEST(CmdForces, BadInputsFailWithOneLine) {
  const fs::path dir = fs::temp_directory_path() / "zona_cmd_forces_test_bad";
  fs::create_directories(dir);
  const Mesh mesh = testing::box_mesh({0, 0, 0}, {1, 1, 1}, 1, 1, 1);
  write_tetgen(dir / "rest", mesh.rest_positions, mesh.tets);
  std::vector<Vec3d> fewer(mesh.rest_positions.begin(), mesh.rest_positions.end() - 1);
  write_tetgen(dir / "fewer", fewer, {});
  const std::string rest = (dir / "rest.node").string();
  const std::string out = " --out " + (dir / "f.csv").string();
  std::string err;
  EXPECT_NE(run(rest + " " + rest + " --poisson 0.5" + out, &err), 0);
  EXPECT_NE(err.find("incompressible"), std::string::npos) << err;
  EXPECT_EQ(std::count(err.begin(), err.end(), '\n'), 1) << err;
  EXPECT_NE(run(rest + " " + rest + " --young -3" + out, &err), 0);
  EXPECT_NE(err.find("Young"), std::string::npos) << err;
  EXPECT_NE(run(rest + " " + (dir / "fewer.node").string() + out, &err), 0);
  EXPECT_NE(err.find("same connectivity"), std::string::npos) << err;
  EXPECT_NE(run(rest + " " + rest + " --backend gpu" + out, &err), 0);
}

}  // namespace
}  // namespace zona
