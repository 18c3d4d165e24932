// Micro-benchmarks of the off-line phase (Ladjal et al. Table II column 3) on the scaling benchmark's
// meshes: the whole build_model per formulation, and its two kernels alone (the rest geometry
// of every tetrahedron; the stored mass tensors). Arguments: vertices, law (0 SVK, 1 linear),
// formulation (0 gradient, 1 tensor_stored, 2 tensor_rebuilt), threads (0: all).
#include <benchmark/benchmark.h>

#include "bench/micro/micro_meshes.h"
#include "engine/fem/mass_tensor.h"

namespace zona::micro {
namespace {

void BM_BuildModel(benchmark::State& s) {
  const Mesh& mesh = cached_mesh(s.range(0));
  const auto law = static_cast<ConstitutiveModel>(s.range(1));
  const auto form = static_cast<Formulation>(s.range(2));
  const ModelDesc desc = bench_model_desc(mesh, law, form, static_cast<int>(s.range(3)));
  for (auto _ : s) {
    Result<Model> model = build_model(mesh, desc);
    if (!model) {
      s.SkipWithError(model.error().message.c_str());
      break;
    }
    benchmark::DoNotOptimize(model->tet_shape.data());
  }
  s.counters["vertices"] = static_cast<double>(mesh.vertex_count());
  s.counters["tets"] = static_cast<double>(mesh.tet_count());
  s.SetLabel(std::string(constitutive_name(law)) + " " + formulation_name(form));
}

void BM_TetShapes(benchmark::State& s) {
  const Mesh& mesh = cached_mesh(s.range(0));
  std::vector<TetShape<double>> shapes;
  for (auto _ : s) {
    compute_tet_shapes(mesh, shapes);
    benchmark::DoNotOptimize(shapes.data());
  }
  s.counters["tets_per_s"] = benchmark::Counter(static_cast<double>(mesh.tet_count()),
                                                benchmark::Counter::kIsIterationInvariantRate);
}

void BM_MassTensors(benchmark::State& s) {
  const Mesh& mesh = cached_mesh(s.range(0));
  const auto law = static_cast<ConstitutiveModel>(s.range(1));
  const int threads = static_cast<int>(s.range(3));
  std::vector<TetShape<double>> shapes;
  compute_tet_shapes(mesh, shapes);
  const std::vector<int32_t> material(mesh.tet_count(), 0);
  const std::vector<Lame> lame = {lame_from_young_poisson(17.9e3, 0.49)};
  MassTensors tensors;
  for (auto _ : s) {
    compute_mass_tensors(shapes, material, lame, law, tensors, threads);
    benchmark::DoNotOptimize(tensors.values.data());
  }
  s.counters["tets_per_s"] = benchmark::Counter(static_cast<double>(mesh.tet_count()),
                                                benchmark::Counter::kIsIterationInvariantRate);
  s.SetBytesProcessed(static_cast<int64_t>(s.iterations()) *
                      static_cast<int64_t>(tensors.bytes()));
  s.SetLabel(constitutive_name(law));
}

void build_cases(benchmark::internal::Benchmark* b) {
  b->ArgNames({"vertices", "law", "form", "threads"});
  for (int64_t n : kMicroSizes)
    for (int law : {0, 1})
      for (int form : {0, 1}) b->Args({n, law, form, 1});
  b->Unit(benchmark::kMillisecond)->UseRealTime();
}

void shape_cases(benchmark::internal::Benchmark* b) {
  b->ArgNames({"vertices"});
  for (int64_t n : kMicroSizes) b->Args({n});
  b->Unit(benchmark::kMillisecond)->UseRealTime();
}

void tensor_cases(benchmark::internal::Benchmark* b) {
  b->ArgNames({"vertices", "law", "form", "threads"});
  for (int64_t n : kMicroSizes)
    for (int law : {0, 1})
      for (int threads : {1, 0}) b->Args({n, law, 1, threads});
  b->Unit(benchmark::kMillisecond)->UseRealTime();
}

BENCHMARK(BM_BuildModel)->Apply(build_cases);
BENCHMARK(BM_TetShapes)->Apply(shape_cases);
BENCHMARK(BM_MassTensors)->Apply(tensor_cases);

}  // namespace
}  // namespace zona::micro
