// Tests of the scaling benchmark's pieces and of a run on a tiny mesh: argument parsing, the
// seed's sizes, the CSV's columns and values, hash determinism. No timing assertions.
#include "bench/scaling/scaling_bench.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <map>
#include <sstream>
#include <string>
#include <vector>

#include "engine/sim/backend_cpu.h"
#include "engine/mesh/mesh_generate.h"
#include "kernels/backend_factory.h"

namespace zona {
namespace {

std::vector<std::string> split(const std::string& line, char sep = ',') {
  std::vector<std::string> out;
  std::stringstream ss(line);
  std::string cell;
  while (std::getline(ss, cell, sep)) out.push_back(cell);
  return out;
}

// A run on one tiny mesh through the real CPU backend (factory as the CLI uses it).
ScalingBenchConfig tiny_config() {
  ScalingBenchConfig c;
  c.vertices = {150};
  c.steps = 3;
  c.repeats = 2;
  c.precompute_repeats = 1;
  c.threads = {1};
  c.copy_bytes = size_t{4} << 20;
  return c;
}

ScalingBenchHooks cpu_hooks() {
  ScalingBenchHooks h;
  h.make_backend = [](BackendKind kind, const BackendOptions& options) {
    return make_backend(kind, options);
  };
  return h;
}

bool one_line(const std::string& s) { return !s.empty() && s.find('\n') == std::string::npos; }

TEST(ScalingBench, Table2ListHasTheSeedsTwelveSizes) {
  Result<std::vector<int64_t>> sizes = parse_vertex_list("table2", 1000000);
  ASSERT_TRUE(sizes.ok());
  ASSERT_EQ(sizes->size(), 12u);
  EXPECT_EQ(sizes->front(), 115);
  EXPECT_EQ(sizes->back(), 1093);
  EXPECT_TRUE(std::is_sorted(sizes->begin(), sizes->end()));
  ASSERT_EQ(seed_table2().size(), 12u);
  for (size_t i = 0; i < 12; ++i) {
    EXPECT_EQ((*sizes)[i], seed_table2()[i].vertices);
    // The seed's step time grows with size; its tetrahedra are 3-4.5 per vertex.
    EXPECT_GT(seed_table2()[i].tets, 2 * seed_table2()[i].vertices);
  }
  EXPECT_DOUBLE_EQ(seed_table2().back().precompute_ms, 88.734);
  EXPECT_DOUBLE_EQ(seed_table2().back().step_ms, 0.703);
}

TEST(ScalingBench, SweepIsPowersOfTwoUpToTheCap) {
  Result<std::vector<int64_t>> sizes = parse_vertex_list("sweep", 1000000);
  ASSERT_TRUE(sizes.ok());
  EXPECT_EQ(sizes->front(), 128);
  EXPECT_EQ(sizes->back(), 524288);
  for (size_t i = 1; i < sizes->size(); ++i) EXPECT_EQ((*sizes)[i], 2 * (*sizes)[i - 1]);
  EXPECT_FALSE(parse_vertex_list("sweep", 100).ok());
}

TEST(ScalingBench, VertexListAcceptsCountsAndScientificNotation) {
  Result<std::vector<int64_t>> sizes = parse_vertex_list("1093, 1e4,2.5e5", 1000000);
  ASSERT_TRUE(sizes.ok()) << sizes.error().message;
  EXPECT_EQ(*sizes, (std::vector<int64_t>{1093, 10000, 250000}));
}

TEST(ScalingBench, BadArgumentsAreRefusedWithOneLineNamingTheEntry) {
  struct Case {
    std::string text;
    std::string named;
  };
  for (const Case& c : {Case{"abc", "abc"}, Case{"1000,x1", "x1"}, Case{"50", "50"},
                        Case{"1e3.5", "1e3.5"}, Case{"1000,,2000", "--vertices"},
                        Case{"2e6", "2e6"}, Case{"-5", "-5"}, Case{"1.5", "1.5"}}) {
    Result<std::vector<int64_t>> r = parse_vertex_list(c.text, 1000000);
    ASSERT_FALSE(r.ok()) << c.text;
    EXPECT_TRUE(one_line(r.error().message)) << r.error().message;
    EXPECT_NE(r.error().message.find(c.named), std::string::npos) << r.error().message;
  }
  Result<std::vector<BackendKind>> b = parse_bench_backends("gpu");
  ASSERT_FALSE(b.ok());
  EXPECT_TRUE(one_line(b.error().message));
  EXPECT_NE(b.error().message.find("gpu"), std::string::npos);
  Result<std::vector<ConstitutiveModel>> m = parse_bench_models("neo_hookean");
  ASSERT_FALSE(m.ok());
  EXPECT_NE(m.error().message.find("neo_hookean"), std::string::npos);
  Result<std::vector<Formulation>> f = parse_bench_formulations("gradient,tensor");
  ASSERT_FALSE(f.ok());
  EXPECT_NE(f.error().message.find("'tensor'"), std::string::npos);
  EXPECT_FALSE(parse_thread_list("two").ok());
  EXPECT_FALSE(parse_thread_list("1,").ok());

  // Lists and "all" expand without duplicates.
  EXPECT_EQ(parse_bench_formulations("all")->size(), 3u);
  EXPECT_EQ(parse_bench_formulations("gradient,gradient")->size(), 1u);
  EXPECT_EQ(parse_bench_models("all")->size(), 2u);
  EXPECT_EQ(parse_bench_backends("all")->size(), 2u);
  EXPECT_EQ(*parse_thread_list("1,2"), (std::vector<int>{1, 2}));
}

TEST(ScalingBench, RunRefusesBadConfigurationsBeforeMeasuring) {
  ScalingBenchConfig c = tiny_config();
  c.repeats = 0;
  Result<ScalingBenchResult> r = run_scaling_bench(c, cpu_hooks(), local_machine_info());
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.error().message.find("--repeats"), std::string::npos);
  c = tiny_config();
  c.vertices.clear();
  EXPECT_FALSE(run_scaling_bench(c, cpu_hooks(), local_machine_info()).ok());
  c = tiny_config();
  EXPECT_FALSE(run_scaling_bench(c, ScalingBenchHooks{}, local_machine_info()).ok());
}

TEST(ScalingBench, HashIsFnv1aOfTheBitPatterns) {
  // Empty input: the FNV-1a offset basis.
  EXPECT_EQ(displacement_hash({}), 14695981039346656037ull);
  std::vector<Vec3d> u = {{1e-7, -2e-7, 3e-7}, {0, 0, 0}};
  const uint64_t h = displacement_hash(u);
  EXPECT_EQ(displacement_hash(u), h);
  // One ulp in one coordinate changes it; so does the sign of a zero.
  std::vector<Vec3d> v = u;
  v[1].y = std::nextafter(0.0, 1.0);
  EXPECT_NE(displacement_hash(v), h);
  v = u;
  v[1].z = -0.0;
  EXPECT_NE(displacement_hash(v), h);
  // Order matters.
  std::swap(v[0], v[1]);
  EXPECT_NE(displacement_hash(v), h);
}

TEST(ScalingBench, LoadedStateIsNonTrivialAndZeroOnTheHeldCap) {
  Result<Mesh> mesh = generate_cell_mesh(table2_spec(150));
  ASSERT_TRUE(mesh.ok());
  const std::vector<Vec3d> u = bench_displacement(*mesh);
  const std::vector<int32_t> fixed = bench_fixed_vertices(*mesh);
  ASSERT_FALSE(fixed.empty());
  ASSERT_LT(fixed.size(), mesh->vertex_count() / 4);
  for (int32_t v : fixed) EXPECT_EQ(norm(u[static_cast<size_t>(v)]), 0.0);
  const Aabb box = mesh_bounds(*mesh);
  const double r = 0.5 * (box.hi.z - box.lo.z);
  double max_u = 0;
  size_t moved = 0;
  for (const Vec3d& d : u) {
    max_u = std::max(max_u, norm(d));
    moved += norm(d) > 0;
  }
  // The top is indented by about 2 % of the radius; most vertices move.
  EXPECT_GT(max_u, 0.01 * r);
  EXPECT_LT(max_u, 0.05 * r);
  EXPECT_GT(moved, mesh->vertex_count() / 2);
}

TEST(ScalingBench, BytesPerStepFollowTheFormulationAndSize) {
  const auto cpu = BackendKind::kCpu;
  const auto svk = ConstitutiveModel::kSvk;
  const Assembly a = BackendOptions{}.assembly;
  const double g = step_bytes(cpu, svk, Formulation::kGradient, a, 1000, 5000);
  const double s = step_bytes(cpu, svk, Formulation::kTensorStored, a, 1000, 5000);
  const double l = step_bytes(cpu, ConstitutiveModel::kLinear, Formulation::kTensorStored, a,
                              1000, 5000);
  EXPECT_GT(g, 0);
  // Stored SVK tensors: 592 doubles per tetrahedron on top of the rest.
  EXPECT_NEAR(s - g, 5000.0 * (8 * kSvkTensorSize + 13 * 8 - 12 * 8), 1e-6);
  EXPECT_GT(s, l);
  EXPECT_GT(l, g);
  // Linear in the mesh size.
  EXPECT_DOUBLE_EQ(step_bytes(cpu, svk, Formulation::kGradient, a, 2000, 10000), 2 * g);
  // The GPU's float32 layout moves fewer bytes than the CPU's float64 one.
  EXPECT_LT(step_bytes(BackendKind::kCuda, svk, Formulation::kGradient, a, 1000, 5000), g);
  // Automatic steps: fewer for larger meshes and for the tensor forms, within the limits.
  EXPECT_EQ(auto_steps(cpu, svk, Formulation::kGradient, 1000, 5000), 1000);
  EXPECT_GT(auto_steps(cpu, svk, Formulation::kGradient, 100000, 600000),
            auto_steps(cpu, svk, Formulation::kTensorStored, 100000, 600000));
  EXPECT_EQ(auto_steps(cpu, svk, Formulation::kGradient, 100000000, 600000000), 1);
  EXPECT_EQ(auto_steps(BackendKind::kCuda, svk, Formulation::kGradient, 100000000, 600000000),
            10);
  // Memory: the stored SVK tensors dominate, and the sweep's top grows with the memory.
  EXPECT_GT(estimate_row_bytes(cpu, svk, Formulation::kTensorStored, 1000, 6000),
            5 * estimate_row_bytes(cpu, svk, Formulation::kGradient, 1000, 6000));
  ScalingBenchConfig c;
  EXPECT_EQ(memory_fit_vertices(c, 1.0), 128);
  EXPECT_GT(memory_fit_vertices(c, 64e9), memory_fit_vertices(c, 4e9));
}

TEST(ScalingBench, TinyRunWritesTheRequiredColumnsWithSaneValues) {
  ScalingBenchConfig c = tiny_config();
  c.formulations = {Formulation::kGradient, Formulation::kTensorStored};
  std::vector<ScalingRow> streamed;
  bool started = false;
  ScalingBenchHooks h = cpu_hooks();
  h.started = [&](const ScalingBenchResult& r) {
    started = true;
    EXPECT_EQ(r.cpu_copy_gb_per_s.size(), 1u);
    EXPECT_TRUE(streamed.empty());
  };
  h.row = [&](const ScalingRow& r) { streamed.push_back(r); };
  Result<ScalingBenchResult> r = run_scaling_bench(c, h, local_machine_info());
  ASSERT_TRUE(r.ok()) << r.error().message;
  EXPECT_TRUE(started);
  ASSERT_EQ(r->rows.size(), 2u);
  ASSERT_EQ(streamed.size(), 2u);

  // Header: the columns, and the comment lines name the machine and the date.
  const std::vector<std::string> columns = split(scaling_csv_header());
  for (const char* need :
       {"backend", "model", "formulation", "vertices", "tets", "precompute_ms", "step_ms_median",
        "step_ms_p90", "steps_per_s", "bytes_per_step", "gb_per_s", "floor_ms", "state_hash"})
    EXPECT_NE(std::find(columns.begin(), columns.end(), need), columns.end()) << need;
  const std::string comments = scaling_csv_comments(*r, c);
  EXPECT_NE(comments.find("# cpu: "), std::string::npos);
  EXPECT_NE(comments.find("# date: "), std::string::npos);
  EXPECT_NE(comments.find("copy bandwidth"), std::string::npos);
  for (const std::string& line : split(comments, '\n')) EXPECT_EQ(line.rfind("# ", 0), 0u) << line;

  for (const ScalingRow& row : r->rows) {
    const std::vector<std::string> cells = split(scaling_csv_row(row));
    ASSERT_EQ(cells.size(), columns.size());
    std::map<std::string, std::string> at;
    for (size_t i = 0; i < cells.size(); ++i) at[columns[i]] = cells[i];
    EXPECT_EQ(at["backend"], "cpu");
    EXPECT_EQ(at["model"], "svk");
    EXPECT_EQ(at["threads"], "1");
    EXPECT_EQ(at["target_vertices"], "150");
    // table2_spec: within 10 % of the count asked.
    EXPECT_NEAR(std::stod(at["vertices"]), 150, 15);
    EXPECT_GT(std::stod(at["tets"]), 2 * std::stod(at["vertices"]));
    EXPECT_GT(std::stod(at["precompute_ms"]), 0);
    EXPECT_GT(std::stod(at["step_ms_median"]), 0);
    EXPECT_GE(std::stod(at["step_ms_p90"]), std::stod(at["step_ms_median"]));
    EXPECT_LE(std::stod(at["step_ms_p10"]), std::stod(at["step_ms_median"]));
    EXPECT_GT(std::stod(at["steps_per_s"]), 0);
    EXPECT_GT(std::stod(at["bytes_per_step"]), 0);
    EXPECT_GT(std::stod(at["gb_per_s"]), 0);
    EXPECT_GT(std::stod(at["copy_gb_per_s"]), 0);
    EXPECT_GT(std::stod(at["floor_ms"]), 0);
    EXPECT_EQ(at["steps"], "3");
    EXPECT_EQ(at["repeats"], "2");
    EXPECT_EQ(at["status"], "ok");
    EXPECT_EQ(at["state_hash"].size(), 16u);
  }
  EXPECT_EQ(r->rows[0].formulation, "gradient");
  EXPECT_EQ(r->rows[1].formulation, "tensor_stored");
  EXPECT_EQ(r->rows[0].tensor_precompute_ms, 0.0);
  EXPECT_GT(r->rows[1].tensor_precompute_ms, 0.0);
  EXPECT_GT(r->rows[1].bytes_per_step, r->rows[0].bytes_per_step);
  // The same mesh for both rows.
  EXPECT_EQ(r->rows[0].vertices, r->rows[1].vertices);
  EXPECT_EQ(r->rows[0].tets, r->rows[1].tets);
}

TEST(ScalingBench, HashIsDeterministicAcrossRunsAndThreadCounts) {
  ScalingBenchConfig c = tiny_config();
  c.threads = {1, 2};
  Result<ScalingBenchResult> a = run_scaling_bench(c, cpu_hooks(), local_machine_info());
  Result<ScalingBenchResult> b = run_scaling_bench(c, cpu_hooks(), local_machine_info());
  ASSERT_TRUE(a.ok() && b.ok());
  ASSERT_EQ(a->rows.size(), 2u);
  ASSERT_EQ(b->rows.size(), 2u);
  EXPECT_EQ(a->rows[0].threads, 1);
  EXPECT_EQ(a->rows[1].threads, 2);
  // The CPU reference gives the same bits on every run and thread count.
  EXPECT_EQ(a->rows[0].state_hash, b->rows[0].state_hash);
  EXPECT_EQ(a->rows[0].state_hash, a->rows[1].state_hash);
  EXPECT_EQ(a->rows[1].state_hash, b->rows[1].state_hash);
  // The state moved away from the loaded field: the hash is not that of the initial state.
  Result<Mesh> mesh = generate_cell_mesh(table2_spec(150));
  ASSERT_TRUE(mesh.ok());
  EXPECT_NE(a->rows[0].state_hash, displacement_hash(bench_displacement(*mesh)));
  // The backend's automatic thread count (one per ~2000 tetrahedra): 1 on this tiny mesh.
  c.threads = {0};
  Result<ScalingBenchResult> e = run_scaling_bench(c, cpu_hooks(), local_machine_info());
  ASSERT_TRUE(e.ok());
  EXPECT_EQ(e->rows[0].threads_requested, 0);
  EXPECT_EQ(e->rows[0].threads, 1);
  EXPECT_EQ(e->rows[0].state_hash, a->rows[0].state_hash);
  // More steps, another state.
  c.threads = {1};
  c.steps = 4;
  Result<ScalingBenchResult> d = run_scaling_bench(c, cpu_hooks(), local_machine_info());
  ASSERT_TRUE(d.ok());
  EXPECT_NE(d->rows[0].state_hash, a->rows[0].state_hash);
}

TEST(ScalingBench, UnavailableBackendIsOneNoticeWhenSkippingElseAnError) {
  ScalingBenchConfig c = tiny_config();
  c.backends = {BackendKind::kCpu, BackendKind::kCuda};
  ScalingBenchHooks h;
  h.make_backend = [](BackendKind kind,
                      const BackendOptions& options) -> Result<std::unique_ptr<Backend>> {
    if (kind == BackendKind::kCuda) return make_error("built without CUDA");
    return make_cpu_backend(options);
  };
  std::vector<std::string> notices;
  h.notice = [&](const std::string& n) { notices.push_back(n); };
  Result<ScalingBenchResult> strict = run_scaling_bench(c, h, local_machine_info());
  ASSERT_FALSE(strict.ok());
  EXPECT_NE(strict.error().message.find("cuda: built without CUDA"), std::string::npos);

  c.skip_unavailable_backends = true;
  Result<ScalingBenchResult> r = run_scaling_bench(c, h, local_machine_info());
  ASSERT_TRUE(r.ok()) << r.error().message;
  ASSERT_EQ(notices.size(), 1u);
  EXPECT_NE(notices[0].find("cuda"), std::string::npos);
  ASSERT_EQ(r->rows.size(), 1u);
  EXPECT_EQ(r->rows[0].backend, "cpu");
}

TEST(ScalingBench, RowsThatDoNotFitInMemoryAreSkippedWithANotice) {
  ScalingBenchConfig c = tiny_config();
  c.memory_limit_bytes = 1000;  // nothing fits
  std::vector<std::string> notices;
  ScalingBenchHooks h = cpu_hooks();
  h.notice = [&](const std::string& n) { notices.push_back(n); };
  Result<ScalingBenchResult> r = run_scaling_bench(c, h, local_machine_info());
  ASSERT_TRUE(r.ok());
  EXPECT_TRUE(r->rows.empty());
  ASSERT_EQ(notices.size(), 1u);
  EXPECT_NE(notices[0].find("skipped"), std::string::npos);
}

}  // namespace
}  // namespace zona
