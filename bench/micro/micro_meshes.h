// Shared fixtures of the micro-benchmarks: the scaling benchmark's meshes (table2_spec, refined
// at the puncture pole), built once per size, and loaded models and states on them.
#pragma once

#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <string>
#include <map>
#include <memory>

#include "engine/mesh/mesh_generate.h"
#include "engine/fem/model.h"
#include "bench/scaling/scaling_bench.h"
#include "engine/fem/state.h"

namespace zona::micro {

/// Setup failures end the benchmark run with the message (no measurement is possible).
[[noreturn]] inline void die(const std::string& message) {
  std::fprintf(stderr, "zona_micro_bench: %s\n", message.c_str());
  std::exit(1);
}

/// The table2_spec mesh with about `vertices` vertices, generated on first use (a few seconds
/// at 1e5) and kept for the process.
inline const Mesh& cached_mesh(int64_t vertices) {
  static std::map<int64_t, std::unique_ptr<Mesh>> meshes;
  std::unique_ptr<Mesh>& slot = meshes[vertices];
  if (!slot) {
    Result<Mesh> mesh = generate_cell_mesh(table2_spec(vertices));
    if (!mesh) die(mesh.error().message);
    slot = std::make_unique<Mesh>(std::move(mesh).value());
  }
  return *slot;
}

/// The scaling benchmark's model description for a mesh: default material (mouse zona
/// pellucida), bottom cap held, half the critical step.
inline ModelDesc bench_model_desc(const Mesh& mesh, ConstitutiveModel law, Formulation form,
                                  int threads) {
  ModelDesc desc;
  desc.constitutive = law;
  desc.formulation = form;
  desc.fixed_vertices = bench_fixed_vertices(mesh);
  desc.dt_safety = 0.5;
  desc.precompute_threads = threads;
  return desc;
}

/// A model and a state loaded with the scaling benchmark's displacement field.
struct Loaded {
  std::unique_ptr<Model> model;
  std::unique_ptr<State> state;
};

inline Loaded make_loaded(int64_t vertices, ConstitutiveModel law, Formulation form,
                          int threads) {
  const Mesh& mesh = cached_mesh(vertices);
  Result<Model> model = build_model(mesh, bench_model_desc(mesh, law, form, threads));
  if (!model) die(model.error().message);
  Loaded l;
  l.model = std::make_unique<Model>(std::move(model).value());
  l.state = std::make_unique<State>(make_state(*l.model, threads));
  const std::vector<Vec3d> u = bench_displacement(mesh);
  set_displacement(*l.state, u);
  return l;
}

/// Sizes of the micro-benchmarks [vertices].
inline constexpr int64_t kMicroSizes[] = {1000, 10000, 100000};

}  // namespace zona::micro
