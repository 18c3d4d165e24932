// Micro-benchmarks of the CPU step's parts on the scaling benchmark's meshes and loaded state:
// the element pass (force assembly, each formulation and law), the element pass plus the
// per-vertex gather, and the whole step (element pass + gather + centred-difference update).
// Arguments: vertices, law (0 SVK, 1 linear), formulation (0 gradient, 1 tensor_stored,
// 2 tensor_rebuilt: the Formulation enum), threads (0: one per hardware thread). Wall-clock
// time (UseRealTime): the pool's workers do half the work, which the main thread's CPU time
// would not see.
#include <benchmark/benchmark.h>

#include "bench/micro/micro_meshes.h"
#include "engine/fem/forces_cpu.h"
#include "engine/sim/integrator.h"

namespace zona::micro {
namespace {

struct Case {
  int64_t vertices;
  ConstitutiveModel law;
  Formulation form;
  int threads;
};

Case read_case(const benchmark::State& s) {
  return {s.range(0), static_cast<ConstitutiveModel>(s.range(1)),
          static_cast<Formulation>(s.range(2)), static_cast<int>(s.range(3))};
}

void set_counters(benchmark::State& s, const Loaded& l, const Case& c) {
  const auto nv = static_cast<int64_t>(l.model->vertex_count());
  const auto nt = static_cast<int64_t>(l.model->tet_count());
  s.counters["vertices"] = static_cast<double>(nv);
  s.counters["tets"] = static_cast<double>(nt);
  s.counters["threads"] = l.state->pool->thread_count();
  // Elements per second, and the bytes the whole step streams (step_bytes) per second.
  s.counters["tets_per_s"] =
      benchmark::Counter(static_cast<double>(nt), benchmark::Counter::kIsIterationInvariantRate);
  s.SetBytesProcessed(static_cast<int64_t>(
      static_cast<double>(s.iterations()) *
      step_bytes(BackendKind::kCpu, c.law, c.form, BackendOptions{}.assembly, nv, nt)));
  s.SetLabel(std::string(constitutive_name(c.law)) + " " + formulation_name(c.form));
}

// Force assembly: the element pass alone (corner forces, energy, health per element).
void BM_ElementPass(benchmark::State& s) {
  const Case c = read_case(s);
  Loaded l = make_loaded(c.vertices, c.law, c.form, c.threads);
  for (auto _ : s) {
    compute_tet_forces(*l.model, *l.state);
    benchmark::DoNotOptimize(l.state->assembly.blocks.data());
    benchmark::ClobberMemory();
  }
  set_counters(s, l, c);
}

// Force assembly with the gather: vertex forces -dW/du (what `zona forces` computes).
void BM_ElasticForces(benchmark::State& s) {
  const Case c = read_case(s);
  Loaded l = make_loaded(c.vertices, c.law, c.form, c.threads);
  for (auto _ : s) {
    compute_elastic_forces(*l.model, *l.state);
    benchmark::DoNotOptimize(l.state->force.data());
    benchmark::ClobberMemory();
  }
  set_counters(s, l, c);
}

// The whole explicit step; the integration update's own cost is this minus BM_ElementPass
// (the engine does not expose the vertex pass on its own).
void BM_Step(benchmark::State& s) {
  const Case c = read_case(s);
  Loaded l = make_loaded(c.vertices, c.law, c.form, c.threads);
  StepStatus all = kStepOk;
  for (auto _ : s) {
    all |= step(*l.model, *l.state);
    benchmark::ClobberMemory();
  }
  if (all & kStepNotAdvanced) s.SkipWithError("a step was not advanced");
  set_counters(s, l, c);
}

// Sizes x law x formulation x {1 thread, all threads}. The stored SVK tensors at 1e5 vertices
// take 2.7 GB and about a second per step on two cores: kept, with few iterations.
void cases(benchmark::internal::Benchmark* b) {
  b->ArgNames({"vertices", "law", "form", "threads"});
  for (int64_t n : kMicroSizes)
    for (int law : {0, 1})
      for (int form : {0, 1, 2})
        for (int threads : {1, 0}) b->Args({n, law, form, threads});
  b->Unit(benchmark::kMillisecond)->UseRealTime();
}

// Step and gather: the gradient form only (the formulation changes the element pass alone).
void step_cases(benchmark::internal::Benchmark* b) {
  b->ArgNames({"vertices", "law", "form", "threads"});
  for (int64_t n : kMicroSizes)
    for (int law : {0, 1})
      for (int threads : {1, 0}) b->Args({n, law, 0, threads});
  b->Unit(benchmark::kMillisecond)->UseRealTime();
}

BENCHMARK(BM_ElementPass)->Apply(cases);
BENCHMARK(BM_ElasticForces)->Apply(step_cases);
BENCHMARK(BM_Step)->Apply(step_cases);

}  // namespace
}  // namespace zona::micro
