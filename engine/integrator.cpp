// The explicit step as a table of contents, its stages, sub-stepping and dynamic relaxation.
#include "engine/integrator.h"

#include <algorithm>
#include <cmath>

#include "engine/forces_cpu.h"

namespace zona {
namespace {

struct PassContext {
  const Model* model;
  State* state;
};

inline bool finite3(Vec3d a) { return std::isfinite(a.x) && std::isfinite(a.y) && std::isfinite(a.z); }

// Stage 2, per chunk of vertices: gather the elastic force, then the centred-difference update
// u+ = a u - b u- + c (f_el + f_ext) of free vertices (DESIGN.md section 3); fixed vertices go to
// zero; prescribed ones are written by apply_prescribed_vertices.
void integrate_chunks(void* context, int64_t chunk_begin, int64_t chunk_end) {
  const Model& m = *static_cast<PassContext*>(context)->model;
  State& s = *static_cast<PassContext*>(context)->state;
  const int64_t nv = static_cast<int64_t>(m.vertex_count());
  const double half_inv_dt = 0.5 / m.dt;
  for (int64_t chunk = chunk_begin; chunk < chunk_end; ++chunk) {
    VertexChunkResult r;
    const int64_t end = std::min(nv, (chunk + 1) * kVertexChunk);
    for (int64_t vi = chunk * kVertexChunk; vi < end; ++vi) {
      const size_t v = static_cast<size_t>(vi);
      const Vec3d f = gather_vertex_force(m, s, v);
      const Vec3d f_ext = s.external_force[v];
      s.force[v] = f;
      Vec3d next = s.u[v];  // prescribed: overwritten by the next stage
      if (s.vertex_constraint[v] == kVertexFree) {
        const VertexCoefficients& k = m.vertex_coefficients[v];
        const Vec3d f_total = f + f_ext;
        const Vec3d up = s.u_prev[v];
        next = k.a * s.u[v] - k.b * up + k.c * f_total;
        const Vec3d du = next - up;  // = 2 dt v_n
        const Vec3d vel = half_inv_dt * du;
        r.kinetic_energy += 0.5 * m.vertex_mass[v] * dot(vel, vel);
        r.input_work += 0.5 * dot(f_ext, du);
        r.residual_sq += dot(f_total, f_total);
      } else {
        if (s.vertex_constraint[v] == kVertexFixed) next = Vec3d{0, 0, 0};
        r.reference_sq += dot(f, f);
      }
      r.reference_sq += dot(f_ext, f_ext);
      if (!finite3(next) && r.first_nonfinite < 0) r.first_nonfinite = vi;
      s.u_next[v] = next;
    }
    s.vertex_chunks[static_cast<size_t>(chunk)] = r;
  }
}

// Stage 2: the vertex pass over the pool.
void integrate_vertices(const Model& model, State& state) {
  PassContext context{&model, &state};
  state.pool->run(static_cast<int64_t>(state.vertex_chunks.size()), &integrate_chunks, &context);
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
    std::snprintf(part, sizeof part,
                  "non-finite displacement at vertex %lld: state not advanced (step %lld)",
                  static_cast<long long>(d.first_nonfinite),
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

RelaxResult relax_to_equilibrium(const Model& model, State& state, const RelaxOptions& options) {
  RelaxResult result;
  double previous_kinetic = 0;
  for (int64_t i = 0; i < options.max_steps; ++i) {
    const StepStatus s = step(model, state);
    result.status |= s;
    if ((s & kStepNotAdvanced) ||
        ((s & kStepDtAboveCritical) && !model.unsafe_allow_dt_above_critical))
      break;
    ++result.steps;
    const StepDiagnostics& d = state.diag;
    result.residual_norm = d.residual_norm;
    result.reference_force_norm = d.reference_force_norm;
    // The residual is that of u_n, the configuration the step's forces were evaluated at.
    if (d.residual_norm <= options.absolute_tolerance ||
        d.residual_norm <= options.relative_tolerance * d.reference_force_norm) {
      result.converged = true;
      break;
    }
    // Kinetic damping: past a kinetic-energy peak, stop every vertex (u_{n-1} = u_n).
    if (d.kinetic_energy < previous_kinetic) {
      std::copy(state.u.begin(), state.u.end(), state.u_prev.begin());
      ++result.kinetic_resets;
      previous_kinetic = 0;
    } else {
      previous_kinetic = d.kinetic_energy;
    }
  }
  return result;
}

}  // namespace zona
