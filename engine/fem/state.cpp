// State creation and the setters that keep its invariants (constraint mask, capacities).
#include "engine/fem/state.h"

#include <algorithm>
#include <cstdlib>
#include <numeric>
#include <vector>

#include <unistd.h>

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
  s.tet_chunks.resize(static_cast<size_t>((static_cast<int64_t>(nt) + kTetChunk - 1) / kTetChunk));
  s.vertex_chunks.resize(
      static_cast<size_t>((static_cast<int64_t>(nv) + kVertexChunk - 1) / kVertexChunk));
  if (model.nodal_pressure) {
    s.tet_volume_change.assign(nt, 0.0);
    s.vertex_pressure.assign(3 * nv, 0.0);
  }
  if (thread_count <= 0) {
    // One thread per ~2000 tetrahedra (~40 us of element work), up to the cores it may run on:
    // below that the hand-off between threads costs more than it saves.
    const int hardware = available_cores();
    thread_count = std::clamp(static_cast<int>(nt / 2048), 1, hardware);
  }
  s.pool = std::make_unique<ThreadPool>(thread_count);
  make_assembly_plan(model, s, assembly_segment_count(model));
  return s;
}

namespace {

// Segment boundaries (first chunk of each segment, and the end): equal chunk counts. (Until
// late slots were per segment, a late corner cost ~0.15 tetrahedron more than an owned one and
// the segments were balanced by that cost; adding into a per-segment slot costs what adding
// into the vertex's block costs, and the balanced cut measured no faster.)
std::vector<int64_t> equal_segments(int64_t chunks, int64_t segments) {
  std::vector<int64_t> bounds(static_cast<size_t>(segments + 1));
  for (int64_t k = 0; k <= segments; ++k) bounds[static_cast<size_t>(k)] = chunks * k / segments;
  return bounds;
}

// The segment of tetrahedron t: the last one whose first chunk is <= t's chunk.
int64_t segment_of(const std::vector<int64_t>& segment_chunk, int64_t t) {
  return static_cast<int64_t>(
      std::upper_bound(segment_chunk.begin(), segment_chunk.end() - 1, t / kTetChunk) -
      segment_chunk.begin() - 1);
}

// AssemblyPlan::vertex_chunk_order for `plan` (its segments and late slots set) and `threads`;
// block_segment[b] is the segment whose thread writes block b (vertex blocks, then late slots;
// -1 for a vertex no tetrahedron uses), as make_assembly_plan assigned them.
std::vector<int32_t> vertex_chunk_order(const Model& model, const AssemblyPlan& plan,
                                        int64_t threads,
                                        const std::vector<int32_t>& block_segment) {
  const int64_t nt = static_cast<int64_t>(model.tet_count());
  const int64_t nv = static_cast<int64_t>(model.vertex_count());
  const int64_t late = plan.late_count();
  // The vertex pass's chunk order: each thread's home slice of it (ThreadPool: equal slices)
  // gets the chunks whose sums its own segments wrote, as far as the equal slices allow. A
  // vertex's sums are its block, written by the home thread of its owner segment, and its late
  // slots, each written by the home thread of its tetrahedron's segment; a chunk that runs on
  // another thread reads those across cores. Greedy: chunks with the most to lose first, each
  // to the thread that wrote most of its sums among those with room left.
  const int64_t segments = plan.segment_count();
  const int64_t vertex_chunks = (nv + kVertexChunk - 1) / kVertexChunk;
  std::vector<int32_t> order(static_cast<size_t>(vertex_chunks));
  std::iota(order.begin(), order.end(), 0);  // chunk order
  // The order only pays where a thread's share of the step's data stays in its private cache
  // from the element pass to the vertex pass (per tetrahedron ~128 bytes of shape, material and
  // corner codes; per vertex ~192 of displacements, loads, coefficients and sums; 32 per late
  // slot) and where it saves at least a tenth of the sums (below): measured faster at 1101
  // vertices, slower at 16k (docs/performance.md). Chunk order elsewhere. ZONA_CPU_VERTEX_ORDER=0
  // asks for chunk order and =1 for the new order everywhere (comparisons and tests).
  const long cache = sysconf(_SC_LEVEL2_CACHE_SIZE);
  const double thread_bytes =
      (128.0 * static_cast<double>(nt) + 192.0 * static_cast<double>(nv) +
       32.0 * static_cast<double>(late)) / static_cast<double>(threads);
  const bool fits = thread_bytes <= (cache > 0 ? static_cast<double>(cache) : 1048576.0);
  const char* env = std::getenv("ZONA_CPU_VERTEX_ORDER");
  if (threads <= 1 || (env ? std::atoi(env) == 0 : !fits)) return order;

  const auto home_thread = [&](int64_t segment) {
    return ThreadPool::home_thread(segment, segments, threads);
  };
  const auto slice_begin = [&](int64_t t) {  // of the vertex pass's run
    return ThreadPool::slice_begin(vertex_chunks, t, threads);
  };
  // written[c * threads + t]: the sums of chunk c that thread t wrote.
  std::vector<int64_t> written(static_cast<size_t>(vertex_chunks * threads), 0);
  int64_t total = 0;
  for (int64_t v = 0; v < nv; ++v) {
    const int32_t owner = block_segment[static_cast<size_t>(v)];
    if (owner < 0) continue;
    int64_t* w = written.data() + (v / kVertexChunk) * threads;
    ++w[home_thread(owner)];
    ++total;
    for (int32_t k = plan.late_offsets[static_cast<size_t>(v)];
         k < plan.late_offsets[static_cast<size_t>(v) + 1]; ++k) {
      ++w[home_thread(block_segment[static_cast<size_t>(k)])];
      ++total;
    }
  }
  // What a chunk loses on any thread but its best: its largest count minus the second largest.
  std::vector<int64_t> loss(static_cast<size_t>(vertex_chunks));
  for (int64_t c = 0; c < vertex_chunks; ++c) {
    const int64_t* w = written.data() + c * threads;
    int64_t a = -1, b = -1;
    for (int64_t t = 0; t < threads; ++t) {
      b = std::max(b, std::min(a, w[t]));
      a = std::max(a, w[t]);
    }
    loss[static_cast<size_t>(c)] = a - b;
  }
  std::vector<int32_t> by_loss = order;
  std::stable_sort(by_loss.begin(), by_loss.end(), [&](int32_t x, int32_t y) {
    return loss[static_cast<size_t>(x)] > loss[static_cast<size_t>(y)];
  });
  std::vector<std::vector<int32_t>> home(static_cast<size_t>(threads));
  for (int32_t c : by_loss) {
    int64_t pick = -1;
    for (int64_t t = 0; t < threads; ++t) {
      const int64_t room = slice_begin(t + 1) - slice_begin(t) -
                           static_cast<int64_t>(home[static_cast<size_t>(t)].size());
      if (room > 0 && (pick < 0 || written[static_cast<size_t>(c * threads + t)] >
                                       written[static_cast<size_t>(c * threads + pick)]))
        pick = t;
    }
    home[static_cast<size_t>(pick)].push_back(c);
  }
  // Sums read on the thread that wrote them, in chunk order and in the new order; the new
  // order reads that many fewer across cores.
  int64_t local_chunk_order = 0, local_new = 0;
  for (int64_t t = 0; t < threads; ++t) {
    for (int64_t c = slice_begin(t); c < slice_begin(t + 1); ++c)
      local_chunk_order += written[static_cast<size_t>(c * threads + t)];
    for (int32_t c : home[static_cast<size_t>(t)])
      local_new += written[static_cast<size_t>(c * threads + t)];
  }
  if (!env && 10 * (local_new - local_chunk_order) < total) return order;
  order.clear();
  for (std::vector<int32_t>& slice : home) {
    std::sort(slice.begin(), slice.end());  // ascending within a slice: runs of neighbours
    order.insert(order.end(), slice.begin(), slice.end());
  }
  return order;
}

}  // namespace

int64_t assembly_segment_count(const Model& model) {
  const int64_t nt = static_cast<int64_t>(model.tet_count());
  const int64_t chunks = (nt + kTetChunk - 1) / kTetChunk;
  // A function of the mesh alone: a vertex force is the owner's partial sum plus one partial
  // sum per later segment, whose rounding depends on where the segments are cut, so the cut
  // must not depend on the thread count. A power of two (an even split for two, four, eight
  // threads) with segments of at least 256k tetrahedra: two below 1M tetrahedra (~180k
  // vertices; Ladjal et al.'s Table II sizes included: 0.18 late slots per vertex at 1101
  // vertices), 16 at 1M vertices (0.19 per vertex; 64 segments there would leave 0.76, and the
  // two-thread step measured ~5 % slower with them, the one-thread one no faster), at most 64.
  int64_t segments = 2;
  while (segments < 64 && (2 * segments) * 262144 <= nt) segments *= 2;
  return std::clamp<int64_t>(segments, 1, std::max<int64_t>(1, chunks));
}

void make_assembly_plan(const Model& model, State& state, int64_t segment_count,
                        bool all_late) {
  const int64_t nt = static_cast<int64_t>(model.tet_count());
  const int64_t nv = static_cast<int64_t>(model.vertex_count());
  const int64_t chunks = (nt + kTetChunk - 1) / kTetChunk;
  AssemblyPlan& plan = state.assembly;
  plan.segment_chunk =
      equal_segments(chunks, std::clamp<int64_t>(segment_count, 1, std::max<int64_t>(1, chunks)));
  // Late slots, vertex by vertex: one per later segment that holds some of the vertex's
  // tetrahedra (in segment order: the adjacency is in ascending tetrahedron order), which every
  // corner of the vertex in that segment adds into; one per corner in all-late mode.
  const VertexTetAdjacency& adj = model.adjacency;
  plan.late_offsets.assign(static_cast<size_t>(nv + 1), 0);
  std::vector<int32_t> block(static_cast<size_t>(4 * nt), 0);
  // The segment that writes each block (vertex blocks, then late slots), for vertex_chunk_order.
  std::vector<int32_t> block_segment(static_cast<size_t>(nv), -1);
  int64_t late = 0;
  const int64_t late_base = nv;
  for (int64_t v = 0; v < nv; ++v) {
    plan.late_offsets[static_cast<size_t>(v)] = static_cast<int32_t>(late_base + late);
    const int32_t begin = adj.offsets[static_cast<size_t>(v)];
    const int32_t end = adj.offsets[static_cast<size_t>(v) + 1];
    if (begin == end) continue;
    const int64_t owner = segment_of(plan.segment_chunk, adj.tets[static_cast<size_t>(begin)]);
    block_segment[static_cast<size_t>(v)] = static_cast<int32_t>(owner);
    int64_t open_segment = owner;
    for (int32_t i = begin; i < end; ++i) {
      const int64_t t = adj.tets[static_cast<size_t>(i)];
      const size_t k = static_cast<size_t>(4 * t + adj.corner[static_cast<size_t>(i)]);
      const int64_t segment = segment_of(plan.segment_chunk, t);
      if (all_late) {
        block[k] = static_cast<int32_t>(late_base + late++);
        block_segment.push_back(static_cast<int32_t>(segment));
      } else if (segment != owner) {
        if (segment != open_segment) {
          open_segment = segment;
          ++late;
          block_segment.push_back(static_cast<int32_t>(segment));
        }
        block[k] = static_cast<int32_t>(late_base + late - 1);
      } else {
        block[k] = static_cast<int32_t>(v);
      }
    }
  }
  plan.late_offsets[static_cast<size_t>(nv)] = static_cast<int32_t>(late_base + late);
  ZONA_ASSERT(4 * (late_base + late) <= INT32_MAX);
  // Codes in the batch layout; lanes past the end repeat the last tetrahedron's offsets but are
  // never stored (batch_pass drops them).
  const int64_t batches = (nt + 7) / 8;
  plan.corner_code.assign(static_cast<size_t>(batches * 32), 0);
  for (int64_t t = 0; t < nt; ++t)
    for (int c = 0; c < 4; ++c) {
      const size_t k = static_cast<size_t>(4 * t + c);
      plan.corner_code[static_cast<size_t>((t / 8) * 32 + 8 * c + t % 8)] =
          4 * block[k];
    }
  if (all_late)
    plan.corner_block = std::move(block);
  else
    plan.corner_block.clear();
  plan.blocks.resize(static_cast<size_t>(4 * (late_base + late)));
  reset_assembly_blocks(state);

  plan.vertex_chunk_order =
      vertex_chunk_order(model, plan, state.pool ? state.pool->thread_count() : 1, block_segment);
}

void reset_assembly_blocks(State& state) {
  AssemblyPlan& plan = state.assembly;
  const size_t vertex_doubles = 4 * (plan.late_offsets.size() - 1);
  std::fill(plan.blocks.begin(), plan.blocks.begin() + static_cast<ptrdiff_t>(vertex_doubles),
            0.0);
  std::fill(plan.blocks.begin() + static_cast<ptrdiff_t>(vertex_doubles), plan.blocks.end(),
            -0.0);
  plan.dirty = false;
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
