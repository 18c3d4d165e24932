// Tests for engine/simulation: the injection experiment end to end on small geometry with known
// answers (reaction = static elastic force, Coulomb stick / slip, suction balance), mesh
// refinement and mass scaling independence, puncture and force drop, the split step, the
// Backend path, and the mouse scene's puncture band at a reduced size.
#include "engine/sim/simulation.h"

#include <gtest/gtest.h>

#include <atomic>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>

#include "engine/sim/backend_cpu.h"
#include "engine/mesh/mesh_generate.h"
#include "engine/mesh/mesh_io.h"
#include "engine/scene/scene_mesh.h"
#include "tests/engine/test_scenes.h"

namespace zona {
namespace {

using json = nlohmann::json;
using test::small_cell_scene;
namespace fs = std::filesystem;

// A folder for this test binary's files, removed at the end of each test.
struct TempDir {
  fs::path path;
  TempDir() {
    path = fs::temp_directory_path() /
           ("zona_sim_" + std::to_string(::testing::UnitTest::GetInstance()->random_seed()) + "_" +
            ::testing::UnitTest::GetInstance()->current_test_info()->name());
    fs::create_directories(path);
  }
  ~TempDir() {
    std::error_code ec;
    fs::remove_all(path, ec);
  }
};

// Writes a box mesh [0, sx] x [0, sy] x [0, sz] um with n cubes per side as a Gmsh file.
std::string write_box(const TempDir& dir, double sx, double sy, double sz, int nx, int ny, int nz) {
  const Mesh box = generate_box_mesh(Vec3d{0, 0, 0}, Vec3d{sx, sy, sz}, nx, ny, nz);
  const std::string path = (dir.path / "box.msh").string();
  EXPECT_TRUE(write_gmsh41(path, box).ok());
  return path;
}

// These tests cover the kinematic contact (engine/tools/contact.h: contact sets, friction return
// mapping, the backend path with uploads); the penalty step is tests/engine/sim/job_test.cpp.
Scene parse(const json& j, const std::vector<std::string>& overrides = {}) {
  std::vector<std::string> all = {"contact.model=kinematic"};
  all.insert(all.end(), overrides.begin(), overrides.end());
  Result<Scene> s = parse_scene(j, "test.json", all);
  EXPECT_TRUE(s.ok()) << (s.ok() ? "" : s.error().message);
  return s.ok() ? *s : Scene{};
}

std::unique_ptr<Simulation> create(const Scene& scene, const SimulationOptions& options = {}) {
  SimulationOptions o = options;
  o.threads = 1;
  Result<std::unique_ptr<Simulation>> sim = Simulation::create(scene, o);
  EXPECT_TRUE(sim.ok()) << (sim.ok() ? "" : sim.error().message);
  return sim.ok() ? std::move(*sim) : nullptr;
}

// A 12 x 12 x 6 um box on a fixed bottom, pressed from above by a flat tool wider than the box
// (its whole top face), linear material.
json pressed_box(const std::string& mesh_file, double friction) {
  return json{
      {"mesh", {{"file", mesh_file}, {"unit", "um"}}},
      {"model", "linear"},
      {"materials", {{"default", {{"young", "10 kPa"}, {"poisson", 0.3}, {"damping", "300 1/s"}}}}},
      {"integrator",
       {{"target_dt", "5 us"}, {"mass_scaling_mode", "selective"}, {"duration", "25 ms"}}},
      {"boundary", json::array({{{"type", "fixed"}, {"where", {{"below", "0.1 um"}}}}})},
      {"needle",
       {{"shape", "flat"},
        {"tip_radius", "20 um"},
        {"direction", "-z"},
        {"standoff", "0.5 um"},
        {"speed", "0.1 mm/s"},
        {"max_travel", "1.1 um"},
        {"friction", friction}}},
      {"output", {{"frames", 0}, {"sample_interval", "0.1 ms"}}}};
}

TEST(Simulation, FlatToolReactionEqualsTheStaticElasticForce) {
  TempDir dir;
  const std::string file = write_box(dir, 12, 12, 6, 4, 4, 2);
  auto sim = create(parse(pressed_box(file, 100.0)));
  ASSERT_TRUE(sim);
  while (!sim->finished()) ASSERT_FALSE(sim->step() & kStepNotAdvanced);
  const NeedleReport& r = sim->report();
  // Every top vertex sticks to the tool, pushed 0.6 um down.
  EXPECT_EQ(r.contacts, 25);
  EXPECT_NEAR(r.deformation, 0.6e-6, 1e-9);
  // The reference: the same body with the top face prescribed 0.6 um down, relaxed statically.
  const Model& m = sim->model();
  State s = make_state(m, 1);
  std::vector<int32_t> top;
  for (size_t v = 0; v < m.vertex_count(); ++v)
    if (m.rest_positions[v].z > 6e-6 - 1e-12) top.push_back(static_cast<int32_t>(v));
  ASSERT_EQ(top.size(), 25u);
  ASSERT_TRUE(set_prescribed_vertices(m, s, top).ok());
  for (Vec3d& t : s.prescribed_displacement) t = Vec3d{0, 0, -0.6e-6};
  RelaxOptions o;
  o.relative_tolerance = 1e-10;
  ASSERT_TRUE(relax_to_equilibrium(m, s, o).converged);
  const double reference = -s.diag.constraint_force.z;  // the tool pushes down (-z)
  ASSERT_GT(reference, 0.0);
  EXPECT_NEAR(r.force, reference, 0.01 * reference);
  // Equilibrium: the fixed bottom carries the same force.
  Vec3d bottom{0, 0, 0};
  for (int32_t v : m.fixed_vertices) bottom += sim->state().force[static_cast<size_t>(v)];
  EXPECT_NEAR(bottom.z, -reference, 0.02 * reference);
}

TEST(Simulation, FrictionSticksInsideTheConeAndSlidesOnIt) {
  TempDir dir;
  const std::string file = write_box(dir, 12, 12, 6, 4, 4, 2);
  // Press 0.6 um down (the tool starts 0.5 um above), then slide 1.5 um along +x.
  const std::string traj = (dir.path / "slide.csv").string();
  {
    std::ofstream f(traj);
    f << "time_s,x_m,y_m,z_m\n0,6e-6,6e-6,6.5e-6\n0.011,6e-6,6e-6,5.4e-6\n0.016,6e-6,6e-6,5.4e-6\n"
         "0.031,7.5e-6,6e-6,5.4e-6\n";
  }
  for (const double mu : {0.1, 5.0}) {
    json j = pressed_box(file, mu);
    j["needle"]["trajectory"] = traj;
    j["needle"]["start"] = "auto";
    j["integrator"]["duration"] = "31 ms";
    auto sim = create(parse(j));
    ASSERT_TRUE(sim);
    while (!sim->finished()) ASSERT_FALSE(sim->step() & kStepNotAdvanced);
    const NeedleReport& r = sim->report();
    const double normal = -r.force_vector.z, tangential = std::fabs(r.force_vector.x);
    ASSERT_GT(normal, 0.0);
    double top_dx = 0;
    int top = 0;
    for (const Contact& c : sim->needle_contacts()) {
      top_dx += sim->state().u[static_cast<size_t>(c.vertex)].x;
      ++top;
    }
    ASSERT_GT(top, 0);
    top_dx /= top;
    if (mu < 1) {
      // Sliding: the tangential force sits on the cone (up to the return mapping's one-step
      // lag), the top lags the tool.
      EXPECT_NEAR(tangential, mu * normal, 0.15 * mu * normal) << "mu " << mu;
      EXPECT_LT(top_dx, 1.0e-6);
    } else {
      // Sticking: inside the cone, the top moved with the tool.
      EXPECT_LT(tangential, mu * normal);
      EXPECT_GT(tangential, 0.1 * normal);
      EXPECT_NEAR(top_dx, 1.5e-6, 0.02e-6);
    }
  }
}

// The same press and slide on the penalty step, its tip scripted by the trajectory file: the
// tangential load sits on the Coulomb cone while the tool slides over the top, and inside it
// when the top sticks and moves with the tool (up to the stick zone's few nm).
TEST(Simulation, PenaltyFrictionFollowsATrajectorySticksAndSlides) {
  TempDir dir;
  const std::string file = write_box(dir, 12, 12, 6, 4, 4, 2);
  const std::string traj = (dir.path / "slide.csv").string();
  {
    std::ofstream f(traj);
    f << "time_s,x_m,y_m,z_m\n0,6e-6,6e-6,6.5e-6\n0.011,6e-6,6e-6,5.4e-6\n0.016,6e-6,6e-6,5.4e-6\n"
         "0.031,7.5e-6,6e-6,5.4e-6\n";
  }
  for (const double mu : {0.1, 5.0}) {
    json j = pressed_box(file, mu);
    j["needle"]["trajectory"] = traj;
    j["needle"]["start"] = "auto";
    j["integrator"]["duration"] = "31 ms";
    auto sim = create(parse(j, {"contact.model=penalty"}));
    ASSERT_TRUE(sim);
    ASSERT_TRUE(sim->job_mode());
    while (!sim->finished()) ASSERT_FALSE(sim->step() & kStepNotAdvanced);
    const NeedleReport& r = sim->report();
    // The tip went where the file says.
    EXPECT_NEAR(r.tip.x, 7.5e-6, 1e-12);
    EXPECT_NEAR(r.tip.z, 5.4e-6, 1e-12);
    const double normal = -r.force_vector.z, tangential = std::fabs(r.force_vector.x);
    ASSERT_GT(normal, 0.0);
    double top_dx = 0;
    int top = 0;
    const Model& m = sim->model();
    for (size_t v = 0; v < m.vertex_count(); ++v)
      if (m.rest_positions[v].z > 6e-6 - 1e-12) {
        top_dx += sim->state().u[v].x;
        ++top;
      }
    ASSERT_EQ(top, 25);
    top_dx /= top;
    if (mu < 1) {
      EXPECT_NEAR(tangential, mu * normal, 0.05 * mu * normal) << "mu " << mu;
      EXPECT_LT(top_dx, 1.0e-6);
    } else {
      EXPECT_LT(tangential, mu * normal);
      EXPECT_GT(tangential, 0.1 * normal);
      EXPECT_NEAR(top_dx, 1.5e-6, 0.02e-6);
    }
  }
}

TEST(Simulation, NeedleForceIsConsistentUnderMeshRefinement) {
  // A sphere tip (R 6 um) 3 um into a box: contact radius sqrt(2 R d) = 6 um, held by 17
  // vertices on the 2 um mesh and 27 on the 1.5 um mesh. Measured: 0.313, 0.264, 0.256, 0.256 uN
  // on 3, 2, 1.5, 1.2 um meshes (docs/injection.md).
  TempDir dir;
  double force[2];
  const int cubes[2] = {12, 16};
  for (int k = 0; k < 2; ++k) {
    const std::string file = write_box(dir, 24, 24, 12, cubes[k], cubes[k], cubes[k] / 2);
    json j = pressed_box(file, 0.3);
    j["needle"] = {{"shape", "sphere"}, {"tip_radius", "6 um"}, {"direction", "-z"},
                   {"standoff", "0.5 um"}, {"speed", "0.2 mm/s"}, {"max_travel", "3.5 um"}};
    j["integrator"] = {{"target_dt", "10 us"}, {"mass_scaling_mode", "selective"},
                       {"dt_safety", 0.25}, {"stiffness_damping", "50 us"}, {"duration", "25 ms"}};
    auto sim = create(parse(j));
    ASSERT_TRUE(sim);
    while (!sim->finished()) ASSERT_FALSE(sim->step() & kStepNotAdvanced);
    force[k] = sim->report().force;
    EXPECT_NEAR(sim->report().deformation, 3e-6, 0.1e-6);
    EXPECT_GT(sim->report().contacts, 12);
  }
  ASSERT_GT(force[0], 0.0);
  EXPECT_NEAR(force[1], force[0], 0.05 * force[0]);
}

// A 24 um ball held on its far side, indented by a point needle: the quasi-static SVK setup of
// the mouse scene at a size a test can afford.

// Force at deformation `at` [m] by linear interpolation of the recorded curve.
double force_at(const RunResult& run, double at) {
  for (size_t i = 1; i < run.samples.size(); ++i) {
    const ForceSample &a = run.samples[i - 1], &b = run.samples[i];
    if (a.deformation <= at && b.deformation >= at && b.deformation > a.deformation)
      return a.force + (at - a.deformation) / (b.deformation - a.deformation) * (b.force - a.force);
  }
  return NAN;
}

TEST(Simulation, QuasiStaticForceDoesNotDependOnTheMassScaling) {
  RunResult runs[2];
  const char* steps[2][2] = {{"20 us", "100 us"}, {"10 us", "50 us"}};
  for (int k = 0; k < 2; ++k) {
    json j = small_cell_scene();
    j["integrator"]["target_dt"] = steps[k][0];
    j["integrator"]["stiffness_damping"] = steps[k][1];
    Result<RunResult> r = run_scene(parse(j));
    ASSERT_TRUE(r.ok()) << r.error().message;
    runs[k] = *r;
    ASSERT_FALSE(runs[k].stopped_early) << runs[k].stop_reason;
  }
  // Halving the step quarters the added mass: the curve must not move.
  for (double at : {2e-6, 4e-6, 5.5e-6}) {
    const double coarse = force_at(runs[0], at), fine = force_at(runs[1], at);
    ASSERT_TRUE(std::isfinite(coarse) && std::isfinite(fine)) << at;
    EXPECT_NEAR(coarse, fine, 0.05 * fine) << "at " << at;
  }
}

TEST(Simulation, NeoHookeanSmallCellRunsThroughWithoutBlowUp) {
  // The small cell pushed 6 um with the stable neo-Hookean law: the whole push completes with no
  // energy blow-up and nothing non-finite, and no element inverts, where the (clamped) SVK run
  // collapses and inverts elements under the tip. At small deformation the two forces agree
  // (both linearise to the same (lambda, mu)).
  RunResult runs[2];
  const char* models[2] = {"svk", "neohookean"};
  for (int k = 0; k < 2; ++k) {
    json j = small_cell_scene();
    j["model"] = models[k];
    Result<RunResult> r = run_scene(parse(j));
    ASSERT_TRUE(r.ok()) << r.error().message;
    runs[k] = *r;
    ASSERT_FALSE(runs[k].stopped_early) << models[k] << ": " << runs[k].stop_reason;
  }
  const RunResult &svk = runs[0], &snh = runs[1];
  EXPECT_TRUE(svk.status & kStepCollapsingElement);
  EXPECT_FALSE(snh.status & (kStepEnergyBlowUp | kStepNonFinite | kStepInvertedElement));
  EXPECT_FALSE(snh.status & (kStepCollapsingElement | kStepClampedElement));
  EXPECT_GT(snh.peak_deformation, 5.5e-6);
  const double svk_small = force_at(svk, 0.2e-6), snh_small = force_at(snh, 0.2e-6);
  ASSERT_TRUE(std::isfinite(svk_small) && std::isfinite(snh_small));
  EXPECT_NEAR(snh_small, svk_small, 0.1 * svk_small);
  char text[200];
  std::snprintf(text, sizeof text,
                "svk / neohookean [N] at 0.2 um %.4g / %.4g, 1 um %.4g / %.4g, 5.5 um %.4g / %.4g",
                svk_small, snh_small, force_at(svk, 1e-6), force_at(snh, 1e-6),
                force_at(svk, 5.5e-6), force_at(snh, 5.5e-6));
  RecordProperty("svk_vs_neohookean_force", text);
}

TEST(Simulation, KinematicContactBlowUpStopsWithStiffnessDampingOn) {
  // The kinematic contact path with an unstable stiffness damping (40 steps, as
  // JobSimulation.BlowUpStopsTheRunWithoutAPuncture): the damping loads' own work is kept out of
  // the energy budget (only the tools' work counts), so the energy test stops the run at the
  // blow-up, before anything turns non-finite, and no puncture is recorded from it.
  json j = small_cell_scene();
  j["integrator"]["stiffness_damping"] = "400 us";
  j["puncture"] = {{"criterion", "energy"}, {"threshold", "1 J"}};  // never met
  Result<RunResult> r = run_scene(parse(j));
  ASSERT_TRUE(r.ok()) << r.error().message;
  EXPECT_TRUE(r->stopped_early);
  EXPECT_TRUE(r->status & kStepEnergyBlowUp) << r->stop_reason;
  EXPECT_FALSE(r->status & kStepNonFinite) << r->stop_reason;
  EXPECT_NE(r->stop_reason.find("energy blow-up"), std::string::npos) << r->stop_reason;
  EXPECT_FALSE(r->puncture.punctured);
  // The stable damping of the calibrated configuration (100 us, 10 steps) runs through.
  json ok = small_cell_scene();
  ok["integrator"]["stiffness_damping"] = "100 us";
  Result<RunResult> fine = run_scene(parse(ok));
  ASSERT_TRUE(fine.ok()) << fine.error().message;
  EXPECT_FALSE(fine->stopped_early) << fine->stop_reason;
}

TEST(Simulation, TheCellsDensityFollowsItsSizeNotItsMass) {
  // The mouse scenes give a density: a 100 um cell is as dense as the 56 um one (a scene that
  // gave Table I's mass would have made it 175 kg/m^3), and its mass grows with its volume.
  auto build = [](const std::vector<std::string>& sets) {
    Result<Scene> scene =
        load_scene(std::string(ZONA_SOURCE_DIR) + "/scenes/mouse_oocyte.json", sets);
    EXPECT_TRUE(scene.ok()) << scene.error().message;
    SimulationOptions so;
    so.threads = 1;
    Result<std::unique_ptr<Simulation>> sim = Simulation::create(*scene, so);
    EXPECT_TRUE(sim.ok()) << sim.error().message;
    return std::move(*sim);
  };
  const auto small = build({"mesh.generate.vertices=800"});
  const auto large = build({"mesh.generate.vertices=800", "mesh.generate.diameter=100um"});
  EXPECT_DOUBLE_EQ(small->model().materials.front().density, 1000.0);
  EXPECT_DOUBLE_EQ(large->model().materials.front().density, 1000.0);
  // A total mass instead: it is spread over the mesh, and the density it implies is said.
  const auto by_mass = build({"mesh.generate.vertices=800", "materials.default.density=null",
                              "materials.default.mass=9.1952e-5 mg",
                              "mesh.generate.diameter=100um"});
  const double rho = by_mass->model().materials.front().density;
  EXPECT_NEAR(rho, 1000.0 * std::pow(56.0 / 100.0, 3), 0.05 * 175.0);
  bool said = false;
  for (const std::string& note : by_mass->notes())
    said = said || note.find("is a density of") != std::string::npos;
  EXPECT_TRUE(said);
}

TEST(Simulation, PunctureRecordsTheMomentAndReleasesTheForce) {
  json j = small_cell_scene();
  j["puncture"] = {{"criterion", "force"}, {"threshold", "0.2 uN"}, {"force_drop", 0.8},
                   {"drop_time", "0.5 ms"}, {"shaft_friction", "0.01 N/m"}};
  j["needle"]["max_travel"] = "7 um";
  auto sim = create(parse(j));
  ASSERT_TRUE(sim);
  double at_puncture_plus_drop = NAN, drag_travel = 0;
  while (!sim->finished()) {
    ASSERT_FALSE(sim->step() & kStepNotAdvanced);
    const PunctureRecord& p = sim->puncture();
    if (p.punctured && std::isnan(at_puncture_plus_drop) && sim->report().time >= p.time + 0.5e-3) {
      at_puncture_plus_drop = sim->report().raw_force;
      drag_travel = sim->report().travel - p.needle_travel;
    }
  }
  const PunctureRecord& p = sim->puncture();
  ASSERT_TRUE(p.punctured);
  EXPECT_GE(p.force, 0.2e-6);
  EXPECT_LT(p.force, 0.22e-6);
  // Deformation: the tip's advance into the cell, travel minus the standoff.
  EXPECT_NEAR(p.deformation, p.needle_travel - 0.5e-6, 0.15e-6);
  EXPECT_NEAR(p.time, p.needle_travel / 0.2e-3, 1e-9);
  // After drop_time: 20 % of the force at puncture plus the shaft drag.
  EXPECT_NEAR(at_puncture_plus_drop, 0.2 * dot(p.force_vector, Vec3d{1, 0, 0}) + 0.01 * drag_travel,
              1e-12);
  EXPECT_TRUE(sim->needle_contacts().empty());
  EXPECT_TRUE(sim->report().punctured);
}

TEST(Simulation, SuctionOnTheAspiratedPatchIsBalancedByTheRim) {
  json j{{"mesh", {{"generate", {{"diameter", "24 um"}, {"vertices", 300}}}}},
         {"model", "svk"},
         {"materials",
          {{"default", {{"young", "10 kPa"}, {"poisson", 0.4}, {"damping", "400 1/s"}}}}},
         {"integrator",
          {{"target_dt", "10 us"}, {"mass_scaling_mode", "selective"}, {"duration", "20 ms"},
           {"dt_safety", 0.25}, {"stiffness_damping", "40 us"}}},
         {"needle", {{"enabled", false}, {"direction", "+x"}}},
         {"holding_pipette",
          {{"mode", "suction"}, {"inner_radius", "5 um"}, {"outer_radius", "10 um"},
           {"suction", "2.5 kPa"}, {"friction", 0.3}}},
         {"output", {{"frames", 0}}}};
  auto sim = create(parse(j));
  ASSERT_TRUE(sim);
  while (!sim->finished()) ASSERT_FALSE(sim->step() & kStepNotAdvanced);
  const HoldingSetup& h = *sim->holding();
  // The pull is p times the aspirated area, pi a^2 up to faceting...
  EXPECT_NEAR(h.suction_total.x, 2.5e3 * M_PI * 25e-12, 0.25 * 2.5e3 * M_PI * 25e-12);
  // ... and the rim holds the cell against it: rim reaction + suction = 0.
  const Vec3d rim = sim->report().holding_force;
  EXPECT_GT(sim->report().holding_contacts, 3);
  EXPECT_NEAR(rim.x, -h.suction_total.x, 0.03 * h.suction_total.x);
  EXPECT_NEAR(rim.y, 0.0, 0.03 * h.suction_total.x);
  EXPECT_NEAR(rim.z, 0.0, 0.03 * h.suction_total.x);
}

TEST(Simulation, SplitStepTakesTheHandedInPose) {
  auto sim = create(parse(small_cell_scene()));
  ASSERT_TRUE(sim);
  sim->step1();
  const Vec3d handed = sim->needle_script().start + Vec3d{0.3e-6, 0.1e-6, 0};
  sim->set_needle_tip(handed);
  sim->step2();
  EXPECT_EQ(sim->report().tip.x, handed.x);
  EXPECT_EQ(sim->report().tip.y, handed.y);
  EXPECT_NEAR(sim->report().travel, 0.3e-6, 1e-15);
  EXPECT_EQ(sim->report().step, 1);
}

// The CPU backend under another name, so that the simulation drives it through the Backend
// interface (upload on contact changes, download every step). `forward_loads` false leaves
// set_external_forces at the interface's "not supported", so loads travel by upload.
class RenamedBackend final : public Backend {
 public:
  explicit RenamedBackend(bool forward_loads = true)
      : inner_(make_cpu_backend(BackendOptions{})), forward_loads_(forward_loads) {}
  const char* name() const override { return "renamed"; }
  std::string description() const override { return "renamed cpu"; }
  Status upload(const Model& m, const State& s) override {
    ++uploads;
    return inner_->upload(m, s);
  }
  Status set_prescribed_targets(std::span<const Vec3d> t) override {
    return inner_->set_prescribed_targets(t);
  }
  Status set_external_forces(std::span<const Vec3d> f) override {
    return forward_loads_ ? inner_->set_external_forces(f) : Backend::set_external_forces(f);
  }
  int uploads = 0;
  StepReport step(int n) override { return inner_->step(n); }
  Status download(State& s) override { return inner_->download(s); }
  Status elastic_forces(std::span<const Vec3d> u, std::span<Vec3d> f) override {
    return inner_->elastic_forces(u, f);
  }
  Result<StateSummary> summarize() override { return inner_->summarize(); }

 private:
  std::unique_ptr<Backend> inner_;
  bool forward_loads_;
};

// With stiffness damping (a load that changes every step) the Backend path gives the in-place
// path's answer, whether loads travel through set_external_forces or by re-uploading; the
// former uploads only when the contact set changes.
TEST(Simulation, BackendPathMatchesTheInPlacePath) {
  json j = small_cell_scene();
  j["needle"]["max_travel"] = "2 um";
  const Scene scene = parse(j);
  ASSERT_GT(scene.integrator.stiffness_damping, 0.0);
  RenamedBackend* forwarding = nullptr;
  RenamedBackend* uploading = nullptr;
  SimulationOptions via_loads, via_uploads;
  via_loads.backend_factory = [&](std::string*) -> Result<std::unique_ptr<Backend>> {
    forwarding = new RenamedBackend(true);
    return std::unique_ptr<Backend>(forwarding);
  };
  via_uploads.backend_factory = [&](std::string*) -> Result<std::unique_ptr<Backend>> {
    uploading = new RenamedBackend(false);
    return std::unique_ptr<Backend>(uploading);
  };
  auto a = create(scene);
  auto b = create(scene, via_loads);
  auto c = create(scene, via_uploads);
  ASSERT_TRUE(a && b && c);
  EXPECT_EQ(b->backend_description(), "renamed cpu");
  for (const std::string& note : b->notes())
    EXPECT_EQ(note.find("stiffness damping"), std::string::npos) << note;
  constexpr int kSteps = 400;
  for (int i = 0; i < kSteps; ++i) {
    a->step();
    b->step();
    c->step();
  }
  EXPECT_GT(a->report().contacts, 0);
  for (const Simulation* s : {b.get(), c.get()}) {
    EXPECT_EQ(a->report().contacts, s->report().contacts);
    EXPECT_NEAR(a->report().force, s->report().force, 1e-9 * std::fabs(a->report().force));
    EXPECT_EQ(a->report().deformation, s->report().deformation);
  }
  // Loads by set_external_forces: uploads only for contact-set changes, far fewer than steps.
  EXPECT_GE(uploading->uploads, kSteps);
  EXPECT_LT(forwarding->uploads, kSteps / 4);
}

// Surface snapshots for a render thread: the initial slot is the rest surface, a publication
// every snapshot_interval steps, and the reader's slot holds the deformed surface of that step.
TEST(Simulation, SurfaceSnapshotsPublishTheDeformedSurface) {
  SimulationOptions o;
  o.snapshot_interval = 10;
  auto sim = create(parse(small_cell_scene()), o);
  ASSERT_TRUE(sim);
  EXPECT_EQ(create(parse(small_cell_scene()))->surface_snapshots(), nullptr);
  TripleBuffer<SurfaceSnapshot>* snapshots = sim->surface_snapshots();
  ASSERT_NE(snapshots, nullptr);
  const std::vector<int32_t>& surface = sim->surface().vertices;
  ASSERT_EQ(snapshots->read_slot().positions.size(), surface.size());
  EXPECT_FALSE(snapshots->acquire());  // nothing published yet: the rest surface
  EXPECT_EQ(norm(snapshots->read_slot().positions[0] - sim->model().rest_positions[size_t(surface[0])]),
            0.0);
  // Into contact, then 20 steps more, then 5 past a publication.
  int64_t steps = 0;
  while (sim->report().contacts == 0 && steps < 20000) sim->step(), ++steps;
  ASSERT_GT(sim->report().contacts, 0);
  const int64_t published = (steps / 10 + 3) * 10;
  while (steps < published + 5) sim->step(), ++steps;
  ASSERT_TRUE(snapshots->acquire());
  const SurfaceSnapshot& snap = snapshots->read_slot();
  EXPECT_EQ(snap.step, published);  // the newest publication, not an older one
  // The state has moved on 5 steps since: recompute that step's surface from a second run.
  auto again = create(parse(small_cell_scene()));
  for (int64_t k = 0; k < published; ++k) again->step();
  double moved = 0;
  for (size_t i = 0; i < surface.size(); ++i) {
    const size_t v = size_t(surface[i]);
    EXPECT_EQ(norm(snap.positions[i] - (again->model().rest_positions[v] + again->state().u[v])), 0.0)
        << i;
    moved = std::max(moved, norm(again->state().u[v]));
  }
  EXPECT_GT(moved, 0.0);
  EXPECT_FALSE(snapshots->acquire());  // read already: nothing newer
}

TEST(Simulation, CoarseMeshPointNeedleUsesTheHitTriangle) {
  // Ladjal et al.'s 115-vertex resolution: a 1 um point tip fits between the vertices, and the
  // triangle it pierces is carried along (the force rises as soon as the tip meets the surface).
  json j = small_cell_scene();
  j["mesh"]["generate"]["vertices"] = 60;
  j["needle"]["tip_radius"] = "0.5 um";
  j["needle"]["max_travel"] = "2 um";
  auto sim = create(parse(j));
  ASSERT_TRUE(sim);
  while (!sim->finished()) sim->step();
  EXPECT_GE(sim->report().contacts, 3);
  EXPECT_GT(sim->report().force, 0.0);
  EXPECT_NEAR(sim->report().deformation, 1.5e-6, 0.2e-6);
}

TEST(Simulation, ScenesItCannotRunAreRefused) {
  json j = small_cell_scene();
  j["model"] = "particles";  // runs (issue 9), but not with the strain criterion: no elements
  j["puncture"] = {{"criterion", "strain"}, {"threshold", 0.2}};
  Result<std::unique_ptr<Simulation>> s = Simulation::create(parse(j));
  ASSERT_FALSE(s.ok());
  EXPECT_NE(s.error().message.find("particles"), std::string::npos);
  j = small_cell_scene();
  j["holding_pipette"]["inner_radius"] = "0.01 um";
  s = Simulation::create(parse(j));
  ASSERT_FALSE(s.ok());
  EXPECT_NE(s.error().message.find("holding_pipette"), std::string::npos);
}

TEST(Simulation, RunStreamsEverySampleAndStopsWhenAsked) {
  const Scene scene = parse(small_cell_scene());
  // Every recorded sample reaches on_sample, in order, the same as the result's.
  std::unique_ptr<Simulation> sim = create(scene);
  ASSERT_TRUE(sim);
  std::vector<ForceSample> streamed;
  RunOptions options;
  options.on_sample = [&](const ForceSample& s) { streamed.push_back(s); };
  const RunResult full = run_simulation(*sim, options);
  EXPECT_FALSE(full.interrupted);
  ASSERT_GT(full.samples.size(), 10u);
  ASSERT_EQ(streamed.size(), full.samples.size());
  for (size_t i = 0; i < streamed.size(); ++i) {
    EXPECT_EQ(streamed[i].time, full.samples[i].time) << i;
    EXPECT_EQ(streamed[i].force, full.samples[i].force) << i;
  }

  // The stop flag, raised after the fifth sample (as a signal handler would), ends the run
  // before the next batch of steps the driver hands the runner: the result says interrupted and
  // holds the curve up to there, the same rows as the full run's.
  sim = create(scene);
  ASSERT_TRUE(sim);
  std::atomic<bool> stop{false};
  size_t seen = 0;
  options.on_sample = [&](const ForceSample&) {
    if (++seen == 5) stop.store(true);
  };
  options.stop = &stop;
  const RunResult cut = run_simulation(*sim, options);
  EXPECT_TRUE(cut.interrupted);
  EXPECT_FALSE(cut.stopped_early);
  EXPECT_GE(cut.samples.size(), 5u);
  EXPECT_EQ(seen, cut.samples.size());
  EXPECT_LT(cut.simulated_time, 0.5 * full.simulated_time);
  // The last row is the state the run stopped in, between two of the full run's rows.
  for (size_t i = 0; i + 1 < cut.samples.size(); ++i) {
    EXPECT_EQ(cut.samples[i].time, full.samples[i].time) << i;
    EXPECT_EQ(cut.samples[i].force, full.samples[i].force) << i;
  }
  EXPECT_GT(cut.samples.back().time, full.samples[cut.samples.size() - 2].time);
  EXPECT_LE(cut.samples.back().time, full.samples[cut.samples.size() - 1].time);

  // Raised before the run: no step is taken, the start is still recorded.
  sim = create(scene);
  ASSERT_TRUE(sim);
  options.on_sample = nullptr;
  const RunResult none = run_simulation(*sim, options);
  EXPECT_TRUE(none.interrupted);
  EXPECT_EQ(none.steps, 0);
  EXPECT_EQ(none.samples.size(), 1u);
}

TEST(Simulation, MouseOocytePunctureLandsInSeed000Band) {
  // The main job on a 300-vertex mesh instead of 800 (CI time; `zona run` runs the full scene,
  // docs/validation.md). Ladjal et al.: puncture at about 45 um and 7.5 uN; the band is 35-55 um and
  // 5-10 uN.
  // The kinematic contact with stiffness damping and SVK, the configuration first calibrated
  // against Ladjal et al. (docs/validation.md); the default scene now runs the converged
  // configuration (neo-Hookean with nodal pressure, penalty contact), calibrated on 1M vertices.
  Result<Scene> scene = load_scene(std::string(ZONA_SOURCE_DIR) + "/scenes/mouse_oocyte.json",
                                   {"mesh.generate.vertices=300", "output.frames=0",
                                    "contact.model=kinematic",
                                    "integrator.stiffness_damping=100us", "model=svk",
                                    "volumetric=element", "materials.default.young=36kPa",
                                    "materials.default.damping=100Hz",
                                    "integrator.target_dt=20us", "puncture.criterion=energy",
                                    "puncture.threshold=1.5e-10J"});
  ASSERT_TRUE(scene.ok()) << scene.error().message;
  RunOptions options;
  options.simulation.threads = 0;
  options.stop_after_puncture = 0;
  Result<RunResult> run = run_scene(*scene, options);
  ASSERT_TRUE(run.ok()) << run.error().message;
  ASSERT_TRUE(run->puncture.punctured);
  EXPECT_GE(run->puncture.deformation, 35e-6);
  EXPECT_LE(run->puncture.deformation, 55e-6);
  EXPECT_GE(run->puncture.force, 5e-6);
  EXPECT_LE(run->puncture.force, 10e-6);
}

TEST(Simulation, DefaultScenePuncturesNearTheConvergedPointOnACoarseMesh) {
  // The shipped configuration (neo-Hookean with nodal pressure, penalty contact, 10 us, E 16.5
  // kPa, force criterion 7.5 uN) on 1500 vertices instead of 6000 (CI time). The converged curve
  // (1M vertices, docs/validation.md) reaches 7.5 uN at 41 um with 1.14e-10 J stored; with nodal
  // pressure a mesh this coarse is still within a few micrometres and 20 % of that energy
  // (measured: 38.6 um, 1.08e-10 J). Without nodal pressure it locks: 30.2 um (measured).
  Result<Scene> scene = load_scene(std::string(ZONA_SOURCE_DIR) + "/scenes/mouse_oocyte.json",
                                   {"mesh.generate.vertices=1500", "output.frames=0"});
  ASSERT_TRUE(scene.ok()) << scene.error().message;
  RunOptions options;
  options.simulation.threads = 0;
  options.stop_after_puncture = 0;
  Result<RunResult> run = run_scene(*scene, options);
  ASSERT_TRUE(run.ok()) << run.error().message;
  ASSERT_FALSE(run->stopped_early) << run->stop_reason;
  ASSERT_TRUE(run->puncture.punctured);
  EXPECT_GE(run->puncture.deformation, 35e-6);
  EXPECT_LE(run->puncture.deformation, 45e-6);
  EXPECT_NEAR(run->puncture.force, 7.5e-6, 0.1e-6);
  EXPECT_NEAR(run->puncture.energy, 1.14e-10, 0.2 * 1.14e-10);
}

}  // namespace
}  // namespace zona
