// The particle model (Asgari et al.) on the GPU: the same per-spring / per-triangle functions as the
// CPU reference (engine/particles/particle_element.h) in thin kernels, float64 throughout. One sub-step is
// six launches in stream order: triangle volume partials, the volume and pressure, the membrane
// pass (forces gathered per particle in CSR order, then the update), the centre particle (its
// springs' reactions reduced in a fixed order), the prescribed particles, and a one-block finish
// that reduces the diagnostics and decides whether the sub-step is committed. Every reduction
// has a fixed order, so runs are bitwise reproducible; they differ from the CPU's serial sums
// only by rounding. u rotates over three buffers: a sub-step that produced a non-finite value
// is not committed (the host reads how many were) and the rest of the call does nothing, so
// u_n and u_{n-1} stay intact, as zona::step promises.
#include <cuda_runtime.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <string>
#include <vector>

#include "engine/particles/particle_element.h"
#include "engine/fem/state.h"
#include "kernels/cuda_check.h"
#include "kernels/device_buffer.h"
#include "kernels/particle_backend.h"

namespace zona {
namespace cuda {
namespace {

constexpr int kBlock = 128;   // particle and triangle passes
constexpr int kReduce = 256;  // one-block reductions (power of two)

// Scalars of the current call; the host reads them once per step() call.
struct ParticleScalars {
  double volume;            // at u_n of the current sub-step [m^3]
  double pressure;          // [Pa]
  double hydraulic_energy;  // [J]
  double centre_kinetic, centre_work, centre_residual_sq;
  double kinetic, elastic, residual_norm, energy_budget;  // the last committed sub-step
  Vec3d constraint_force;
  int budget_valid;
  int nonfinite;  // raised by any pass of the current sub-step
  int halted;     // a sub-step was not advanced: the rest of the call does nothing
  int committed;  // sub-steps committed in this call
  uint32_t status;
};

// Device pointers and constants of the immutable model.
struct View {
  int membrane_count, centre, triangle_count;
  const Vec3d* rest;
  const int32_t* triangles;  // 3 per triangle
  const int32_t *nb_offsets, *nb_index;
  const double *nb_rest, *nb_k, *nb_c;
  const double *c_rest, *c_k, *c_c;
  const int32_t *tri_offsets, *tri_index;
  const double* mass;
  const Vec3d* damping;
  const uint8_t* constraint;
  double rest_volume, beta, dt;
};

// Sum over the block in a fixed tree order; every thread gets the total.
__device__ double block_sum(double v, double* shared) {
  const int t = static_cast<int>(threadIdx.x);
  shared[t] = v;
  __syncthreads();
  for (int s = static_cast<int>(blockDim.x) / 2; s > 0; s >>= 1) {
    if (t < s) shared[t] += shared[t + s];
    __syncthreads();
  }
  const double total = shared[0];
  __syncthreads();
  return total;
}

__device__ bool finite3(Vec3d a) { return isfinite(a.x) && isfinite(a.y) && isfinite(a.z); }

__device__ Vec3d position(const View& p, const Vec3d* u, int i) { return p.rest[i] + u[i]; }

// 1. Volume partials: one per block of triangles.
__global__ void volume_partial_kernel(View p, const Vec3d* u, double* partial) {
  __shared__ double shared[kBlock];
  const int t = static_cast<int>(blockIdx.x * blockDim.x + threadIdx.x);
  double v = 0;
  if (t < p.triangle_count) {
    const int a = p.triangles[3 * t], b = p.triangles[3 * t + 1], c = p.triangles[3 * t + 2];
    v = triangle_volume_term(position(p, u, a), position(p, u, b), position(p, u, c));
  }
  const double total = block_sum(v, shared);
  if (threadIdx.x == 0) partial[blockIdx.x] = total;
}

// 2. Volume, pressure (eq. 6) and the interior's energy.
__global__ void volume_final_kernel(View p, const double* partial, int count, ParticleScalars* sc) {
  __shared__ double shared[kReduce];
  double v = 0;
  for (int i = static_cast<int>(threadIdx.x); i < count; i += kReduce) v += partial[i];
  const double volume = block_sum(v, shared);
  if (threadIdx.x == 0) {
    sc->volume = volume;
    sc->pressure = hydraulic_pressure(volume, p.rest_volume, p.beta);
    sc->hydraulic_energy = hydraulic_energy(volume, p.rest_volume, p.beta);
  }
}

// 3. Membrane particles: springs, dashpots, centre spring and pressure (engine/particles/particle_model.cpp
//    particle_forces, same order), then the centred difference with eq. 5's damping.
__global__ void membrane_kernel(View p, const Vec3d* u, const Vec3d* up, Vec3d* un, Vec3d* force,
                                const Vec3d* ext, double inv_dt, bool integrate, Vec3d* centre_part,
                                double* energy_part, double* kinetic_part, double* work_part,
                                double* residual_part, ParticleScalars* sc) {
  const int i = static_cast<int>(blockIdx.x * blockDim.x + threadIdx.x);
  if (i >= p.membrane_count) return;
  if (integrate && sc->halted) return;
  const Vec3d xi = position(p, u, i), vi = inv_dt * (u[i] - up[i]);
  const int c = p.centre;
  const Vec3d xc = position(p, u, c), vc = inv_dt * (u[c] - up[c]);
  Vec3d f{0, 0, 0};
  double energy = 0;
  for (int e = p.nb_offsets[i]; e < p.nb_offsets[i + 1]; ++e) {
    const int j = p.nb_index[e];
    const Vec3d xj = position(p, u, j);
    f += particle_spring_force(xi, xj, vi, inv_dt * (u[j] - up[j]), p.nb_rest[e], p.nb_k[e], p.nb_c[e]);
    if (j > i) energy += particle_spring_energy(xi, xj, p.nb_rest[e], p.nb_k[e]);
  }
  const Vec3d fc = particle_spring_force(xi, xc, vi, vc, p.c_rest[i], p.c_k[i], p.c_c[i]);
  f += fc;
  energy += particle_spring_energy(xi, xc, p.c_rest[i], p.c_k[i]);
  Vec3d g{0, 0, 0};
  for (int e = p.tri_offsets[i]; e < p.tri_offsets[i + 1]; ++e) {
    const int t = p.tri_index[e];
    const int a = p.triangles[3 * t], b = p.triangles[3 * t + 1], cc = p.triangles[3 * t + 2];
    g += triangle_area_vector(position(p, u, a), position(p, u, b), position(p, u, cc));
  }
  f += (sc->pressure / 3.0) * g;
  force[i] = f;
  centre_part[i] = fc;
  energy_part[i] = energy;
  if (!integrate) return;

  double kinetic = 0, work = 0, residual = 0;
  Vec3d next = u[i];  // prescribed: written by prescribed_kernel
  const uint8_t kind = p.constraint[i];
  if (kind == kVertexFree) {
    const Vec3d e = ext[i], total = f + e, un0 = u[i], up0 = up[i], b = p.damping[i];
    const double m = p.mass[i];
    next = Vec3d{particle_update(un0.x, up0.x, total.x, m, b.x, p.dt),
                 particle_update(un0.y, up0.y, total.y, m, b.y, p.dt),
                 particle_update(un0.z, up0.z, total.z, m, b.z, p.dt)};
    const Vec3d du = next - up0, vel = (0.5 * inv_dt) * du;
    kinetic = 0.5 * m * dot(vel, vel);
    work = 0.5 * dot(e, du);
    residual = dot(total, total);
  } else if (kind == kVertexFixed) {
    next = Vec3d{0, 0, 0};
  }
  if (!finite3(next)) atomicOr(&sc->nonfinite, 1);
  un[i] = next;
  kinetic_part[i] = kinetic;
  work_part[i] = work;
  residual_part[i] = residual;
}

// 4. The centre particle: minus the sum of its springs' forces on the membrane, then its update.
__global__ void centre_kernel(View p, const Vec3d* u, const Vec3d* up, Vec3d* un, Vec3d* force,
                              const Vec3d* ext, const Vec3d* centre_part, bool integrate,
                              ParticleScalars* sc) {
  __shared__ double shared[kReduce];
  if (integrate && sc->halted) return;
  Vec3d sum{0, 0, 0};
  for (int i = static_cast<int>(threadIdx.x); i < p.membrane_count; i += kReduce) sum -= centre_part[i];
  const Vec3d f{block_sum(sum.x, shared), block_sum(sum.y, shared), block_sum(sum.z, shared)};
  if (threadIdx.x != 0) return;
  const int c = p.centre;
  force[c] = f;
  if (!integrate) return;
  double kinetic = 0, work = 0, residual = 0;
  Vec3d next = u[c];
  if (p.constraint[c] == kVertexFree) {
    const Vec3d e = ext[c], total = f + e, b = p.damping[c];
    const double m = p.mass[c];
    next = Vec3d{particle_update(u[c].x, up[c].x, total.x, m, b.x, p.dt),
                 particle_update(u[c].y, up[c].y, total.y, m, b.y, p.dt),
                 particle_update(u[c].z, up[c].z, total.z, m, b.z, p.dt)};
    const Vec3d du = next - up[c], vel = (0.5 / p.dt) * du;
    kinetic = 0.5 * m * dot(vel, vel);
    work = 0.5 * dot(e, du);
    residual = dot(total, total);
  } else if (p.constraint[c] == kVertexFixed) {
    next = Vec3d{0, 0, 0};
  }
  if (!finite3(next)) atomicOr(&sc->nonfinite, 1);
  un[c] = next;
  sc->centre_kinetic = kinetic;
  sc->centre_work = work;
  sc->centre_residual_sq = residual;
}

// 5. Prescribed particles at start + (s + 1) delta; the constraint force M a + B v - f - f_ext.
__global__ void prescribed_kernel(View p, const int32_t* index, const Vec3d* start, const Vec3d* delta,
                                  double fraction, int count, const Vec3d* u, const Vec3d* up,
                                  Vec3d* un, const Vec3d* force, const Vec3d* ext, Vec3d* reaction,
                                  double* kinetic, double* work, ParticleScalars* sc) {
  const int k = static_cast<int>(blockIdx.x * blockDim.x + threadIdx.x);
  if (k >= count || sc->halted) return;
  const int v = index[k];
  const Vec3d next = start[k] + fraction * delta[k];
  un[v] = next;
  const double inv_dt = 1.0 / p.dt;
  const Vec3d du = next - up[v], vel = (0.5 * inv_dt) * du,
              acc = (inv_dt * inv_dt) * (next - 2.0 * u[v] + up[v]);
  const Vec3d b = p.damping[v];
  const Vec3d r = p.mass[v] * acc + Vec3d{b.x * vel.x, b.y * vel.y, b.z * vel.z} - force[v] - ext[v];
  reaction[k] = r;
  kinetic[k] = 0.5 * p.mass[v] * dot(vel, vel);
  work[k] = 0.5 * dot(r + ext[v], du);
  if (!finite3(next)) atomicOr(&sc->nonfinite, 1);
}

// 6. Diagnostics in a fixed order and the verdict of zona::step's rules.
__global__ void finish_kernel(View p, const double* energy_part, const double* kinetic_part,
                              const double* work_part, const double* residual_part,
                              const Vec3d* reaction, const double* p_kinetic, const double* p_work,
                              int count, double blowup_factor, double energy_floor,
                              ParticleScalars* sc) {
  __shared__ double shared[kReduce];
  if (sc->halted) return;
  double e = 0, ke = 0, w = 0, r = 0;
  Vec3d cf{0, 0, 0};
  for (int i = static_cast<int>(threadIdx.x); i < p.membrane_count; i += kReduce) {
    e += energy_part[i];
    ke += kinetic_part[i];
    w += work_part[i];
    r += residual_part[i];
  }
  for (int k = static_cast<int>(threadIdx.x); k < count; k += kReduce) {
    ke += p_kinetic[k];
    w += p_work[k];
    cf += reaction[k];
  }
  e = block_sum(e, shared);
  ke = block_sum(ke, shared);
  w = block_sum(w, shared);
  r = block_sum(r, shared);
  cf = Vec3d{block_sum(cf.x, shared), block_sum(cf.y, shared), block_sum(cf.z, shared)};
  if (threadIdx.x != 0) return;
  const double elastic = e + sc->hydraulic_energy;
  const double kinetic = ke + sc->centre_kinetic;
  const double work = w + sc->centre_work;
  sc->kinetic = kinetic;
  sc->elastic = elastic;
  sc->residual_norm = sqrt(r + sc->centre_residual_sq);
  sc->constraint_force = cf;
  const double energy = kinetic + elastic;
  if (sc->nonfinite || !isfinite(energy)) {
    sc->status |= kStepNonFinite;
    sc->halted = 1;
    return;
  }
  if (!sc->budget_valid) {
    sc->energy_budget = energy;
    sc->budget_valid = 1;
  }
  sc->energy_budget += work;
  if (energy > blowup_factor * fmax(sc->energy_budget, energy_floor)) sc->status |= kStepEnergyBlowUp;
  ++sc->committed;
}

// Start of a call: per-call flags, and the prescribed path from the current targets.
__global__ void begin_call_kernel(const Vec3d* current, const Vec3d* target, Vec3d* start,
                                  Vec3d* delta, int count, double substeps, ParticleScalars* sc) {
  const int k = static_cast<int>(blockIdx.x * blockDim.x + threadIdx.x);
  if (k == 0) {
    sc->halted = 0;
    sc->nonfinite = 0;
    sc->committed = 0;
    sc->status = 0;
  }
  if (k >= count) return;
  start[k] = current[k];
  delta[k] = (target[k] - current[k]) / substeps;
}

// End of a call: where the prescribed particles are now (the last committed sub-step).
__global__ void end_call_kernel(Vec3d* current, const Vec3d* start, const Vec3d* delta, int count,
                                const ParticleScalars* sc) {
  const int k = static_cast<int>(blockIdx.x * blockDim.x + threadIdx.x);
  if (k >= count) return;
  current[k] = start[k] + static_cast<double>(sc->committed) * delta[k];
}

int blocks_for(int count, int block) { return std::max(1, (count + block - 1) / block); }

class ParticleCudaBackend final : public Backend {
 public:
  ParticleCudaBackend(const ParticleModel& particles, const BackendOptions& options, std::string device)
      : pm_(particles), options_(options), device_(std::move(device)) {}

  const char* name() const override { return "cuda"; }
  std::string description() const override {
    return "particles: cuda on " + device_ + ", float64, fixed-order reductions";
  }

  Status upload(const Model& model, const State& state) override {
    const size_t n = pm_.particle_count();
    if (model.vertex_count() != n || state.u.size() != n)
      return make_error("particle cuda backend: the model has %zu vertices, the state %zu, the "
                        "particle model %zu", model.vertex_count(), state.u.size(), n);
    ZONA_CUDA_TRY(cudaSetDevice(options_.device));
    if (!static_ready_) {
      if (Status s = upload_static(); !s) return s;
      static_ready_ = true;
    }
    model_ = &model;
    // Dynamic state: u_{n-1} in slot 0, u_n in slot 1.
    rotation_ = 0;
    ZONA_CUDA_TRY(cudaMemcpy(u_[0].data(), state.u_prev.data(), n * sizeof(Vec3d), cudaMemcpyHostToDevice));
    ZONA_CUDA_TRY(cudaMemcpy(u_[1].data(), state.u.data(), n * sizeof(Vec3d), cudaMemcpyHostToDevice));
    ZONA_CUDA_TRY(cudaMemcpy(external_.data(), state.external_force.data(), n * sizeof(Vec3d),
                             cudaMemcpyHostToDevice));
    ZONA_CUDA_TRY(cudaMemcpy(constraint_.data(), state.vertex_constraint.data(), n, cudaMemcpyHostToDevice));
    prescribed_count_ = static_cast<int>(state.prescribed_vertices.size());
    if (state.prescribed_displacement.size() != state.prescribed_vertices.size())
      return make_error("particle cuda backend: %zu prescribed targets for %zu prescribed vertices",
                        state.prescribed_displacement.size(), state.prescribed_vertices.size());
    if (prescribed_count_ > 0) {
      const size_t bytes = size_t(prescribed_count_) * sizeof(Vec3d);
      ZONA_CUDA_TRY(cudaMemcpy(p_index_.data(), state.prescribed_vertices.data(),
                               size_t(prescribed_count_) * sizeof(int32_t), cudaMemcpyHostToDevice));
      ZONA_CUDA_TRY(cudaMemcpy(p_current_.data(), state.prescribed_displacement.data(), bytes, cudaMemcpyHostToDevice));
      ZONA_CUDA_TRY(cudaMemcpy(p_target_.data(), state.prescribed_displacement.data(), bytes, cudaMemcpyHostToDevice));
    }
    if (options_.poison_outputs) {
      // Every output a pass must write starts as NaN (0xFF bytes), so a forgotten entry shows.
      ZONA_CUDA_TRY(cudaMemset(u_[2].data(), 0xFF, n * sizeof(Vec3d)));
      ZONA_CUDA_TRY(cudaMemset(force_.data(), 0xFF, n * sizeof(Vec3d)));
      ZONA_CUDA_TRY(cudaMemset(centre_part_.data(), 0xFF,
                               size_t(pm_.membrane_count) * sizeof(Vec3d)));  // (membrane count)
    }
    ParticleScalars sc{};
    sc.energy_budget = state.diag.energy_budget;
    sc.budget_valid = state.energy_budget_valid ? 1 : 0;
    sc.kinetic = state.diag.kinetic_energy;
    sc.elastic = state.diag.elastic_energy;
    sc.constraint_force = state.diag.constraint_force;
    ZONA_CUDA_TRY(cudaMemcpy(scalars_.data(), &sc, sizeof sc, cudaMemcpyHostToDevice));
    *host_scalars_.data() = sc;
    time_ = state.time;
    step_count_ = state.step_count;
    // The copies above ran on the legacy stream from pageable memory: cudaMemcpy may return
    // before their DMA lands, and the step's non-blocking stream does not wait for the legacy
    // one. Without this the first kernels of the next step can read the old state.
    ZONA_CUDA_TRY(cudaDeviceSynchronize());
    return {};
  }

  Status set_external_forces(std::span<const Vec3d> forces) override {
    if (!model_) return make_error("particle cuda backend: nothing uploaded");
    const size_t n = pm_.particle_count();
    if (forces.size() != n)
      return make_error("particle cuda backend: %zu loads given for %zu particles", forces.size(), n);
    // The step stream first (the copy below is on the legacy stream), then a blocking copy.
    ZONA_CUDA_TRY(cudaStreamSynchronize(stream_.get()));
    ZONA_CUDA_TRY(cudaMemcpy(external_.data(), forces.data(), n * sizeof(Vec3d),
                             cudaMemcpyHostToDevice));
    return {};
  }

  Status set_prescribed_targets(std::span<const Vec3d> targets) override {
    if (!model_) return make_error("particle cuda backend: nothing uploaded");
    if (targets.size() != size_t(prescribed_count_))
      return make_error("particle cuda backend: %zu prescribed targets given for %d prescribed "
                        "vertices", targets.size(), prescribed_count_);
    for (size_t k = 0; k < targets.size(); ++k)
      if (!(std::isfinite(targets[k].x) && std::isfinite(targets[k].y) && std::isfinite(targets[k].z)))
        return make_error("particle cuda backend: prescribed target %zu is not finite", k);
    if (!targets.empty())
      ZONA_CUDA_TRY(cudaMemcpyAsync(p_target_.data(), targets.data(), targets.size() * sizeof(Vec3d),
                                    cudaMemcpyHostToDevice, stream_.get()));
    return {};
  }

  StepReport step(int substeps) override {
    StepReport report;
    if (!model_ || substeps < 1) return report;
    if (model_->dt > model_->dt_critical && !model_->unsafe_allow_dt_above_critical) {
      report.status = kStepDtAboveCritical;
      return report;
    }
    const cudaStream_t s = stream_.get();
    const View p = view();
    const int nm = pm_.membrane_count, np = prescribed_count_;
    bool ok = ZONA_CUDA_STEP(log_, cudaEventRecord(start_.get(), s));
    begin_call_kernel<<<blocks_for(np, kBlock), kBlock, 0, s>>>(
        p_current_.data(), p_target_.data(), p_start_.data(), p_delta_.data(), np,
        static_cast<double>(substeps), scalars_.data());
    const double inv_dt = 1.0 / model_->dt;
    for (int k = 0; k < substeps; ++k) {
      const int r = (rotation_ + k) % 3;
      Vec3d* up = u_[r].data();
      Vec3d* u = u_[(r + 1) % 3].data();
      Vec3d* un = u_[(r + 2) % 3].data();
      volume_partial_kernel<<<volume_blocks_, kBlock, 0, s>>>(p, u, partial_.data());
      volume_final_kernel<<<1, kReduce, 0, s>>>(p, partial_.data(), volume_blocks_, scalars_.data());
      membrane_kernel<<<blocks_for(nm, kBlock), kBlock, 0, s>>>(
          p, u, up, un, force_.data(), external_.data(), inv_dt, true, centre_part_.data(),
          energy_part_.data(), kinetic_part_.data(), work_part_.data(), residual_part_.data(),
          scalars_.data());
      centre_kernel<<<1, kReduce, 0, s>>>(p, u, up, un, force_.data(), external_.data(),
                                          centre_part_.data(), true, scalars_.data());
      if (np > 0)
        prescribed_kernel<<<blocks_for(np, kBlock), kBlock, 0, s>>>(
            p, p_index_.data(), p_start_.data(), p_delta_.data(), static_cast<double>(k + 1), np,
            u, up, un, force_.data(), external_.data(), p_reaction_.data(), p_kinetic_.data(),
            p_work_.data(), scalars_.data());
      finish_kernel<<<1, kReduce, 0, s>>>(p, energy_part_.data(), kinetic_part_.data(),
                                          work_part_.data(), residual_part_.data(),
                                          p_reaction_.data(), p_kinetic_.data(), p_work_.data(), np,
                                          model_->energy_blowup_factor, model_->energy_floor,
                                          scalars_.data());
      // The next sub-step's passes start with nonfinite cleared (finish has read it).
      ok = ok && ZONA_CUDA_STEP(log_, cudaMemsetAsync(&scalars_.data()->nonfinite, 0, sizeof(int), s));
    }
    end_call_kernel<<<blocks_for(np, kBlock), kBlock, 0, s>>>(p_current_.data(), p_start_.data(),
                                                              p_delta_.data(), np, scalars_.data());
    ok = ok && ZONA_CUDA_STEP(log_, cudaGetLastError());
    ok = ok && ZONA_CUDA_STEP(log_, cudaEventRecord(stop_.get(), s));
    ok = ok && ZONA_CUDA_STEP(log_, cudaMemcpyAsync(host_scalars_.data(), scalars_.data(),
                                                     sizeof(ParticleScalars), cudaMemcpyDeviceToHost, s));
    ok = ok && ZONA_CUDA_STEP(log_, cudaStreamSynchronize(s));
    if (!ok) {
      report.status = kStepNonFinite;
      return report;
    }
    const ParticleScalars& sc = *host_scalars_.data();
    rotation_ = (rotation_ + sc.committed) % 3;
    // One addition per sub-step, as the CPU's commit does: the same bits of simulated time.
    for (int k = 0; k < sc.committed; ++k) time_ += model_->dt;
    step_count_ += sc.committed;
    report.status = sc.status;
    if (model_->dt > model_->dt_critical) report.status |= kStepDtAboveCritical;
    report.steps = sc.committed;
    report.constraint_force = sc.constraint_force;
    report.kinetic_energy = sc.kinetic;
    report.elastic_energy = sc.elastic;
    report.residual_norm = sc.residual_norm;
    report.device_ms = cuda::elapsed_ms(start_, stop_);
    return report;
  }

  Status download(State& state) override {
    if (!model_) return make_error("particle cuda backend: nothing uploaded");
    const size_t n = pm_.particle_count();
    ZONA_CUDA_TRY(cudaStreamSynchronize(stream_.get()));
    ZONA_CUDA_TRY(cudaMemcpy(state.u_prev.data(), u_[rotation_].data(), n * sizeof(Vec3d), cudaMemcpyDeviceToHost));
    ZONA_CUDA_TRY(cudaMemcpy(state.u.data(), u_[(rotation_ + 1) % 3].data(), n * sizeof(Vec3d),
                             cudaMemcpyDeviceToHost));
    ZONA_CUDA_TRY(cudaMemcpy(state.force.data(), force_.data(), n * sizeof(Vec3d), cudaMemcpyDeviceToHost));
    if (prescribed_count_ > 0 && state.prescribed_displacement.size() == size_t(prescribed_count_))
      ZONA_CUDA_TRY(cudaMemcpy(state.prescribed_displacement.data(), p_current_.data(),
                               size_t(prescribed_count_) * sizeof(Vec3d), cudaMemcpyDeviceToHost));
    const ParticleScalars& sc = *host_scalars_.data();
    state.time = time_;
    state.step_count = step_count_;
    state.diag.elastic_energy = sc.elastic;
    state.diag.kinetic_energy = sc.kinetic;
    state.diag.constraint_force = sc.constraint_force;
    state.diag.residual_norm = sc.residual_norm;
    state.diag.energy_budget = sc.energy_budget;
    state.energy_budget_valid = sc.budget_valid != 0;
    return {};
  }

  Status elastic_forces(std::span<const Vec3d> u, std::span<Vec3d> f) override {
    if (!model_) return make_error("particle cuda backend: nothing uploaded");
    const size_t n = pm_.particle_count();
    if (u.size() != n || f.size() != n)
      return make_error("particle cuda backend: elastic_forces needs %zu vertices, got u %zu, f %zu",
                        n, u.size(), f.size());
    const cudaStream_t s = stream_.get();
    const View p = view();
    ZONA_CUDA_TRY(cudaMemcpyAsync(scratch_u_.data(), u.data(), n * sizeof(Vec3d), cudaMemcpyHostToDevice, s));
    volume_partial_kernel<<<volume_blocks_, kBlock, 0, s>>>(p, scratch_u_.data(), partial_.data());
    volume_final_kernel<<<1, kReduce, 0, s>>>(p, partial_.data(), volume_blocks_, scalars_.data());
    membrane_kernel<<<blocks_for(pm_.membrane_count, kBlock), kBlock, 0, s>>>(
        p, scratch_u_.data(), scratch_u_.data(), nullptr, scratch_f_.data(), external_.data(), 0.0,
        false, centre_part_.data(), energy_part_.data(), nullptr, nullptr, nullptr, scalars_.data());
    centre_kernel<<<1, kReduce, 0, s>>>(p, scratch_u_.data(), scratch_u_.data(), nullptr,
                                        scratch_f_.data(), external_.data(), centre_part_.data(),
                                        false, scalars_.data());
    ZONA_CUDA_TRY_LAUNCH();
    ZONA_CUDA_TRY(cudaMemcpyAsync(f.data(), scratch_f_.data(), n * sizeof(Vec3d), cudaMemcpyDeviceToHost, s));
    ZONA_CUDA_TRY(cudaStreamSynchronize(s));
    return {};
  }

  Result<StateSummary> summarize() override {
    if (!model_) return make_error("particle cuda backend: nothing uploaded");
    const size_t n = pm_.particle_count();
    std::vector<Vec3d> u(n), up(n);
    ZONA_CUDA_TRY(cudaStreamSynchronize(stream_.get()));
    ZONA_CUDA_TRY(cudaMemcpy(up.data(), u_[rotation_].data(), n * sizeof(Vec3d), cudaMemcpyDeviceToHost));
    ZONA_CUDA_TRY(cudaMemcpy(u.data(), u_[(rotation_ + 1) % 3].data(), n * sizeof(Vec3d), cudaMemcpyDeviceToHost));
    StateSummary s;
    const double inv_dt = 1.0 / model_->dt;
    for (size_t v = 0; v < n; ++v) {
      s.max_displacement = std::max(s.max_displacement, norm(u[v]));
      const Vec3d vel = inv_dt * (u[v] - up[v]);
      s.kinetic_energy += 0.5 * pm_.mass[v] * dot(vel, vel);
    }
    return s;
  }

 private:
  Status upload_static() {
    const size_t n = pm_.particle_count(), nm = size_t(pm_.membrane_count);
    if (Status s = stream_.create(); !s) return s;
    if (Status s = start_.create(true); !s) return s;
    if (Status s = stop_.create(true); !s) return s;
    std::vector<int32_t> triangles;
    triangles.reserve(3 * pm_.triangles.size());
    for (const Triangle& t : pm_.triangles) triangles.insert(triangles.end(), t.begin(), t.end());
    Status s;
    auto check = [&s](Status next) {
      if (s && !next) s = next;
    };
    check(rest_.upload(pm_.rest_positions, "particle rest positions"));
    check(triangles_.upload(triangles, "particle triangles"));
    check(nb_offsets_.upload(pm_.neighbor_offsets, "spring offsets"));
    check(nb_index_.upload(pm_.neighbor_index, "spring neighbours"));
    check(nb_rest_.upload(pm_.neighbor_rest_length, "spring free lengths"));
    check(nb_k_.upload(pm_.neighbor_stiffness, "spring stiffness"));
    check(nb_c_.upload(pm_.neighbor_damping, "dashpots"));
    check(c_rest_.upload(pm_.centre_rest_length, "centre free lengths"));
    check(c_k_.upload(pm_.centre_stiffness, "centre stiffness"));
    check(c_c_.upload(pm_.centre_damping, "centre dashpots"));
    check(tri_offsets_.upload(pm_.triangle_offsets, "triangle offsets"));
    check(tri_index_.upload(pm_.particle_triangles, "particle triangles"));
    check(mass_.upload(pm_.mass, "particle masses"));
    check(damping_.upload(pm_.damping, "particle damping"));
    for (auto& b : u_) check(b.allocate(n, "displacements"));
    check(force_.allocate(n, "forces"));
    check(external_.allocate(n, "loads"));
    check(constraint_.allocate(n, "constraints"));
    check(centre_part_.allocate(nm, "centre spring forces"));
    check(energy_part_.allocate(nm, "energies"));
    check(kinetic_part_.allocate(nm, "kinetic energies"));
    check(work_part_.allocate(nm, "work"));
    check(residual_part_.allocate(nm, "residuals"));
    volume_blocks_ = blocks_for(static_cast<int>(pm_.triangles.size()), kBlock);
    check(partial_.allocate(size_t(volume_blocks_), "volume partials"));
    // Prescribed arrays at full capacity: a new contact set never reallocates.
    check(p_index_.allocate(n, "prescribed vertices"));
    for (DeviceBuffer<Vec3d>* b : {&p_current_, &p_target_, &p_start_, &p_delta_, &p_reaction_})
      check(b->allocate(n, "prescribed targets"));
    check(p_kinetic_.allocate(n, "prescribed kinetic energies"));
    check(p_work_.allocate(n, "prescribed work"));
    check(scratch_u_.allocate(n, "scratch displacements"));
    check(scratch_f_.allocate(n, "scratch forces"));
    check(scalars_.allocate(1, "particle scalars"));
    check(host_scalars_.allocate(1, "particle scalars (host)"));
    return s;
  }

  View view() {
    View p{};
    p.membrane_count = pm_.membrane_count;
    p.centre = pm_.centre;
    p.triangle_count = static_cast<int>(pm_.triangles.size());
    p.rest = rest_.data();
    p.triangles = triangles_.data();
    p.nb_offsets = nb_offsets_.data();
    p.nb_index = nb_index_.data();
    p.nb_rest = nb_rest_.data();
    p.nb_k = nb_k_.data();
    p.nb_c = nb_c_.data();
    p.c_rest = c_rest_.data();
    p.c_k = c_k_.data();
    p.c_c = c_c_.data();
    p.tri_offsets = tri_offsets_.data();
    p.tri_index = tri_index_.data();
    p.mass = mass_.data();
    p.damping = damping_.data();
    p.constraint = constraint_.data();
    p.rest_volume = pm_.rest_volume;
    p.beta = pm_.compressibility;
    p.dt = model_->dt;
    return p;
  }

  const ParticleModel& pm_;
  BackendOptions options_;
  std::string device_;
  const Model* model_ = nullptr;
  bool static_ready_ = false;
  Stream stream_;
  Event start_, stop_;
  StepErrorLog log_;
  DeviceBuffer<Vec3d> rest_;
  DeviceBuffer<int32_t> triangles_, nb_offsets_, nb_index_, tri_offsets_, tri_index_;
  DeviceBuffer<double> nb_rest_, nb_k_, nb_c_, c_rest_, c_k_, c_c_, mass_;
  DeviceBuffer<Vec3d> damping_;
  DeviceBuffer<Vec3d> u_[3];
  DeviceBuffer<Vec3d> force_, external_, centre_part_, scratch_u_, scratch_f_;
  DeviceBuffer<uint8_t> constraint_;
  DeviceBuffer<double> energy_part_, kinetic_part_, work_part_, residual_part_, partial_;
  DeviceBuffer<int32_t> p_index_;
  DeviceBuffer<Vec3d> p_current_, p_target_, p_start_, p_delta_, p_reaction_;
  DeviceBuffer<double> p_kinetic_, p_work_;
  DeviceBuffer<ParticleScalars> scalars_;
  PinnedBuffer<ParticleScalars> host_scalars_;
  int volume_blocks_ = 1;
  int rotation_ = 0;
  int prescribed_count_ = 0;
  double time_ = 0;
  int64_t step_count_ = 0;
};

}  // namespace
}  // namespace cuda

Result<std::unique_ptr<Backend>> make_particle_cuda_backend(const ParticleModel& model,
                                                            const BackendOptions& options) {
  cudaDeviceProp prop{};
  if (Status s = cuda::open_device(options.device, &prop); !s) return s.error();
  cudaFuncAttributes attributes{};
  if (const cudaError_t e = cudaFuncGetAttributes(&attributes, cuda::membrane_kernel); e != cudaSuccess) {
    (void)cudaGetLastError();
    return make_error("zona's particle kernels do not run on %s (sm_%d%d): %s; rebuild with "
                      "-DCMAKE_CUDA_ARCHITECTURES=%d%d",
                      prop.name, prop.major, prop.minor, cudaGetErrorString(e), prop.major, prop.minor);
  }
  return std::unique_ptr<Backend>(std::make_unique<cuda::ParticleCudaBackend>(model, options, prop.name));
}

}  // namespace zona
