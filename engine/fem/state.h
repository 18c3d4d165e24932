// The mutable simulation state of the CPU backend: displacements, forces, loads, prescribed
// vertices, the last step's diagnostics, and all scratch memory (allocated once, here).
#pragma once

#include <cstdint>
#include <memory>
#include <span>
#include <vector>

#include "engine/core/aligned_vector.h"
#include "engine/core/base.h"
#include "engine/fem/model.h"
#include "engine/core/thread_pool.h"
#include "engine/core/vec.h"

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

/// How the element pass sums corner forces into vertex forces without shared writes and in a
/// fixed order (engine/fem/forces_cpu.h). The tetrahedra are cut into `segment_count` contiguous
/// segments of whole chunks (assembly_segment_count: a function of the mesh alone); one thread
/// runs a segment, in tetrahedron order. A vertex is owned by the segment of its first
/// tetrahedron: there its corner forces are added into its own block (`blocks`, four doubles
/// per vertex) as they are computed, in ascending tetrahedron order. Its corners in each later
/// segment are added, in that order, into one late slot of that segment's, and the vertex pass
/// adds the slots to the block in segment order. Every vertex force is therefore
/// (((+0 + f_1) + ... + f_a) + (f_a+1 + ... + f_b)) + ...: partial sums over the segments,
/// which depend on where the segments are cut but not on which thread ran which segment, nor
/// on how many threads there are. The blocks stay in cache between their corners (the
/// generator numbers tetrahedra along a lattice), so large meshes do not write and re-read 96
/// bytes of corner forces per tetrahedron; one slot per (vertex, later segment) instead of one
/// per late corner keeps the slots few (195 instead of 2316 on the 1101-vertex bench mesh).
///
/// Every corner is one add into its destination (no per-corner case): vertex blocks start each
/// element pass at +0.0, which is how the ordered sum starts, and late slots at -0.0, to which
/// adding f gives f exactly. Whoever consumes the sums (the vertex pass of step(),
/// compute_elastic_forces) puts those values back as it reads them; compute_tet_forces resets
/// every block first when `dirty` says the last pass's sums were not consumed. In all-late mode
/// (tests) every corner has a slot of its own and the sum is the plain ordered one.
struct AssemblyPlan {
  std::vector<int64_t> segment_chunk;  ///< first tetrahedron chunk of each segment, (segments + 1)
  /// Where each corner's force is added, in the layout of Model::cpu_tet_corner_offsets (per
  /// batch of eight tetrahedra: corner c of lane l at 8 c + l): 4 x its block index, a double
  /// offset into `blocks`.
  CacheAlignedVector<int32_t> corner_code;
  /// Blocks 0 .. vertex_count - 1: the vertex sums; then the late slots, those of vertex v at
  /// late_offsets[v] .. late_offsets[v + 1] (block indices), one per later segment in segment
  /// order (one per corner, in ascending tetrahedron order, in all-late mode). Four doubles per
  /// block (x, y, z, and a fourth lane that nothing reads).
  CacheAlignedVector<double> blocks;
  std::vector<int32_t> late_offsets;  ///< (vertex_count + 1), block indices
  /// The blocks hold an element pass's sums that nobody has consumed (and reset) yet.
  bool dirty = false;
  /// Only in a plan where every corner is late (each has a slot of its own, so that the corner
  /// forces can be read one by one: corner_force, for tests; same bits): the block of corner
  /// 4 t + c, (4 tet_count). Empty otherwise.
  std::vector<int32_t> corner_block;

  int64_t segment_count() const { return static_cast<int64_t>(segment_chunk.size()) - 1; }
  /// Late slots (blocks after the vertex blocks).
  int64_t late_count() const {
    return late_offsets.empty()
               ? 0
               : late_offsets.back() - static_cast<int64_t>(late_offsets.size() - 1);
  }
  bool all_late() const { return !corner_block.empty(); }

  /// The order in which the vertex pass's pool run claims vertex chunks (a permutation of
  /// [0, vertex chunks)): sorted by which thread wrote the chunk's sums, so that each thread's
  /// home slice (ThreadPool) holds the chunks whose blocks and late slots its own element
  /// segments wrote and are still in its cache. Results do not depend on it. Chunk order where
  /// a thread's share of the step's data exceeds its L2 cache or the order would save less than
  /// a tenth of the sums read across cores; ZONA_CPU_VERTEX_ORDER=0 or 1 forces chunk order or
  /// the new order (comparisons, tests).
  std::vector<int32_t> vertex_chunk_order;
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
  /// The element pass's assembly plan and its force blocks (make_assembly_plan; docs/physics.md
  /// "Assembly").
  AssemblyPlan assembly;
  std::vector<TetChunkResult> tet_chunks;        ///< (ceil(tet_count / kTetChunk))
  std::vector<VertexChunkResult> vertex_chunks;  ///< (ceil(vertex_count / kVertexChunk))
  /// Model::nodal_pressure only, else empty: V_e / 4 (J_e - 1) per tetrahedron [m^3],
  /// (tet_count), and per vertex (lambda_v (Jbar_v - 1) [Pa], lambda_v / 2 (Jbar_v - 1)^2
  /// [J/m^3], unused), (3 vertex_count): three doubles so that the element pass finds vertex v's
  /// at its displacement offset 3 v.
  std::vector<double> tet_volume_change;
  std::vector<double> vertex_pressure;
  std::unique_ptr<ThreadPool> pool;              ///< the CPU backend's threads
};

/// Creates a zero state (at rest, no loads, no prescribed vertices) for `model`, with
/// `thread_count` threads (0: automatic, one per ~2000 tetrahedra up to the hardware's count).
/// Results do not depend on it, bit for bit.
State make_state(const Model& model, int thread_count = 0);

/// Segments make_state's plan uses: a function of the mesh alone (the bits of the forces depend
/// on where the segments are cut, and must not depend on the thread count): two, doubling while
/// every segment keeps at least 256k tetrahedra, at most 64, never more than the chunks. Threads
/// beyond the segment count do not help the element pass.
int64_t assembly_segment_count(const Model& model);

/// Builds state.assembly for `segment_count` segments (clamped to [1, chunks]); `all_late` gives
/// every corner a slot of its own (corner_force). Allocates. The forces' bits depend on where
/// the segments are cut (partial sums per segment; all-late: the plain ordered sum), never on the
/// thread count.
void make_assembly_plan(const Model& model, State& state, int64_t segment_count,
                        bool all_late = false);

/// Puts every block of state.assembly at its start value (+0.0 for vertex sums, -0.0 for late
/// slots) and clears `dirty`.
void reset_assembly_blocks(State& state);

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
