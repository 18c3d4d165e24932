// The mutable simulation state of the CPU backend: displacements, forces, loads, prescribed
// vertices, the last step's diagnostics, and all scratch memory (allocated once, here).
#pragma once

#include <cstdint>
#include <memory>
#include <span>
#include <vector>

#include "engine/base.h"
#include "engine/model.h"
#include "engine/thread_pool.h"
#include "engine/vec.h"

namespace zona {

/// Per-vertex constraint kinds held in State::vertex_constraint.
enum VertexConstraint : uint8_t {
  kVertexFree = 0,
  kVertexFixed = 1,       ///< held at zero displacement (Model::fixed_vertices)
  kVertexPrescribed = 2,  ///< moved to State::prescribed_displacement each step
};

/// Chunk sizes of the parallel passes. Per-chunk partial results are reduced in chunk order,
/// so sums are bitwise identical for every thread count.
inline constexpr int64_t kTetChunk = 128;
inline constexpr int64_t kVertexChunk = 64;

/// Partial results of one chunk of tetrahedra (scratch). Cache-line aligned: written by
/// different threads.
struct alignas(64) TetChunkResult {
  double elastic_energy = 0;      ///< [J]
  uint32_t health = 0;            ///< OR of ElementHealth bits
  int32_t inverted_count = 0;
  int32_t collapsing_count = 0;
  int32_t clamped_count = 0;
  int64_t first_inverted = -1;    ///< smallest inverted tetrahedron index, -1 if none
  int64_t first_collapsing = -1;  ///< smallest collapsing tetrahedron index, -1 if none
};

/// Partial results of one chunk of vertices (scratch).
struct alignas(64) VertexChunkResult {
  double kinetic_energy = 0;   ///< [J]
  double input_work = 0;       ///< work of loads and prescribed vertices over the step [J]
  double residual_sq = 0;      ///< |f_el + f_ext|^2 over free vertices [N^2]
  double reference_sq = 0;     ///< |f_ext|^2 + |f_el|^2 over constrained vertices [N^2]
  int64_t first_nonfinite = -1;  ///< smallest vertex with a non-finite update, -1 if none
};

/// What the last step (or force evaluation) saw. Energies are at time t_n, the configuration
/// the forces were evaluated at.
struct StepDiagnostics {
  double elastic_energy = 0;      ///< W(u_n) [J]
  double kinetic_energy = 0;      ///< sum M |v_n|^2 / 2 with v_n = (u_{n+1} - u_{n-1}) / 2dt [J]
  /// Initial energy plus the work put in by loads and prescribed vertices so far [J]; damping
  /// only removes energy, so kinetic + elastic above a multiple of this is a blow-up.
  double energy_budget = 0;
  double step_input_work = 0;     ///< work of loads and prescribed vertices in this step [J]
  double residual_norm = 0;       ///< |f_el + f_ext| over free vertices [N]
  double reference_force_norm = 0;  ///< |f_ext| and constraint forces, for relative residuals [N]
  /// Sum over prescribed vertices of the force the constraint applies to the body,
  /// M a + gamma v - f_el - f_ext [N]; the needle feels minus this.
  Vec3d constraint_force{0, 0, 0};
  uint32_t element_health = 0;    ///< OR of ElementHealth bits
  int64_t inverted_count = 0;     ///< elements with det F <= 0
  int64_t collapsing_count = 0;   ///< SVK elements with a stretch below 1/sqrt(3)
  int64_t clamped_count = 0;      ///< elements the inversion-safe SVK clamped
  int64_t first_inverted = -1;    ///< an inverted element (smallest index), -1 if none
  int64_t first_collapsing = -1;  ///< a collapsing element (smallest index), -1 if none
  int64_t first_nonfinite = -1;   ///< a vertex whose update was not finite, -1 if none
};

/// The mutable state. Created by make_state for one model; nothing in it is reallocated by
/// step(). Move-only (it owns the worker threads).
struct State {
  std::vector<Vec3d> u;        ///< displacement u_n [m], (vertex_count), float64 (docs/physics.md)
  std::vector<Vec3d> u_prev;   ///< displacement u_{n-1} [m], (vertex_count)
  std::vector<Vec3d> force;    ///< elastic force -dW/du at the last evaluated u [N], (vertex_count)
  std::vector<Vec3d> external_force;  ///< applied nodal loads [N], (vertex_count), user-set
  /// Vertices whose displacement is prescribed (set with set_prescribed_vertices).
  std::vector<int32_t> prescribed_vertices;
  /// Target displacement of each prescribed vertex at the end of the next step [m],
  /// (prescribed count); set before each step().
  std::vector<Vec3d> prescribed_displacement;
  std::vector<uint8_t> vertex_constraint;  ///< VertexConstraint per vertex, (vertex_count)

  double time = 0;         ///< simulated time t_n [s]
  int64_t step_count = 0;  ///< steps taken
  StepDiagnostics diag;    ///< the last step's diagnostics
  /// False until a step records the initial energy as the start of diag.energy_budget; set it
  /// false (or call set_displacement) after editing u or u_prev by hand.
  bool energy_budget_valid = false;

  // Scratch, sized once by make_state.
  std::vector<Vec3d> u_next;     ///< u_{n+1} before it is accepted [m], (vertex_count)
  /// Per-element corner forces [N], (4 tet_count + 1): corner c of tetrahedron t at 4 t + c;
  /// the last slot is padding (zero) so that a 32-byte load from any corner slot stays inside.
  std::vector<Vec3d> tet_force;
  std::vector<TetChunkResult> tet_chunks;        ///< (ceil(tet_count / kTetChunk))
  std::vector<VertexChunkResult> vertex_chunks;  ///< (ceil(vertex_count / kVertexChunk))
  std::unique_ptr<ThreadPool> pool;              ///< the CPU backend's threads
};

/// Creates a zero state (at rest, no loads, no prescribed vertices) for `model`, with
/// `thread_count` threads (0: automatic, one per ~2000 tetrahedra up to the hardware's count).
/// Results do not depend on it, bit for bit.
State make_state(const Model& model, int thread_count = 0);

/// Sets the prescribed vertices (replacing the previous set); their targets start at their
/// current displacement. Errors: index out of range, fixed vertex, repeated vertex. Does not
/// allocate (capacity reserved by make_state).
Status set_prescribed_vertices(const Model& model, State& state,
                               std::span<const int32_t> vertices);

/// Puts the state back at rest: zero displacements, loads, time and diagnostics; keeps the
/// prescribed set with zero targets.
void reset_state(State& state);

/// Sets a displacement field with zero velocity (u_n = u_{n-1} = u) [m], (vertex_count).
void set_displacement(State& state, std::span<const Vec3d> u);

}  // namespace zona
