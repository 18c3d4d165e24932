// State creation and the setters that keep its invariants (constraint mask, capacities).
#include "engine/state.h"

#include <algorithm>
#include <cstdlib>
#include <numeric>
#include <thread>
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
  if (thread_count <= 0) {
    // One thread per ~2000 tetrahedra (~40 us of element work), up to the hardware's count:
    // below that the hand-off between threads costs more than it saves.
    const int hardware = std::max(1, static_cast<int>(std::thread::hardware_concurrency()));
    thread_count = std::clamp(static_cast<int>(nt / 2048), 1, hardware);
  }
  s.pool = std::make_unique<ThreadPool>(thread_count);
  make_assembly_plan(model, s, assembly_segment_count(model, thread_count));
  return s;
}

namespace {

// What a late corner costs the element pass beyond an owned one, in tetrahedra: its add goes to
// a slot of its own, in a region the segment touches once (measured on the 1101-vertex bench
// mesh: two segments make 12 % of the corners late and the second segment ~12 % slower).
constexpr double kLateCornerCost = 0.15;

// Segment boundaries (first chunk of each segment, and the end) that give the segments about
// the same cost, a chunk costing its tetrahedra plus kLateCornerCost per late corner (a corner
// whose vertex's first tetrahedron lies before the segment). Bisection on the largest segment
// cost, filling segments greedily; equal chunk counts where every corner is late anyway and on
// large meshes.
std::vector<int64_t> balanced_segments(const Model& model, int64_t segments, bool all_late) {
  const int64_t nt = static_cast<int64_t>(model.tet_count());
  const int64_t chunks = (nt + kTetChunk - 1) / kTetChunk;
  std::vector<int64_t> bounds(static_cast<size_t>(segments + 1));
  for (int64_t k = 0; k <= segments; ++k) bounds[static_cast<size_t>(k)] = chunks * k / segments;
  // Large meshes: segments of ~250k tetrahedra and more have a few per cent of late corners at
  // most (their cost differs by < 1 %), and the search below costs ~0.1 s per million corners.
  if (segments == 1 || all_late || nt > (int64_t{1} << 20)) return bounds;
  // The chunk of each vertex's first tetrahedron, per corner in tetrahedron order.
  const VertexTetAdjacency& adj = model.adjacency;
  std::vector<int32_t> first_chunk(static_cast<size_t>(4 * nt));
  for (int64_t t = 0; t < nt; ++t)
    for (int c = 0; c < 4; ++c) {
      const size_t v = static_cast<size_t>(model.tets[static_cast<size_t>(t)][c]);
      first_chunk[static_cast<size_t>(4 * t + c)] =
          static_cast<int32_t>(adj.tets[static_cast<size_t>(adj.offsets[v])] / kTetChunk);
    }
  const auto chunk_cost = [&](int64_t chunk, int64_t segment_start) {
    const int64_t t0 = chunk * kTetChunk, t1 = std::min(nt, t0 + kTetChunk);
    int64_t late = 0;
    for (int64_t k = 4 * t0; k < 4 * t1; ++k) late += first_chunk[static_cast<size_t>(k)] < segment_start;
    return static_cast<double>(t1 - t0) + kLateCornerCost * static_cast<double>(late);
  };
  // Greedy fill for a largest cost `limit`: the boundaries, or false if more segments are needed.
  const auto fill = [&](double limit, std::vector<int64_t>& out) {
    out.assign(1, 0);
    int64_t start = 0;
    double cost = 0;
    for (int64_t c = 0; c < chunks; ++c) {
      double add = chunk_cost(c, start);
      if (cost > 0 && cost + add > limit) {
        if (static_cast<int64_t>(out.size()) == segments) return false;
        out.push_back(c);
        start = c;
        cost = 0;
        add = chunk_cost(c, start);
      }
      cost += add;
    }
    while (static_cast<int64_t>(out.size()) < segments) out.push_back(chunks);  // (tiny meshes)
    out.push_back(chunks);
    return true;
  };
  double lo = static_cast<double>(nt) / static_cast<double>(segments);
  double hi = 2.0 * static_cast<double>(nt);
  std::vector<int64_t> trial;
  if (!fill(hi, trial)) return bounds;
  bounds = trial;
  for (int it = 0; it < 30 && hi - lo > 0.5; ++it) {
    const double mid = 0.5 * (lo + hi);
    if (fill(mid, trial)) {
      hi = mid;
      bounds = trial;
    } else {
      lo = mid;
    }
  }
  // Empty trailing segments (a limit reached early) would leave threads idle: keep the equal
  // split then.
  for (int64_t k = 0; k < segments; ++k)
    if (bounds[static_cast<size_t>(k)] >= bounds[static_cast<size_t>(k) + 1]) {
      for (int64_t j = 0; j <= segments; ++j) bounds[static_cast<size_t>(j)] = chunks * j / segments;
      break;
    }
  return bounds;
}

// The segment of tetrahedron t: the last one whose first chunk is <= t's chunk.
int64_t segment_of(const std::vector<int64_t>& segment_chunk, int64_t t) {
  return static_cast<int64_t>(
      std::upper_bound(segment_chunk.begin(), segment_chunk.end() - 1, t / kTetChunk) -
      segment_chunk.begin() - 1);
}

// AssemblyPlan::vertex_chunk_order for `plan` (its segments and late slots set) and `threads`.
std::vector<int32_t> vertex_chunk_order(const Model& model, const AssemblyPlan& plan,
                                        int64_t threads, bool all_late) {
  const int64_t nt = static_cast<int64_t>(model.tet_count());
  const int64_t nv = static_cast<int64_t>(model.vertex_count());
  const int64_t late = plan.late_count();
  const VertexTetAdjacency& adj = model.adjacency;
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
    const int32_t begin = adj.offsets[static_cast<size_t>(v)];
    const int32_t end = adj.offsets[static_cast<size_t>(v) + 1];
    if (begin == end) continue;
    int64_t* w = written.data() + (v / kVertexChunk) * threads;
    const int64_t owner = segment_of(plan.segment_chunk, adj.tets[static_cast<size_t>(begin)]);
    ++w[home_thread(owner)];
    ++total;
    for (int32_t i = begin; i < end; ++i) {
      const int64_t segment = segment_of(plan.segment_chunk, adj.tets[static_cast<size_t>(i)]);
      if (all_late || segment != owner) {
        ++w[home_thread(segment)];
        ++total;
      }
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

int64_t assembly_segment_count(const Model& model, int thread_count) {
  const int64_t nt = static_cast<int64_t>(model.tet_count());
  const int64_t chunks = (nt + kTetChunk - 1) / kTetChunk;
  const int64_t threads = std::max(1, thread_count);
  // One thread: one segment (no late corners; nobody to take work over).
  if (threads == 1) return 1;
  // Segments of at least ~250k tetrahedra beyond one per thread: a vertex's tetrahedra span
  // about one lattice layer of the generator's numbering (~5 % of a 1M-vertex mesh), so
  // shorter segments would make most corners late.
  const int64_t per_thread = std::clamp<int64_t>(nt / (threads * 262144), 1, 4);
  return std::clamp<int64_t>(threads * per_thread, 1, std::max<int64_t>(1, chunks));
}

void make_assembly_plan(const Model& model, State& state, int64_t segment_count,
                        bool all_late) {
  const int64_t nt = static_cast<int64_t>(model.tet_count());
  const int64_t nv = static_cast<int64_t>(model.vertex_count());
  const int64_t chunks = (nt + kTetChunk - 1) / kTetChunk;
  AssemblyPlan& plan = state.assembly;
  plan.segment_chunk = balanced_segments(
      model, std::clamp<int64_t>(segment_count, 1, std::max<int64_t>(1, chunks)), all_late);
  // Late corners, vertex by vertex in adjacency (ascending tetrahedron) order.
  const VertexTetAdjacency& adj = model.adjacency;
  plan.late_offsets.assign(static_cast<size_t>(nv + 1), 0);
  std::vector<int32_t> block(static_cast<size_t>(4 * nt), 0);
  int64_t late = 0;
  const int64_t late_base = nv;
  for (int64_t v = 0; v < nv; ++v) {
    plan.late_offsets[static_cast<size_t>(v)] = static_cast<int32_t>(late_base + late);
    const int32_t begin = adj.offsets[static_cast<size_t>(v)];
    const int32_t end = adj.offsets[static_cast<size_t>(v) + 1];
    if (begin == end) continue;
    const int64_t owner = segment_of(plan.segment_chunk, adj.tets[static_cast<size_t>(begin)]);
    for (int32_t i = begin; i < end; ++i) {
      const int64_t t = adj.tets[static_cast<size_t>(i)];
      const size_t k = static_cast<size_t>(4 * t + adj.corner[static_cast<size_t>(i)]);
      if (all_late || segment_of(plan.segment_chunk, t) != owner) {
        block[k] = static_cast<int32_t>(late_base + late++);
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
      vertex_chunk_order(model, plan, state.pool ? state.pool->thread_count() : 1, all_late);
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
