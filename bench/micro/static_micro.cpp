// Micro-benchmarks of the static solver's inner loop: the product of the assembled Newton
// Hessian (block_sparse.h: 3 x 3 blocks plus nodal pressure's rank-one vertex terms) with a
// vector, which CG calls once per iteration, and the Hessian's assembly, once per Newton
// iteration. Stable neo-Hookean with nodal pressure (the mouse scenes' law) on the scaling
// benchmark's meshes, at its displacement field. Arguments: vertices; for the assembly, the
// exact Hessian (0, Newton's first try) or the projected one (1).
//
// The product's floor: it must read the blocks (72 B + a 4 B column each), the rank-one
// vectors (24 B + a 4 B vertex each, twice: the dots and the rows), and write y; the
// counter `bytes_per_second` is that traffic over the time, to set against the machine's
// bandwidth (at 6k-10k vertices the matrix fits in the last-level cache).
#include <benchmark/benchmark.h>

#include "bench/micro/micro_meshes.h"
#include "engine/core/parallel.h"
#include "engine/fem/elastic_energy.h"
#include "engine/solver/multigrid.h"

namespace zona::micro {
namespace {

struct Assembled {
  Loaded loaded;
  std::unique_ptr<ElasticEnergy> energy;
  std::unique_ptr<BlockSparseMatrix> h;
  std::vector<Vec3d> u;
};

Assembled& assembled(int64_t vertices) {
  static std::map<int64_t, std::unique_ptr<Assembled>> cache;
  std::unique_ptr<Assembled>& slot = cache[vertices];
  if (slot) return *slot;
  const Mesh& mesh = cached_mesh(vertices);
  ModelDesc desc = bench_model_desc(mesh, ConstitutiveModel::kStableNeoHookean,
                                    Formulation::kGradient, 0);
  desc.nodal_pressure = true;
  Result<Model> model = build_model(mesh, desc);
  if (!model) die(model.error().message);
  slot = std::make_unique<Assembled>();
  slot->loaded.model = std::make_unique<Model>(std::move(model).value());
  Result<ElasticEnergy> energy = ElasticEnergy::create(*slot->loaded.model);
  if (!energy) die(energy.error().message);
  slot->energy = std::make_unique<ElasticEnergy>(std::move(energy).value());
  slot->h = std::make_unique<BlockSparseMatrix>(
      ElasticEnergy::hessian_pattern(*slot->loaded.model));
  slot->u = bench_displacement(mesh);
  slot->h->set_zero();
  slot->energy->add_hessian(slot->u, *slot->h, true);
  return *slot;
}

void BM_HessianProduct(benchmark::State& s) {
  Assembled& a = assembled(s.range(0));
  const BlockSparseMatrix& h = *a.h;
  const size_t n = h.rows();
  std::vector<Vec3d> x(n), y(n);
  for (size_t i = 0; i < n; ++i)
    x[i] = Vec3d{1.0 + 1e-3 * static_cast<double>(i % 7), -0.5, 0.25};
  for (auto _ : s) {
    h.multiply(x, y);
    benchmark::DoNotOptimize(y.data());
  }
  const double blocks = static_cast<double>(h.cols().size());
  const double r1 = static_cast<double>(h.rank_one_vertices().size());
  const double bytes = blocks * (sizeof(Mat3d) + sizeof(int32_t)) +
                       2.0 * r1 * (sizeof(Vec3d) + sizeof(int32_t)) +
                       2.0 * static_cast<double>(n) * sizeof(Vec3d);
  s.counters["vertices"] = static_cast<double>(n);
  s.counters["blocks"] = blocks;
  s.counters["rank_one_entries"] = r1;
  s.counters["bytes_per_second"] =
      benchmark::Counter(bytes, benchmark::Counter::kIsIterationInvariantRate);
}

void BM_HessianAssembly(benchmark::State& s) {
  Assembled& a = assembled(s.range(0));
  const bool project = s.range(1) != 0;
  for (auto _ : s) {
    a.h->set_zero();
    a.energy->add_hessian(a.u, *a.h, project);
    benchmark::DoNotOptimize(a.h->values().data());
  }
  s.counters["tets_per_s"] =
      benchmark::Counter(static_cast<double>(a.loaded.model->tet_count()),
                         benchmark::Counter::kIsIterationInvariantRate);
  s.SetLabel(project ? "projected" : "exact");
}

// The floor's bandwidth, measured in the same run: a sum over 256 MB of doubles on the shared
// pool (the threads the product runs on), bytes read per second. Eight independent partial sums
// per thread, so that the loads and not the chain of additions set the pace (one running sum
// is bound by the adder's latency, at about two thirds of this VM's bandwidth).
void BM_ReadBandwidth(benchmark::State& s) {
  const size_t n = size_t{32} << 20;
  std::vector<double> a(n, 1.0);
  std::vector<double> partial;
  for (auto _ : s) {
    const double sum = pooled_chunk_sum(n, size_t{1} << 16, partial, [&](size_t begin, size_t end) {
      double t[8] = {0, 0, 0, 0, 0, 0, 0, 0};
      for (size_t i = begin; i + 8 <= end; i += 8)
        for (int k = 0; k < 8; ++k) t[k] += a[i + static_cast<size_t>(k)];
      return ((t[0] + t[1]) + (t[2] + t[3])) + ((t[4] + t[5]) + (t[6] + t[7]));
    });
    benchmark::DoNotOptimize(sum);
  }
  s.counters["bytes_per_second"] = benchmark::Counter(
      static_cast<double>(n * sizeof(double)), benchmark::Counter::kIsIterationInvariantRate);
}

// The multigrid preconditioner (multigrid.h) on the assembled Hessian: one V-cycle (CG's
// application per iteration), to set against BM_HessianProduct, and a whole setup (Galerkin
// products, smoothers' spectral bounds, the coarsest factor: a load step's first Newton
// iteration). A free cell's Hessian has the rigid motions in its null space (a run's inertia term
// and mask remove them), so each diagonal block is shifted by 1e-6 of the mean diagonal here.
struct Shifted {
  BlockSparseMatrix h;
  std::unique_ptr<Preconditioner> mg;
};

Shifted& shifted(int64_t vertices) {
  static std::map<int64_t, std::unique_ptr<Shifted>> cache;
  std::unique_ptr<Shifted>& slot = cache[vertices];
  if (slot) return *slot;
  Assembled& a = assembled(vertices);
  slot = std::make_unique<Shifted>();
  slot->h = *a.h;
  double mean = 0;
  for (size_t i = 0; i < slot->h.rows(); ++i) mean += trace(slot->h.diagonal_block(i)) / 3.0;
  mean /= static_cast<double>(slot->h.rows());
  for (size_t i = 0; i < slot->h.rows(); ++i) {
    Mat3d& d = slot->h.diagonal_block(i);
    d = d + (1e-6 * mean) * Mat3d::identity();
  }
  slot->mg = make_multigrid(a.loaded.model->rest_positions, {});
  if (Status st = slot->mg->setup(slot->h); !st) die(st.error().message);
  return *slot;
}

void BM_MultigridCycle(benchmark::State& s) {
  Shifted& m = shifted(s.range(0));
  const size_t n = m.h.rows();
  std::vector<Vec3d> r(n), z(n);
  for (size_t i = 0; i < n; ++i) r[i] = Vec3d{1.0 + 1e-3 * static_cast<double>(i % 7), -0.5, 0.25};
  for (auto _ : s) {
    m.mg->apply(r, z);
    benchmark::DoNotOptimize(z.data());
  }
  s.SetLabel(m.mg->structure());
}

void BM_MultigridSetup(benchmark::State& s) {
  Shifted& m = shifted(s.range(0));
  for (auto _ : s) {
    if (Status st = m.mg->setup(m.h); !st) die(st.error().message);
  }
}

BENCHMARK(BM_MultigridCycle)->Arg(6000)->Arg(64000)->Unit(benchmark::kMicrosecond)->UseRealTime();
BENCHMARK(BM_MultigridSetup)->Arg(6000)->Arg(64000)->Unit(benchmark::kMillisecond)->UseRealTime();
BENCHMARK(BM_ReadBandwidth)->Unit(benchmark::kMillisecond)->UseRealTime();
BENCHMARK(BM_HessianProduct)->Arg(6000)->Arg(64000)->Unit(benchmark::kMicrosecond)->UseRealTime();
BENCHMARK(BM_HessianAssembly)
    ->Args({6000, 0})
    ->Args({6000, 1})
    ->Args({64000, 0})->Unit(benchmark::kMillisecond)->UseRealTime();

}  // namespace
}  // namespace zona::micro
