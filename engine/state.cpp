// State creation and the setters that keep its invariants (constraint mask, capacities).
#include "engine/state.h"

#include <algorithm>
#include <thread>

namespace zona {

State make_state(const Model& model, int thread_count) {
  const size_t nv = model.vertex_count();
  const size_t nt = model.tet_count();
  State s;
  const Vec3d zero{0, 0, 0};
  s.u.assign(nv, zero);
  s.u_prev.assign(nv, zero);
  s.u_next.assign(nv, zero);
  s.force.assign(nv, zero);
  s.external_force.assign(nv, zero);
  s.prescribed_vertices.reserve(nv);
  s.prescribed_displacement.reserve(nv);
  s.vertex_constraint.assign(nv, kVertexFree);
  for (int32_t v : model.fixed_vertices) s.vertex_constraint[v] = kVertexFixed;
  // One slot more than the corners: the vertex pass loads 32 bytes from each 24-byte slot.
  s.tet_force.assign(4 * nt + 1, zero);
  s.tet_chunks.resize(static_cast<size_t>((static_cast<int64_t>(nt) + kTetChunk - 1) / kTetChunk));
  s.vertex_chunks.resize(
      static_cast<size_t>((static_cast<int64_t>(nv) + kVertexChunk - 1) / kVertexChunk));
  if (thread_count <= 0) {
    // One thread per ~2000 tetrahedra (~40 us of element work), up to the hardware's count:
    // below that the hand-off between threads costs more than it saves.
    const int hardware = std::max(1, static_cast<int>(std::thread::hardware_concurrency()));
    thread_count = std::clamp(static_cast<int>(nt / 2048), 1, hardware);
  }
  s.pool = std::make_unique<ThreadPool>(thread_count);
  return s;
}

Status set_prescribed_vertices(const Model& model, State& state,
                               std::span<const int32_t> vertices) {
  const size_t nv = model.vertex_count();
  if (vertices.size() > nv)
    return make_error("prescribed vertices: %zu given for %zu vertices", vertices.size(), nv);
  // Validate everything before touching the state so that an error leaves it unchanged.
  for (size_t i = 0; i < vertices.size(); ++i) {
    const int32_t v = vertices[i];
    if (v < 0 || static_cast<size_t>(v) >= nv)
      return make_error("prescribed vertex %d out of range [0, %zu)", v, nv);
    if (model.vertex_fixed[v]) return make_error("prescribed vertex %d is a fixed vertex", v);
  }
  for (int32_t v : state.prescribed_vertices) state.vertex_constraint[v] = kVertexFree;
  for (size_t i = 0; i < vertices.size(); ++i) {
    const int32_t v = vertices[i];
    if (state.vertex_constraint[v] == kVertexPrescribed) {
      // Undo the marks made so far; the previous set is gone, leave an empty set.
      for (size_t j = 0; j < i; ++j) state.vertex_constraint[vertices[j]] = kVertexFree;
      state.prescribed_vertices.clear();
      state.prescribed_displacement.clear();
      return make_error("prescribed vertex %d is listed twice", v);
    }
    state.vertex_constraint[v] = kVertexPrescribed;
  }
  state.prescribed_vertices.assign(vertices.begin(), vertices.end());
  state.prescribed_displacement.resize(vertices.size());
  for (size_t i = 0; i < vertices.size(); ++i)
    state.prescribed_displacement[i] = state.u[vertices[i]];
  return Status::ok_status();
}

void reset_state(State& state) {
  const Vec3d zero{0, 0, 0};
  std::fill(state.u.begin(), state.u.end(), zero);
  std::fill(state.u_prev.begin(), state.u_prev.end(), zero);
  std::fill(state.u_next.begin(), state.u_next.end(), zero);
  std::fill(state.force.begin(), state.force.end(), zero);
  std::fill(state.external_force.begin(), state.external_force.end(), zero);
  std::fill(state.prescribed_displacement.begin(), state.prescribed_displacement.end(), zero);
  state.time = 0;
  state.step_count = 0;
  state.diag = StepDiagnostics{};
  state.energy_budget_valid = false;
}

void set_displacement(State& state, std::span<const Vec3d> u) {
  ZONA_ASSERT(u.size() == state.u.size());
  std::copy(u.begin(), u.end(), state.u.begin());
  std::copy(u.begin(), u.end(), state.u_prev.begin());
  // A new configuration starts a new energy account.
  state.diag = StepDiagnostics{};
  state.energy_budget_valid = false;
}

}  // namespace zona
