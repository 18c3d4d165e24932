// GPU against CPU on the same inputs (STYLE.md habit 7): elastic forces for every element kind
// and assembly, 1000-step trajectories with fixed and prescribed vertices, graph replay against
// single stepping, bitwise-identical deterministic runs, health flags, the stable neo-Hookean law
// (forces, inversion, trajectory). Every test skips when the
// CUDA backend cannot be created (no GPU, or built without CUDA); it only uses the Backend
// interface, so it compiles in the CPU-only build too.
#include "kernels/cuda_backend.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <limits>
#include <random>
#include <string>
#include <vector>

#include "engine/sim/backend.h"
#include "engine/sim/backend_cpu.h"
#include "engine/mesh/mesh_generate.h"
#include "engine/fem/model.h"
#include "engine/fem/state.h"

namespace zona {
namespace {

/// GPU forces (float32 element math) against the CPU's float64, relative to the largest force:
/// the gradient form, and the seed's tensor contraction, whose hundreds of terms of both signs
/// cancel more (its float32 rounding is larger).
constexpr double kForceTolerance = 2e-5;
constexpr double kTensorForceTolerance = 3e-4;
/// Displacements after 1000 steps, relative to the largest displacement: float32 forces
/// perturb every step by ~1e-7 relative; the dynamics carry it without amplifying it much.
constexpr double kTrajectoryTolerance = 2e-4;
/// The needle's constraint force after 1000 steps, relative to its magnitude.
constexpr double kConstraintForceTolerance = 1e-3;

#define ZONA_CUDA_BACKEND_OR_SKIP(var, options)                               \
  Result<std::unique_ptr<Backend>> var##_result = make_cuda_backend(options); \
  if (!var##_result) GTEST_SKIP() << var##_result.error().message;            \
  std::unique_ptr<Backend> var = std::move(var##_result).value()

// A small cell: 56 um ball with a zona shell (two materials), about 400 vertices.
Mesh small_cell() {
  CellMeshSpec spec;
  spec.target_vertices = 400;
  spec.zona_thickness = 6e-6;
  Result<Mesh> mesh = generate_cell_mesh(spec);
  EXPECT_TRUE(mesh.ok()) << (mesh ? "" : mesh.error().message);
  return mesh ? std::move(mesh).value() : Mesh{};
}

ModelDesc cell_desc(ConstitutiveModel law, Formulation form) {
  ModelDesc d;
  d.material.young = 2e3;  // cytoplasm [Pa]
  d.material.poisson = 0.45;
  d.material.damping = 200;  // [1/s]
  RegionMaterial zona;
  zona.region = kRegionZona;
  zona.material.young = 17.9e3;
  zona.material.poisson = 0.49;
  zona.material.damping = 200;
  d.region_materials.push_back(zona);
  d.constitutive = law;
  d.formulation = form;
  return d;
}

// Displacements of amplitude `strain` times the cell size, smooth plus random: large enough
// for SVK's cubic and quartic terms to matter, small enough to invert nothing.
std::vector<Vec3d> test_displacement(const Model& model, double strain, uint32_t seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> r(-1, 1);
  std::vector<Vec3d> u(model.vertex_count());
  const double size = 56e-6;
  for (size_t v = 0; v < u.size(); ++v) {
    const Vec3d p = model.rest_positions[v];
    u[v] = Vec3d{0.5 * p.x + 0.2 * p.y, -0.3 * p.y, 0.4 * p.z - 0.1 * p.x} * strain +
           Vec3d{r(rng), r(rng), r(rng)} * (0.05 * strain * size);
  }
  return u;
}

double max_norm(const std::vector<Vec3d>& a) {
  double m = 0;
  for (const Vec3d& x : a) m = std::max(m, norm(x));
  return m;
}

double max_diff(const std::vector<Vec3d>& a, const std::vector<Vec3d>& b) {
  double m = 0;
  for (size_t i = 0; i < a.size(); ++i) m = std::max(m, norm(a[i] - b[i]));
  return m;
}

std::vector<Vec3d> poisoned(size_t n) {
  const double nan = std::numeric_limits<double>::quiet_NaN();
  return std::vector<Vec3d>(n, Vec3d{nan, nan, nan});
}

struct ForceCase {
  ConstitutiveModel law;
  Formulation form;
  Assembly assembly;
};

class CudaForces : public ::testing::TestWithParam<ForceCase> {};

TEST_P(CudaForces, MatchCpuOnTheSameInputs) {
  const ForceCase c = GetParam();
  BackendOptions options;
  options.assembly = c.assembly;
  options.poison_outputs = true;
  ZONA_CUDA_BACKEND_OR_SKIP(gpu, options);
  const Mesh mesh = small_cell();
  Result<Model> model = build_model(mesh, cell_desc(c.law, c.form));
  ASSERT_TRUE(model.ok()) << model.error().message;
  const State state = make_state(*model, 1);
  std::unique_ptr<Backend> cpu = make_cpu_backend(BackendOptions{});
  ASSERT_TRUE(cpu->upload(*model, state).ok());
  ASSERT_TRUE(gpu->upload(*model, state).ok());
  for (uint32_t seed : {1u, 2u}) {
    const std::vector<Vec3d> u = test_displacement(*model, 0.08, seed);
    std::vector<Vec3d> f_cpu = poisoned(u.size()), f_gpu = poisoned(u.size());
    ASSERT_TRUE(cpu->elastic_forces(u, f_cpu).ok());
    const Status s = gpu->elastic_forces(u, f_gpu);
    ASSERT_TRUE(s.ok()) << s.error().message;
    const double scale = max_norm(f_cpu);
    ASSERT_GT(scale, 0);
    for (const Vec3d& f : f_gpu) ASSERT_TRUE(std::isfinite(f.x + f.y + f.z));
    const double tolerance =
        c.form == Formulation::kGradient ? kForceTolerance : kTensorForceTolerance;
    const double error = max_diff(f_cpu, f_gpu) / scale;
    // The measured error, for docs/performance.md's precision table.
    std::printf("[ measured ] force error %.3g of max |f| (%s)\n", error,
                gpu->description().c_str());
    EXPECT_LE(error, tolerance) << gpu->description();
  }
}

INSTANTIATE_TEST_SUITE_P(
    Cuda, CudaForces,
    ::testing::Values(
        ForceCase{ConstitutiveModel::kSvk, Formulation::kGradient, Assembly::kScatterAtomic},
        ForceCase{ConstitutiveModel::kSvk, Formulation::kGradient, Assembly::kScatterFixed},
        ForceCase{ConstitutiveModel::kSvk, Formulation::kGradient, Assembly::kGatherRecompute},
        ForceCase{ConstitutiveModel::kSvk, Formulation::kGradient, Assembly::kGatherStored},
        ForceCase{ConstitutiveModel::kSvk, Formulation::kTensorRebuilt, Assembly::kScatterAtomic},
        ForceCase{ConstitutiveModel::kSvk, Formulation::kTensorStored, Assembly::kScatterAtomic},
        ForceCase{ConstitutiveModel::kSvk, Formulation::kTensorStored, Assembly::kGatherStored},
        ForceCase{ConstitutiveModel::kLinear, Formulation::kGradient, Assembly::kScatterAtomic},
        ForceCase{ConstitutiveModel::kLinear, Formulation::kTensorRebuilt,
                  Assembly::kGatherRecompute},
        ForceCase{ConstitutiveModel::kLinear, Formulation::kTensorStored, Assembly::kScatterAtomic},
        ForceCase{ConstitutiveModel::kStableNeoHookean, Formulation::kGradient,
                  Assembly::kScatterAtomic},
        ForceCase{ConstitutiveModel::kStableNeoHookean, Formulation::kGradient,
                  Assembly::kScatterFixed},
        ForceCase{ConstitutiveModel::kStableNeoHookean, Formulation::kGradient,
                  Assembly::kGatherRecompute},
        ForceCase{ConstitutiveModel::kStableNeoHookean, Formulation::kGradient,
                  Assembly::kGatherStored}));

// The needle scenario: bottom cap fixed, a patch at the north pole pushed 1.5 um inwards over
// 1000 steps in 10 calls of 100 sub-steps.
struct NeedleRun {
  std::vector<Vec3d> u;
  Vec3d constraint_force{0, 0, 0};
  StepStatus status = kStepOk;
  int64_t steps = 0;
};

struct NeedleSetup {
  Model model;
  State state;
  std::vector<Vec3d> start;
  Vec3d push{0, 0, 0};
};

// `initial_strain` > 0 starts from a deformed, resting configuration (the patch held there).
NeedleSetup needle_setup(const Mesh& mesh, double initial_strain = 0,
                         ConstitutiveModel law = ConstitutiveModel::kSvk) {
  ModelDesc desc = cell_desc(law, Formulation::kGradient);
  const double r = 28e-6;
  for (size_t v = 0; v < mesh.vertex_count(); ++v)
    if (mesh.rest_positions[v].z < -0.85 * r) desc.fixed_vertices.push_back(int32_t(v));
  Result<Model> model = build_model(mesh, desc);
  EXPECT_TRUE(model.ok()) << (model ? "" : model.error().message);
  NeedleSetup s{std::move(model).value(), State{}, {}, Vec3d{0, 0, -1.5e-6}};
  s.state = make_state(s.model, 1);
  if (initial_strain > 0) {
    std::vector<Vec3d> u = test_displacement(s.model, initial_strain, 5);
    for (int32_t v : s.model.fixed_vertices) u[v] = Vec3d{0, 0, 0};
    set_displacement(s.state, u);
    s.push = Vec3d{0, 0, 0};
  }
  std::vector<int32_t> patch;
  for (size_t v = 0; v < mesh.vertex_count(); ++v)
    if (mesh.rest_positions[v].z > 0.9 * r) patch.push_back(int32_t(v));
  EXPECT_TRUE(set_prescribed_vertices(s.model, s.state, patch).ok());
  s.start.assign(s.state.prescribed_displacement.begin(), s.state.prescribed_displacement.end());
  return s;
}

NeedleRun run_needle(Backend& backend, NeedleSetup& s, int calls, int substeps) {
  NeedleRun run;
  EXPECT_TRUE(backend.upload(s.model, s.state).ok());
  std::vector<Vec3d> targets(s.start.size());
  for (int call = 0; call < calls; ++call) {
    const double frac = static_cast<double>(call + 1) / calls;
    for (size_t k = 0; k < targets.size(); ++k) targets[k] = s.start[k] + frac * s.push;
    EXPECT_TRUE(backend.set_prescribed_targets(targets).ok());
    const StepReport r = backend.step(substeps);
    run.status |= r.status;
    run.steps += r.steps;
    run.constraint_force = r.constraint_force;
  }
  State out = make_state(s.model, 1);
  out.u = poisoned(out.u.size());
  EXPECT_TRUE(backend.download(out).ok());
  run.u = out.u;
  return run;
}

TEST(CudaTrajectory, ThousandStepsMatchCpu) {
  BackendOptions options;
  options.poison_outputs = true;
  ZONA_CUDA_BACKEND_OR_SKIP(gpu, options);
  NeedleSetup s = needle_setup(small_cell());
  ASSERT_FALSE(s.start.empty());
  std::unique_ptr<Backend> cpu = make_cpu_backend(BackendOptions{});
  const NeedleRun a = run_needle(*cpu, s, 10, 100);
  const NeedleRun b = run_needle(*gpu, s, 10, 100);
  EXPECT_EQ(a.steps, 1000);
  EXPECT_EQ(b.steps, 1000);
  EXPECT_EQ(a.status, kStepOk);
  EXPECT_EQ(b.status, kStepOk);
  const double scale = max_norm(a.u);
  ASSERT_GT(scale, 1e-6);  // the patch moved 1.5 um
  std::printf(
      "[ measured ] 1000-step displacement error %.3g of max |u|, constraint force "
      "error %.3g\n",
      max_diff(a.u, b.u) / scale,
      norm(a.constraint_force - b.constraint_force) / norm(a.constraint_force));
  EXPECT_LE(max_diff(a.u, b.u), kTrajectoryTolerance * scale);
  ASSERT_GT(norm(a.constraint_force), 0);
  EXPECT_LE(norm(a.constraint_force - b.constraint_force),
            kConstraintForceTolerance * norm(a.constraint_force));
}

TEST(CudaGraph, OneWindowEqualsSingleSteps) {
  BackendOptions options;
  options.assembly = Assembly::kGatherStored;  // deterministic: the comparison can be bitwise
  ZONA_CUDA_BACKEND_OR_SKIP(gpu_window, options);
  ZONA_CUDA_BACKEND_OR_SKIP(gpu_single, options);
  // From a deformed state with the patch held: the window and the single steps then see
  // the same targets to the bit (a moving target is interpolated differently).
  NeedleSetup s = needle_setup(small_cell(), 0.02);
  // 1 call of 60 sub-steps against 60 calls of 1.
  const NeedleRun a = run_needle(*gpu_window, s, 1, 60);
  const NeedleRun b = run_needle(*gpu_single, s, 60, 1);
  ASSERT_EQ(a.steps, 60);
  ASSERT_EQ(b.steps, 60);
  ASSERT_EQ(a.u.size(), b.u.size());
  EXPECT_EQ(std::memcmp(a.u.data(), b.u.data(), a.u.size() * sizeof(Vec3d)), 0)
      << "max difference " << max_diff(a.u, b.u);
}

// Launching each kernel early (programmatic dependent launch) must not change a single bit:
// every kernel waits for its predecessor before reading what it wrote.
TEST(CudaGraph, ProgrammaticLaunchChangesNothing) {
  BackendOptions options;
  options.assembly = Assembly::kScatterFixed;
  options.programmatic_launch = true;
  ZONA_CUDA_BACKEND_OR_SKIP(early, options);
  options.programmatic_launch = false;
  ZONA_CUDA_BACKEND_OR_SKIP(plain, options);
  NeedleSetup s = needle_setup(small_cell());
  const NeedleRun a = run_needle(*early, s, 3, 40);
  const NeedleRun b = run_needle(*plain, s, 3, 40);
  ASSERT_EQ(a.u.size(), b.u.size());
  EXPECT_EQ(std::memcmp(a.u.data(), b.u.data(), a.u.size() * sizeof(Vec3d)), 0);
}

class CudaDeterministic : public ::testing::TestWithParam<Assembly> {};

TEST_P(CudaDeterministic, RunsAreBitwiseIdentical) {
  BackendOptions options;
  options.assembly = GetParam();
  ZONA_CUDA_BACKEND_OR_SKIP(gpu, options);
  NeedleSetup s = needle_setup(small_cell());
  const NeedleRun a = run_needle(*gpu, s, 4, 50);
  const NeedleRun b = run_needle(*gpu, s, 4, 50);
  ASSERT_EQ(a.u.size(), b.u.size());
  EXPECT_EQ(std::memcmp(a.u.data(), b.u.data(), a.u.size() * sizeof(Vec3d)), 0);
  EXPECT_EQ(std::memcmp(&a.constraint_force, &b.constraint_force, sizeof(Vec3d)), 0);
}

INSTANTIATE_TEST_SUITE_P(Cuda, CudaDeterministic,
                         ::testing::Values(Assembly::kScatterFixed, Assembly::kGatherRecompute,
                                           Assembly::kGatherStored));

TEST(CudaHealth, NonFiniteLoadStopsTheWindowAndKeepsTheState) {
  ZONA_CUDA_BACKEND_OR_SKIP(gpu, BackendOptions{});
  const Mesh mesh = small_cell();
  Result<Model> model =
      build_model(mesh, cell_desc(ConstitutiveModel::kSvk, Formulation::kGradient));
  ASSERT_TRUE(model.ok());
  State state = make_state(*model, 1);
  const std::vector<Vec3d> u0 = test_displacement(*model, 0.01, 3);
  set_displacement(state, u0);
  state.external_force[7] = Vec3d{std::numeric_limits<double>::infinity(), 0, 0};
  ASSERT_TRUE(gpu->upload(*model, state).ok());
  const StepReport r = gpu->step(10);
  EXPECT_TRUE(r.status & kStepNonFinite);
  EXPECT_EQ(r.steps, 0);
  State out = make_state(*model, 1);
  ASSERT_TRUE(gpu->download(out).ok());
  EXPECT_EQ(out.diag.first_nonfinite, 7);
  EXPECT_EQ(out.step_count, 0);
  EXPECT_EQ(max_diff(out.u, u0), 0.0);
}

// Nodal pressure with the fixed-point scatter: its per-vertex sums are integers too, so two runs
// are bitwise identical (float atomics made their last bits depend on the order). And a window
// halted by a non-finite load leaves the sums zero for the next one: after the load is taken
// away, the state steps exactly as a backend that never saw it.
TEST(CudaNodal, FixedPointRunsAreBitwiseIdenticalAndAHaltLeavesNoSums) {
  BackendOptions options;
  options.assembly = Assembly::kScatterFixed;
  ZONA_CUDA_BACKEND_OR_SKIP(gpu, options);
  ZONA_CUDA_BACKEND_OR_SKIP(fresh, options);
  const Mesh mesh = small_cell();
  ModelDesc desc = cell_desc(ConstitutiveModel::kStableNeoHookean, Formulation::kGradient);
  desc.nodal_pressure = true;
  Result<Model> model = build_model(mesh, desc);
  ASSERT_TRUE(model.ok()) << model.error().message;
  const std::vector<Vec3d> u0 = test_displacement(*model, 0.01, 3);
  auto run = [&](Backend& b, bool poisoned) {
    State state = make_state(*model, 1);
    set_displacement(state, u0);
    EXPECT_TRUE(b.upload(*model, state).ok());
    if (poisoned) {
      std::vector<Vec3d> bad(model->vertex_count(), Vec3d{0, 0, 0});
      bad[7] = Vec3d{std::numeric_limits<double>::infinity(), 0, 0};
      EXPECT_TRUE(b.set_external_forces(bad).ok());
      EXPECT_TRUE(b.step(10).status & kStepNonFinite);
      EXPECT_TRUE(b.set_external_forces(std::vector<Vec3d>(model->vertex_count())).ok());
    }
    const StepReport r = b.step(40);
    EXPECT_EQ(r.steps, 40);
    State out = make_state(*model, 1);
    EXPECT_TRUE(b.download(out).ok());
    return out.u;
  };
  const std::vector<Vec3d> a = run(*fresh, false), b = run(*fresh, false);
  ASSERT_EQ(a.size(), b.size());
  EXPECT_EQ(std::memcmp(a.data(), b.data(), a.size() * sizeof(Vec3d)), 0);
  EXPECT_GT(max_diff(a, u0), 0.0);  // it moved
  const std::vector<Vec3d> c = run(*gpu, true);
  EXPECT_EQ(std::memcmp(a.data(), c.data(), a.size() * sizeof(Vec3d)), 0);
}

// Loads set between steps (Backend::set_external_forces) act as loads given at upload: the
// first set allocates the array and recaptures the step graphs, later sets only copy.
TEST(CudaLoads, SetExternalForcesEqualsUploadingThem) {
  BackendOptions options;
  options.assembly = Assembly::kScatterFixed;  // bitwise reproducible
  ZONA_CUDA_BACKEND_OR_SKIP(a, options);
  ZONA_CUDA_BACKEND_OR_SKIP(b, options);
  const Mesh mesh = small_cell();
  Result<Model> model =
      build_model(mesh, cell_desc(ConstitutiveModel::kSvk, Formulation::kGradient));
  ASSERT_TRUE(model.ok());
  State loaded = make_state(*model, 1);
  for (size_t v = 0; v < loaded.external_force.size(); ++v)
    loaded.external_force[v] = Vec3d{1e-9, -2e-9, 0.5e-9} * (1.0 + 0.01 * double(v % 7));
  State bare = make_state(*model, 1);
  ASSERT_TRUE(a->upload(*model, loaded).ok());
  ASSERT_TRUE(b->upload(*model, bare).ok());
  ASSERT_EQ(b->step(5).steps, 5);  // graphs captured without loads
  ASSERT_TRUE(a->upload(*model, loaded).ok());
  ASSERT_TRUE(b->upload(*model, bare).ok());
  ASSERT_TRUE(b->set_external_forces(loaded.external_force).ok());
  ASSERT_EQ(a->step(100).steps, 100);
  ASSERT_EQ(b->step(100).steps, 100);
  State out_a = make_state(*model, 1), out_b = make_state(*model, 1);
  ASSERT_TRUE(a->download(out_a).ok());
  ASSERT_TRUE(b->download(out_b).ok());
  EXPECT_GT(max_norm(out_a.u), 0.0);
  EXPECT_EQ(max_diff(out_a.u, out_b.u), 0.0);
  // Loads removed on one, kept on the other: the runs part.
  std::vector<Vec3d> none(model->vertex_count(), Vec3d{0, 0, 0});
  ASSERT_TRUE(b->set_external_forces(none).ok());
  ASSERT_EQ(a->step(50).steps, 50);
  ASSERT_EQ(b->step(50).steps, 50);
  ASSERT_TRUE(a->download(out_a).ok());
  ASSERT_TRUE(b->download(out_b).ok());
  EXPECT_GT(max_diff(out_a.u, out_b.u), 1e-3 * max_norm(out_a.u));
  EXPECT_FALSE(b->set_external_forces(std::vector<Vec3d>(3)).ok());
}

TEST(CudaHealth, InvertedElementIsFlaggedLikeOnTheCpu) {
  ZONA_CUDA_BACKEND_OR_SKIP(gpu, BackendOptions{});
  const Mesh mesh = small_cell();
  Result<Model> model =
      build_model(mesh, cell_desc(ConstitutiveModel::kSvk, Formulation::kGradient));
  ASSERT_TRUE(model.ok());
  State state = make_state(*model, 1);
  // Push one corner of tetrahedron 0 through its opposite face.
  std::vector<Vec3d> u(model->vertex_count(), Vec3d{0, 0, 0});
  const Tet& t = model->tets[0];
  const Vec3d face_centre =
      (model->rest_positions[t[1]] + model->rest_positions[t[2]] + model->rest_positions[t[3]]) /
      3.0;
  u[t[0]] = 2.0 * (face_centre - model->rest_positions[t[0]]);
  set_displacement(state, u);
  std::unique_ptr<Backend> cpu = make_cpu_backend(BackendOptions{});
  ASSERT_TRUE(cpu->upload(*model, state).ok());
  ASSERT_TRUE(gpu->upload(*model, state).ok());
  const StepReport rc = cpu->step(1);
  const StepReport rg = gpu->step(1);
  EXPECT_TRUE(rc.status & kStepInvertedElement);
  EXPECT_TRUE(rg.status & kStepInvertedElement);
  State a = make_state(*model, 1), b = make_state(*model, 1);
  ASSERT_TRUE(cpu->download(a).ok());
  ASSERT_TRUE(gpu->download(b).ok());
  EXPECT_EQ(b.diag.inverted_count, a.diag.inverted_count);
  EXPECT_EQ(b.diag.first_inverted, a.diag.first_inverted);
}

// Stable neo-Hookean where SVK gives way: strongly compressed and inverted elements (a corner
// of every tenth tetrahedron pushed through its opposite face). Forces match the CPU's, and the
// inversion is flagged alike (informational for this law: the step goes on).
TEST(CudaNeoHookean, CompressedAndInvertedElementsMatchCpu) {
  BackendOptions options;
  options.poison_outputs = true;
  ZONA_CUDA_BACKEND_OR_SKIP(gpu, options);
  const Mesh mesh = small_cell();
  Result<Model> model =
      build_model(mesh, cell_desc(ConstitutiveModel::kStableNeoHookean, Formulation::kGradient));
  ASSERT_TRUE(model.ok()) << model.error().message;
  std::vector<Vec3d> u = test_displacement(*model, 0.05, 4);
  std::vector<uint8_t> moved(model->vertex_count(), 0);
  for (size_t k = 0; k < model->tet_count(); k += 10) {
    const Tet& t = model->tets[k];
    if (moved[t[0]] || moved[t[1]] || moved[t[2]] || moved[t[3]]) continue;
    const Vec3d face_centre =
        (model->rest_positions[t[1]] + model->rest_positions[t[2]] + model->rest_positions[t[3]]) /
        3.0;
    u[t[0]] = 1.6 * (face_centre - model->rest_positions[t[0]]);
    for (int c = 0; c < 4; ++c) moved[t[c]] = 1;
  }
  State state = make_state(*model, 1);
  set_displacement(state, u);
  std::unique_ptr<Backend> cpu = make_cpu_backend(BackendOptions{});
  ASSERT_TRUE(cpu->upload(*model, state).ok());
  const Status up = gpu->upload(*model, state);
  ASSERT_TRUE(up.ok()) << up.error().message;
  std::vector<Vec3d> f_cpu = poisoned(u.size()), f_gpu = poisoned(u.size());
  ASSERT_TRUE(cpu->elastic_forces(u, f_cpu).ok());
  ASSERT_TRUE(gpu->elastic_forces(u, f_gpu).ok());
  for (const Vec3d& f : f_gpu) ASSERT_TRUE(std::isfinite(f.x + f.y + f.z));
  const double error = max_diff(f_cpu, f_gpu) / max_norm(f_cpu);
  std::printf("[ measured ] neohookean inverted-field force error %.3g of max |f|\n", error);
  EXPECT_LE(error, kForceTolerance);
  const StepReport rc = cpu->step(1);
  const StepReport rg = gpu->step(1);
  EXPECT_TRUE(rc.status & kStepInvertedElement);
  EXPECT_TRUE(rg.status & kStepInvertedElement);
  EXPECT_FALSE((rc.status | rg.status) & kStepNotAdvanced);
  EXPECT_EQ(rg.steps, 1);
  State a = make_state(*model, 1), b = make_state(*model, 1);
  ASSERT_TRUE(cpu->download(a).ok());
  ASSERT_TRUE(gpu->download(b).ok());
  EXPECT_GT(a.diag.inverted_count, 10);
  EXPECT_EQ(b.diag.inverted_count, a.diag.inverted_count);
  EXPECT_EQ(b.diag.first_inverted, a.diag.first_inverted);
  EXPECT_NE(gpu->description().find("neohookean/gradient"), std::string::npos)
      << gpu->description();
}

// The law with nodal pressure (ModelDesc::nodal_pressure), with the stabilisation beta
// (ModelDesc::nodal_stabilisation: beta lambda kept in each element, lambda_v carrying 1 - beta):
// the device's first pass (volume changes summed at the vertices by float atomics) and element
// pass against the CPU's, forces and energy, and again after a step (the sums are zeroed
// between steps).
void check_nodal_pressure_against_cpu(double stabilisation) {
  BackendOptions options;
  options.poison_outputs = true;
  ZONA_CUDA_BACKEND_OR_SKIP(gpu, options);
  ModelDesc desc = cell_desc(ConstitutiveModel::kStableNeoHookean, Formulation::kGradient);
  desc.nodal_pressure = true;
  desc.nodal_stabilisation = stabilisation;
  Result<Model> model = build_model(small_cell(), desc);
  ASSERT_TRUE(model.ok()) << model.error().message;
  const std::vector<Vec3d> u = test_displacement(*model, 0.05, 7);
  State state = make_state(*model, 1);
  set_displacement(state, u);
  std::unique_ptr<Backend> cpu = make_cpu_backend(BackendOptions{});
  ASSERT_TRUE(cpu->upload(*model, state).ok());
  const Status up = gpu->upload(*model, state);
  ASSERT_TRUE(up.ok()) << up.error().message;
  for (int round = 0; round < 2; ++round) {
    std::vector<Vec3d> f_cpu = poisoned(u.size()), f_gpu = poisoned(u.size());
    ASSERT_TRUE(cpu->elastic_forces(u, f_cpu).ok());
    ASSERT_TRUE(gpu->elastic_forces(u, f_gpu).ok());
    const double error = max_diff(f_cpu, f_gpu) / max_norm(f_cpu);
    std::printf("[ measured ] nodal-pressure (beta %g) force error %.3g of max |f| (round %d)\n",
                stabilisation, error, round);
    EXPECT_LE(error, kForceTolerance) << "round " << round;
    const StepReport rc = cpu->step(3);
    const StepReport rg = gpu->step(3);
    ASSERT_EQ(rc.steps, 3);
    ASSERT_EQ(rg.steps, 3);
    State a = make_state(*model, 1), b = make_state(*model, 1);
    ASSERT_TRUE(cpu->download(a).ok());
    ASSERT_TRUE(gpu->download(b).ok());
    ASSERT_GT(a.diag.elastic_energy, 0);
    EXPECT_NEAR(b.diag.elastic_energy, a.diag.elastic_energy, 1e-4 * a.diag.elastic_energy);
    EXPECT_LE(max_diff(a.u, b.u), kTrajectoryTolerance * max_norm(a.u));
  }
}

TEST(CudaNeoHookean, NodalPressureMatchesCpu) { check_nodal_pressure_against_cpu(0.0); }

// The stabilisation moves a part of the stiffness from the vertices into the elements: the
// device's element pass must take it (a kernel that ignored beta would carry only 1 - beta of
// the volumetric stiffness and miss the CPU's forces by about beta of their volumetric part).
TEST(CudaNeoHookean, NodalStabilisationMatchesCpu) { check_nodal_pressure_against_cpu(0.3); }

TEST(CudaNeoHookean, TensorFormulationIsRefused) {
  BackendOptions options;
  options.formulation = static_cast<int32_t>(Formulation::kTensorStored);
  ZONA_CUDA_BACKEND_OR_SKIP(gpu, options);
  Result<Model> model = build_model(
      small_cell(), cell_desc(ConstitutiveModel::kStableNeoHookean, Formulation::kGradient));
  ASSERT_TRUE(model.ok());
  const Status s = gpu->upload(*model, make_state(*model, 1));
  ASSERT_FALSE(s.ok());
  EXPECT_NE(s.error().message.find("no mass-tensor form"), std::string::npos) << s.error().message;
}

TEST(CudaNeoHookean, ThousandStepsMatchCpu) {
  BackendOptions options;
  options.poison_outputs = true;
  ZONA_CUDA_BACKEND_OR_SKIP(gpu, options);
  NeedleSetup s = needle_setup(small_cell(), 0, ConstitutiveModel::kStableNeoHookean);
  ASSERT_FALSE(s.start.empty());
  std::unique_ptr<Backend> cpu = make_cpu_backend(BackendOptions{});
  const NeedleRun a = run_needle(*cpu, s, 10, 100);
  const NeedleRun b = run_needle(*gpu, s, 10, 100);
  EXPECT_EQ(a.steps, 1000);
  EXPECT_EQ(b.steps, 1000);
  EXPECT_EQ(a.status, kStepOk);
  EXPECT_EQ(b.status, kStepOk);
  const double scale = max_norm(a.u);
  ASSERT_GT(scale, 1e-6);
  std::printf("[ measured ] neohookean 1000-step displacement error %.3g of max |u|\n",
              max_diff(a.u, b.u) / scale);
  EXPECT_LE(max_diff(a.u, b.u), kTrajectoryTolerance * scale);
  ASSERT_GT(norm(a.constraint_force), 0);
  EXPECT_LE(norm(a.constraint_force - b.constraint_force),
            kConstraintForceTolerance * norm(a.constraint_force));
}

TEST(CudaSummary, MatchesCpu) {
  ZONA_CUDA_BACKEND_OR_SKIP(gpu, BackendOptions{});
  NeedleSetup s = needle_setup(small_cell());
  std::unique_ptr<Backend> cpu = make_cpu_backend(BackendOptions{});
  run_needle(*cpu, s, 2, 50);
  run_needle(*gpu, s, 2, 50);
  Result<StateSummary> a = cpu->summarize(), b = gpu->summarize();
  ASSERT_TRUE(a.ok());
  ASSERT_TRUE(b.ok()) << b.error().message;
  EXPECT_NEAR(b->max_displacement, a->max_displacement, 1e-4 * a->max_displacement);
  EXPECT_NEAR(b->kinetic_energy, a->kinetic_energy, 5e-3 * a->kinetic_energy);
}

}  // namespace
}  // namespace zona
