// The explicit step as a table of contents, its stages, sub-stepping and dynamic relaxation.
#include "engine/sim/integrator.h"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <vector>

#include "engine/fem/forces_cpu.h"
#include "engine/core/simd_pack.h"

namespace zona {
namespace {

struct PassContext {
  const Model* model;
  State* state;
};

inline bool finite3(Vec3d a) { return std::isfinite(a.x) && std::isfinite(a.y) && std::isfinite(a.z); }

// What the vertex pass reads and writes, as plain pointers: the pass stores through memcpy,
// which may alias anything, so pointers read from the Model and State on every vertex would be
// reloaded on every vertex.
struct VertexPassArrays {
  double* blocks;                         // State::assembly.blocks (read, then reset)
  const int32_t* late_offsets;            // State::assembly.late_offsets
  const double* u;                        // u_n, 3 per vertex
  const double* u_prev;                   // u_{n-1}
  const double* external_force;
  const uint8_t* constraint;              // VertexConstraint per vertex
  const double* coefficients;             // VertexCoefficients (a, b, c) per vertex
  const double* mass;
  double* force;                          // out: elastic force
  double* u_next;                         // out: u_{n+1}
};
static_assert(sizeof(VertexCoefficients) == 3 * sizeof(double));
static_assert(sizeof(Vec3d) == 3 * sizeof(double));

// A chunk's sums, lane l holding those of its vertices 4 k + l (reduced by lane_sum).
struct VertexSums {
  P4 kinetic = zero4(), work = zero4(), residual = zero4(), reference = zero4();
  P4 probe = zero4();  // next - next summed: 0 where every update was finite, NaN otherwise
};

// (l0 + l1) + (l2 + l3).
[[gnu::always_inline]] inline double lane_sum(P4 a) {
  return (a.v[0] + a.v[1]) + (a.v[2] + a.v[3]);
}

// (x x' + y y') + z z' per lane: dot() of four vectors, in dot()'s order (the same bits).
[[gnu::always_inline]] inline P4 dot3(P4 x, P4 y, P4 z, P4 x2, P4 y2, P4 z2) {
  return (x * x2 + y * y2) + z * z2;
}

// Lanes of `a` where `m` holds, +0 elsewhere.
[[gnu::always_inline]] inline P4 select(M4 m, P4 a) {
  P4 r;
  r.v = reinterpret_cast<V4>(m & reinterpret_cast<M4>(a.v));
  return r;
}

// Lanes of `a` where `m` holds, of `b` elsewhere, bit for bit (a -0.0 stays -0.0).
[[gnu::always_inline]] inline P4 blend(M4 m, P4 a, P4 b) {
  P4 r;
  r.v = reinterpret_cast<V4>((m & reinterpret_cast<M4>(a.v)) | (~m & reinterpret_cast<M4>(b.v)));
  return r;
}

// The centred-difference update u+ = a u - b u- + c (f_el + f_ext) (docs/physics.md) of four
// consecutive vertices, one per lane, whose arrays start at the pointers given; f holds their
// elastic forces as (x, y, z, *), lane 3 unread. Fixed vertices go to zero; prescribed ones keep
// u_n here and are written by apply_prescribed_vertices. Each lane performs the Vec3d operations
// of one vertex in their order, so the displacements are those of a vertex-by-vertex update bit
// for bit; the chunk sums add per lane (VertexSums).
[[gnu::always_inline]] inline void update_four(const double* u, const double* u_prev,
                                               const double* external_force,
                                               const uint8_t* constraint,
                                               const double* coefficients, const double* mass,
                                               P4 f[4], P4 half_inv_dt, double* force_out,
                                               double* next_out, VertexSums& s) {
  transpose4(f);  // f[0..2]: x, y, z of the four vertices
  store_aos3(f[0], f[1], f[2], force_out);
  P4 ux, uy, uz, px, py, pz, ex, ey, ez, ka, kb, kc;
  load_soa3(u, ux, uy, uz);
  load_soa3(u_prev, px, py, pz);
  load_soa3(external_force, ex, ey, ez);
  load_soa3(coefficients, ka, kb, kc);
  const P4 tx = f[0] + ex, ty = f[1] + ey, tz = f[2] + ez;  // f_el + f_ext
  P4 nx = ka * ux - kb * px + kc * tx;
  P4 ny = ka * uy - kb * py + kc * ty;
  P4 nz = ka * uz - kb * pz + kc * tz;
  const P4 dx = nx - px, dy = ny - py, dz = nz - pz;  // = 2 dt v_n
  const P4 vx = half_inv_dt * dx, vy = half_inv_dt * dy, vz = half_inv_dt * dz;
  const P4 kinetic = P4(0.5) * load4(mass) * dot3(vx, vy, vz, vx, vy, vz);
  const P4 work = P4(0.5) * dot3(ex, ey, ez, dx, dy, dz);
  const P4 residual = dot3(tx, ty, tz, tx, ty, tz);
  const P4 reference = dot3(ex, ey, ez, ex, ey, ez);
  uint32_t kinds;
  std::memcpy(&kinds, constraint, sizeof kinds);
  if (kinds == 0) {  // all four free (kVertexFree == 0)
    s.kinetic += kinetic;
    s.work += work;
    s.residual += residual;
  } else {
    M4 free, fixed;
    for (int l = 0; l < 4; ++l) {
      free[l] = constraint[l] == kVertexFree ? -1 : 0;
      fixed[l] = constraint[l] == kVertexFixed ? -1 : 0;
    }
    // Free: the update; fixed: +0; prescribed: u_n (overwritten by the next stage).
    nx = blend(free, nx, select(~fixed, ux));
    ny = blend(free, ny, select(~fixed, uy));
    nz = blend(free, nz, select(~fixed, uz));
    s.kinetic += select(free, kinetic);
    s.work += select(free, work);
    s.residual += select(free, residual);
    s.reference += select(~free, dot3(f[0], f[1], f[2], f[0], f[1], f[2]));
  }
  s.reference += reference;
  s.probe += (nx - nx) + (ny - ny) + (nz - nz);
  store_aos3(nx, ny, nz, next_out);
}

// Stage 2, per chunk of vertices: take the elastic force, then the centred-difference update,
// four vertices at a time (a last group of fewer goes through copies padded with fixed vertices
// at rest, which add +0 to every sum).
[[gnu::always_inline]] inline void integrate_chunks_body(void* context, int64_t chunk_begin,
                                                         int64_t chunk_end) {
  const Model& m = *static_cast<PassContext*>(context)->model;
  State& s = *static_cast<PassContext*>(context)->state;
  const int64_t nv = static_cast<int64_t>(m.vertex_count());
  const P4 half_inv_dt(0.5 / m.dt);
  const VertexPassArrays a{s.assembly.blocks.data(),
                           s.assembly.late_offsets.data(),
                           &s.u.data()->x,
                           &s.u_prev.data()->x,
                           &s.external_force.data()->x,
                           s.vertex_constraint.data(),
                           &m.vertex_coefficients.data()->a,
                           m.vertex_mass.data(),
                           &s.force.data()->x,
                           &s.u_next.data()->x};
  for (int64_t chunk = chunk_begin; chunk < chunk_end; ++chunk) {
    const int64_t begin = chunk * kVertexChunk;
    const int64_t end = std::min(nv, begin + kVertexChunk);
    VertexSums sums;
    int64_t v = begin;
    for (; v + 4 <= end; v += 4) {
      P4 f[4];
#pragma GCC unroll 4
      for (int l = 0; l < 4; ++l)
        f[l] = take_vertex_force(a.blocks, a.late_offsets, static_cast<size_t>(v + l));
      const size_t o = 3 * static_cast<size_t>(v);
      update_four(a.u + o, a.u_prev + o, a.external_force + o, a.constraint + v,
                  a.coefficients + o, a.mass + v, f, half_inv_dt, a.force + o, a.u_next + o,
                  sums);
    }
    if (v < end) {
      const int n = static_cast<int>(end - v);
      const size_t o = 3 * static_cast<size_t>(v);
      const size_t n3 = 3 * static_cast<size_t>(n);
      double u[12] = {}, up[12] = {}, ext[12] = {}, coef[12] = {}, mass[4] = {};
      double force[12], next[12];
      uint8_t kind[4] = {kVertexFixed, kVertexFixed, kVertexFixed, kVertexFixed};
      P4 f[4] = {zero4(), zero4(), zero4(), zero4()};
      std::copy_n(a.u + o, n3, u);
      std::copy_n(a.u_prev + o, n3, up);
      std::copy_n(a.external_force + o, n3, ext);
      std::copy_n(a.coefficients + o, n3, coef);
      std::copy_n(a.mass + v, n, mass);
      std::copy_n(a.constraint + v, n, kind);
      for (int l = 0; l < n; ++l)
        f[l] = take_vertex_force(a.blocks, a.late_offsets, static_cast<size_t>(v + l));
      update_four(u, up, ext, kind, coef, mass, f, half_inv_dt, force, next, sums);
      std::copy_n(force, n3, a.force + o);
      std::copy_n(next, n3, a.u_next + o);
    }
    VertexChunkResult r;
    r.kinetic_energy = lane_sum(sums.kinetic);
    r.input_work = lane_sum(sums.work);
    r.residual_sq = lane_sum(sums.residual);
    r.reference_sq = lane_sum(sums.reference);
    if (!(lane_sum(sums.probe) == 0)) {
      for (int64_t w = begin; w < end; ++w)
        if (!finite3(s.u_next[static_cast<size_t>(w)])) {
          r.first_nonfinite = w;
          break;
        }
    }
    s.vertex_chunks[static_cast<size_t>(chunk)] = r;
  }
}

ZONA_SIMD_CLONES void integrate_chunks(void* context, int64_t chunk_begin, int64_t chunk_end) {
  integrate_chunks_body(context, chunk_begin, chunk_end);
}

#if defined(__GNUC__) && !defined(__clang__) && defined(__x86_64__) && \
    !defined(__SANITIZE_THREAD__)
// The same pass encoded with AVX-512VL where cpu_simd_registers() says 32: still 256-bit vectors,
// but one-instruction two-source shuffles (vpermt2pd) for the 3-vector to pack conversions and 32
// registers. Contraction off: the same operations, the same bits.
__attribute__((target("avx2,avx512f,avx512vl"), optimize("fp-contract=off"), flatten)) void
integrate_chunks_vl(void* context, int64_t chunk_begin, int64_t chunk_end) {
  integrate_chunks_body(context, chunk_begin, chunk_end);
}
#define ZONA_HAVE_VL_VERTEX_PASS 1
#endif

// The vertex pass over positions [begin, end) of AssemblyPlan::vertex_chunk_order.
struct OrderedContext {
  PassContext pass;
  ThreadPool::ChunkFn chunks;
};

void integrate_in_order(void* context, int64_t begin, int64_t end) {
  OrderedContext& c = *static_cast<OrderedContext*>(context);
  const int32_t* order = c.pass.state->assembly.vertex_chunk_order.data();
  for (int64_t i = begin; i < end;) {  // runs of consecutive chunks in one call
    int64_t j = i + 1;
    while (j < end && order[j] == order[j - 1] + 1) ++j;
    c.chunks(&c.pass, order[i], order[j - 1] + 1);
    i = j;
  }
}

// Stage 2: the vertex pass over the pool, in the plan's chunk order.
void integrate_vertices(const Model& model, State& state) {
  OrderedContext context{{&model, &state}, &integrate_chunks};
#ifdef ZONA_HAVE_VL_VERTEX_PASS
  if (cpu_simd_registers() >= 32) context.chunks = &integrate_chunks_vl;
#endif
  state.pool->run(static_cast<int64_t>(state.vertex_chunks.size()), &integrate_in_order,
                  &context);
  state.assembly.dirty = false;
}

// Stage 3: prescribed vertices take their targets; the constraint force that moves each one is
// what the centred-difference equation of that vertex leaves over: M a + gamma v - f_el - f_ext.
// Serial and in list order (the set is small: a needle's contact patch). Leaves its kinetic
// energy, work and first non-finite vertex in diag for stage 4 to add to the chunk sums.
void apply_prescribed_vertices(const Model& model, State& state) {
  StepDiagnostics& d = state.diag;
  const double inv_dt2 = 1.0 / (model.dt * model.dt);
  const double half_inv_dt = 0.5 / model.dt;
  Vec3d reaction{0, 0, 0};
  double kinetic = 0, work = 0;
  d.first_nonfinite = -1;
  for (size_t i = 0; i < state.prescribed_vertices.size(); ++i) {
    const size_t v = static_cast<size_t>(state.prescribed_vertices[i]);
    const Vec3d next = state.prescribed_displacement[i];
    const Vec3d un = state.u[v], up = state.u_prev[v];
    state.u_next[v] = next;
    const Vec3d du = next - up;
    const Vec3d vel = half_inv_dt * du;
    const Vec3d acc = inv_dt2 * (next - 2.0 * un + up);
    const double m = model.vertex_mass[v];
    const Vec3d r =
        m * acc + model.vertex_damping[v] * vel - state.force[v] - state.external_force[v];
    reaction += r;
    kinetic += 0.5 * m * dot(vel, vel);
    work += 0.5 * dot(r + state.external_force[v], du);
    if (!finite3(next) && (d.first_nonfinite < 0 || static_cast<int64_t>(v) < d.first_nonfinite))
      d.first_nonfinite = static_cast<int64_t>(v);
  }
  d.constraint_force = reaction;
  d.kinetic_energy = kinetic;
  d.step_input_work = work;
}

// Stage 4: reduce the chunk results in chunk order (the same sums for every thread count) and
// raise the flags.
StepStatus check_health(const Model& model, State& state) {
  StepDiagnostics& d = state.diag;
  reduce_tet_chunks(state, d);
  double residual_sq = 0, reference_sq = 0;
  for (const VertexChunkResult& r : state.vertex_chunks) {
    d.kinetic_energy += r.kinetic_energy;
    d.step_input_work += r.input_work;
    residual_sq += r.residual_sq;
    reference_sq += r.reference_sq;
    if (r.first_nonfinite >= 0 && (d.first_nonfinite < 0 || r.first_nonfinite < d.first_nonfinite))
      d.first_nonfinite = r.first_nonfinite;
  }
  reference_sq += dot(d.constraint_force, d.constraint_force);
  d.residual_norm = std::sqrt(residual_sq);
  d.reference_force_norm = std::sqrt(reference_sq);

  StepStatus status = kStepOk;
  const double energy = d.kinetic_energy + d.elastic_energy;
  if (d.first_nonfinite >= 0 || !std::isfinite(energy)) {
    status |= kStepNonFinite;
  } else {
    if (!state.energy_budget_valid) {
      d.energy_budget = energy;
      state.energy_budget_valid = true;
    }
    d.energy_budget += d.step_input_work;
    if (energy > model.energy_blowup_factor * std::max(d.energy_budget, model.energy_floor))
      status |= kStepEnergyBlowUp;
  }
  if (d.element_health & kElementInverted) status |= kStepInvertedElement;
  if (d.element_health & kElementCollapsing) status |= kStepCollapsingElement;
  if (d.element_health & kElementClamped) status |= kStepClampedElement;
  if (model.dt > model.dt_critical) status |= kStepDtAboveCritical;
  return status;
}

// Stage 5: accept u_{n+1}. Swapping the buffers moves no data and allocates nothing.
void commit_step(const Model& model, State& state) {
  std::swap(state.u_prev, state.u);
  std::swap(state.u, state.u_next);
  state.time += model.dt;
  ++state.step_count;
}

// Kinetic damping's reset: velocity zero at t_n in the centred sense, v_n = (u_{n+1} -
// u_{n-1}) / 2dt = 0, by choosing u_{n-1} so that the next update lands on it:
// u_{n-1} = (a u_n + c f_n) / (1 + b). (Merely setting u_{n-1} = u_n zeroes v_{n-1/2} instead and,
// repeated at kinetic-energy peaks, pumps energy into modes with omega dt > 1.)
void restart_at_rest(const Model& model, State& state) {
  compute_elastic_forces(model, state);
  for (size_t v = 0; v < model.vertex_count(); ++v) {
    if (state.vertex_constraint[v] != kVertexFree) {
      state.u_prev[v] = state.u[v];
      continue;
    }
    const VertexCoefficients& k = model.vertex_coefficients[v];
    state.u_prev[v] =
        (k.a * state.u[v] + k.c * (state.force[v] + state.external_force[v])) / (1.0 + k.b);
  }
}

}  // namespace

StepStatus step(const Model& model, State& state) {
  // 0. Never step above the critical step unless an experiment asked for it.
  if (model.dt > model.dt_critical && !model.unsafe_allow_dt_above_critical)
    return kStepDtAboveCritical;
  // (Tool, contact and puncture stages will run here: they set prescribed targets and loads.)
  compute_tet_forces(model, state);                      // 1. element pass: f_e, W, health
  integrate_vertices(model, state);                      // 2. gather + centred difference
  apply_prescribed_vertices(model, state);               // 3. prescribed targets, reaction
  const StepStatus status = check_health(model, state);  // 4. reductions and flags
  if (!(status & kStepNotAdvanced)) commit_step(model, state);  // 5. accept u_{n+1}
  return status;
}

std::string describe_step_status(StepStatus status, const Model& model, const State& state) {
  if (status == kStepOk) return "ok";
  const StepDiagnostics& d = state.diag;
  std::string text;
  char part[256];
  auto add = [&text](const char* s) {
    if (!text.empty()) text += "; ";
    text += s;
  };
  if (status & kStepDtAboveCritical) {
    std::snprintf(part, sizeof part, "dt %.4g s is above the critical step %.4g s%s", model.dt,
                  model.dt_critical,
                  model.unsafe_allow_dt_above_critical ? " (unsafe override)" : ": step refused");
    add(part);
  }
  if (status & kStepNonFinite) {
    if (d.first_nonfinite >= 0)
      std::snprintf(part, sizeof part,
                    "non-finite displacement at vertex %lld: state not advanced (step %lld)",
                    static_cast<long long>(d.first_nonfinite),
                    static_cast<long long>(state.step_count));
    else
      std::snprintf(part, sizeof part, "non-finite energy: state not advanced (step %lld)",
                    static_cast<long long>(state.step_count));
    add(part);
  }
  if (status & kStepEnergyBlowUp) {
    std::snprintf(part, sizeof part,
                  "energy blow-up: kinetic + elastic %.4g J > %g x budget %.4g J (unstable step)",
                  d.kinetic_energy + d.elastic_energy, model.energy_blowup_factor,
                  d.energy_budget);
    add(part);
  }
  if (status & kStepInvertedElement) {
    std::snprintf(part, sizeof part, "%lld inverted element(s) (det F <= 0), first tet %lld",
                  static_cast<long long>(d.inverted_count),
                  static_cast<long long>(d.first_inverted));
    add(part);
  }
  if (status & kStepCollapsingElement) {
    std::snprintf(part, sizeof part,
                  "%lld collapsing element(s) (stretch < 1/sqrt(3)), first tet %lld",
                  static_cast<long long>(d.collapsing_count),
                  static_cast<long long>(d.first_collapsing));
    add(part);
  }
  if (status & kStepClampedElement) {
    std::snprintf(part, sizeof part, "%lld element(s) clamped by the inversion-safe SVK",
                  static_cast<long long>(d.clamped_count));
    add(part);
  }
  return text;
}

AdvanceResult advance(const Model& model, State& state, double duration) {
  AdvanceResult result;
  if (!(duration > 0)) return result;
  // The relative slack keeps 10 * dt from becoming 11 sub-steps through rounding.
  const int64_t steps =
      std::max<int64_t>(1, static_cast<int64_t>(std::ceil(duration / model.dt * (1 - 1e-12))));
  for (int64_t i = 0; i < steps; ++i) {
    const StepStatus s = step(model, state);
    result.status |= s;
    if ((s & kStepNotAdvanced) ||
        ((s & kStepDtAboveCritical) && !model.unsafe_allow_dt_above_critical))
      break;
    ++result.steps;
  }
  result.time_advanced = static_cast<double>(result.steps) * model.dt;
  return result;
}

namespace {

// Residual, reference and constraint force of the configuration whose forces are in
// state.force (static: no inertia).
void static_diagnostics(const Model& model, State& state) {
  StepDiagnostics& d = state.diag;
  double residual_sq = 0, reference_sq = 0;
  Vec3d reaction{0, 0, 0};
  for (size_t v = 0; v < model.vertex_count(); ++v) {
    const Vec3d f_total = state.force[v] + state.external_force[v];
    reference_sq += dot(state.external_force[v], state.external_force[v]);
    if (state.vertex_constraint[v] == kVertexFree) {
      residual_sq += dot(f_total, f_total);
    } else {
      reference_sq += dot(state.force[v], state.force[v]);
      if (state.vertex_constraint[v] == kVertexPrescribed) reaction -= f_total;
    }
  }
  d.residual_norm = std::sqrt(residual_sq);
  d.reference_force_norm = std::sqrt(reference_sq);
  d.constraint_force = reaction;
  d.kinetic_energy = 0;
}

bool converged(const RelaxOptions& o, const StepDiagnostics& d) {
  return d.residual_norm <= o.absolute_tolerance ||
         d.residual_norm <= o.relative_tolerance * d.reference_force_norm;
}

RelaxResult relax_kinetic(const Model& model, State& state, const RelaxOptions& options) {
  RelaxResult result;
  double previous_kinetic = 0;
  for (int64_t i = 0; i < options.max_steps; ++i) {
    const StepStatus s = step(model, state);
    result.status |= s;
    if ((s & kStepNotAdvanced) ||
        ((s & kStepDtAboveCritical) && !model.unsafe_allow_dt_above_critical))
      break;
    ++result.steps;
    // The residual is that of u_n, the configuration the step's forces were evaluated at.
    if (converged(options, state.diag)) {
      result.converged = true;
      break;
    }
    // Kinetic damping: past a kinetic-energy peak, stop every vertex.
    if (state.diag.kinetic_energy < previous_kinetic) {
      restart_at_rest(model, state);
      ++result.kinetic_resets;
      previous_kinetic = 0;
    } else {
      previous_kinetic = state.diag.kinetic_energy;
    }
  }
  return result;
}

RelaxResult relax_adaptive(const Model& model, State& state, const RelaxOptions& options) {
  RelaxResult result;
  const size_t nv = model.vertex_count();
  const double dt = model.dt;
  std::vector<Vec3d> previous_force(nv, Vec3d{0, 0, 0});
  std::copy(state.u.begin(), state.u.end(), state.u_prev.begin());  // start at rest
  double c = 0;  // damping rate [1/s]
  for (int64_t i = 0;; ++i) {
    compute_elastic_forces(model, state);
    result.status |= (state.diag.element_health & kElementInverted ? kStepInvertedElement : 0u) |
                     (state.diag.element_health & kElementCollapsing ? kStepCollapsingElement : 0u) |
                     (state.diag.element_health & kElementClamped ? kStepClampedElement : 0u);
    static_diagnostics(model, state);
    if (converged(options, state.diag)) {
      result.converged = true;
      break;
    }
    if (i >= options.max_steps) break;
    // Rayleigh quotient of the last increment: omega_1^2 ~ du.K du / du.M du.
    if (i > 0) {
      double num = 0, den = 0;
      for (size_t v = 0; v < nv; ++v)
        if (state.vertex_constraint[v] == kVertexFree) {
          const Vec3d du = state.u[v] - state.u_prev[v];
          num -= dot(du, state.force[v] - previous_force[v]);
          den += model.vertex_mass[v] * dot(du, du);
        }
      // A negative quotient (softening, collapse) keeps the last rate.
      if (num > 0 && den > 0) c = std::min(2.0 * std::sqrt(num / den), 2.0 / dt);
    }
    // Damped centred difference with rate c: u+ = u + k1 (u - u-) + k2 f / M.
    const double k1 = (2.0 - c * dt) / (2.0 + c * dt);
    const double k2 = 2.0 * dt * dt / (2.0 + c * dt);
    bool finite = true;
    for (size_t v = 0; v < nv; ++v) {
      Vec3d next{0, 0, 0};
      if (state.vertex_constraint[v] == kVertexFree) {
        const double m = model.vertex_mass[v];
        next = m > 0 ? state.u[v] + k1 * (state.u[v] - state.u_prev[v]) +
                           (k2 / m) * (state.force[v] + state.external_force[v])
                     : state.u[v];
        finite = finite && finite3(next);
      } else if (state.vertex_constraint[v] == kVertexPrescribed) {
        next = state.u[v];  // already at its target
      }
      state.u_next[v] = next;
    }
    if (!finite) {
      result.status |= kStepNonFinite;
      break;
    }
    std::copy(state.force.begin(), state.force.end(), previous_force.begin());
    std::swap(state.u_prev, state.u);
    std::swap(state.u, state.u_next);
    ++result.steps;
  }
  result.residual_norm = state.diag.residual_norm;
  result.reference_force_norm = state.diag.reference_force_norm;
  return result;
}

}  // namespace

RelaxResult relax_to_equilibrium(const Model& model, State& state, const RelaxOptions& options) {
  // Put prescribed vertices at their targets first: the residual is that of u_n, and a state at
  // rest with targets not yet reached would look converged.
  for (size_t i = 0; i < state.prescribed_vertices.size(); ++i) {
    const size_t v = static_cast<size_t>(state.prescribed_vertices[i]);
    state.u[v] = state.u_prev[v] = state.prescribed_displacement[i];
  }
  RelaxResult result = options.method == RelaxMethod::kKineticDamping
                           ? relax_kinetic(model, state, options)
                           : relax_adaptive(model, state, options);
  if (options.method == RelaxMethod::kKineticDamping) {
    // Report the static diagnostics of the final configuration.
    compute_elastic_forces(model, state);
    static_diagnostics(model, state);
    result.residual_norm = state.diag.residual_norm;
    result.reference_force_norm = state.diag.reference_force_norm;
  }
  // The answer is a configuration at rest: a following step() starts from zero velocity.
  std::copy(state.u.begin(), state.u.end(), state.u_prev.begin());
  state.energy_budget_valid = false;
  return result;
}

}  // namespace zona
