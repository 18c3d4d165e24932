// The CPU backend: owns a State and runs the reference step() over it, sub-step by sub-step,
// moving prescribed vertices linearly towards the targets of the call.
#include "engine/sim/backend_cpu.h"

#include <algorithm>
#include <chrono>
#include <cmath>

#include "engine/sim/backend_cpu_base.h"
#include "engine/fem/forces_cpu.h"

namespace zona {

void copy_state_fields(const State& from, State& to) {
  to.u = from.u;
  to.u_prev = from.u_prev;
  to.force = from.force;
  to.external_force = from.external_force;
  to.prescribed_vertices = from.prescribed_vertices;
  to.prescribed_displacement = from.prescribed_displacement;
  to.vertex_constraint = from.vertex_constraint;
  to.time = from.time;
  to.step_count = from.step_count;
  to.diag = from.diag;
  to.energy_budget_valid = from.energy_budget_valid;
}

Status CpuBackendBase::upload(const Model& model, const State& state) {
  if (Status s = check_upload(model, state); !s) return s;
  model_ = &model;
  state_ = make_state(model, threads_);
  copy_state_fields(state, state_);
  start_.assign(state_.prescribed_displacement.begin(), state_.prescribed_displacement.end());
  target_ = start_;
  delta_.assign(start_.size(), Vec3d{0, 0, 0});
  return {};
}

Status CpuBackendBase::set_prescribed_targets(std::span<const Vec3d> targets) {
  if (targets.size() != target_.size())
    return make_error("%s: %zu prescribed targets given for %zu prescribed vertices", label_,
                      targets.size(), target_.size());
  for (size_t k = 0; k < targets.size(); ++k) {
    if (!(std::isfinite(targets[k].x) && std::isfinite(targets[k].y) &&
          std::isfinite(targets[k].z)))
      return make_error("%s: prescribed target %zu is not finite", label_, k);
    target_[k] = targets[k];
  }
  return {};
}

Status CpuBackendBase::set_external_forces(std::span<const Vec3d> forces) {
  if (!model_) return make_error("%s: nothing uploaded", label_);
  if (forces.size() != state_.external_force.size())
    return make_error("%s: %zu loads given for %zu vertices", label_, forces.size(),
                      state_.external_force.size());
  std::copy(forces.begin(), forces.end(), state_.external_force.begin());
  return {};
}

StepReport CpuBackendBase::step(int substeps) {
  StepReport report;
  if (!model_ || substeps < 1) return report;
  const auto t0 = std::chrono::steady_clock::now();
  // Sub-step i moves each prescribed vertex to start + (i + 1) * delta: the same arithmetic
  // as the CUDA backends, so both see the same targets.
  const double n = static_cast<double>(substeps);
  for (size_t k = 0; k < target_.size(); ++k) {
    start_[k] = state_.prescribed_displacement[k];
    delta_[k] = (target_[k] - start_[k]) / n;
  }
  for (int i = 0; i < substeps; ++i) {
    for (size_t k = 0; k < target_.size(); ++k)
      state_.prescribed_displacement[k] = start_[k] + static_cast<double>(i + 1) * delta_[k];
    const StepStatus s = advance(*model_, state_);
    report.status |= s;
    if ((s & kStepNotAdvanced) ||
        ((s & kStepDtAboveCritical) && !model_->unsafe_allow_dt_above_critical))
      break;
    ++report.steps;
  }
  const StepDiagnostics& d = state_.diag;
  report.constraint_force = d.constraint_force;
  report.kinetic_energy = d.kinetic_energy;
  report.elastic_energy = d.elastic_energy;
  report.residual_norm = d.residual_norm;
  report.device_ms =
      std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
  return report;
}

Status CpuBackendBase::download(State& state) {
  if (!model_) return make_error("%s: nothing uploaded", label_);
  copy_state_fields(state_, state);
  return {};
}

Result<StateSummary> CpuBackendBase::summarize() {
  if (!model_) return make_error("%s: nothing uploaded", label_);
  StateSummary s;
  const double inv_dt = 1.0 / model_->dt;
  for (size_t v = 0; v < state_.u.size(); ++v) {
    s.max_displacement = std::max(s.max_displacement, norm(state_.u[v]));
    const Vec3d vel = inv_dt * (state_.u[v] - state_.u_prev[v]);
    s.kinetic_energy += 0.5 * model_->vertex_mass[v] * dot(vel, vel);
  }
  return s;
}

namespace {

// The FEM reference: zona::step over the owned State on the backend's thread pool.
class CpuBackend final : public CpuBackendBase {
 public:
  explicit CpuBackend(const BackendOptions& options)
      : CpuBackendBase("cpu backend", options.cpu_threads), options_(options) {}

  std::string description() const override {
    return "cpu: " + std::to_string(state_.pool ? state_.pool->thread_count() : 0) +
           " thread(s), float64";
  }

  Status elastic_forces(std::span<const Vec3d> u, std::span<Vec3d> f) override {
    if (!model_) return make_error("cpu backend: nothing uploaded");
    if (u.size() != model_->vertex_count() || f.size() != model_->vertex_count())
      return make_error("cpu backend: elastic_forces needs %zu vertices, got u %zu, f %zu",
                        model_->vertex_count(), u.size(), f.size());
    // A scratch state keeps the backend's own state untouched.
    if (!scratch_.pool) scratch_ = make_state(*model_, options_.cpu_threads);
    std::copy(u.begin(), u.end(), scratch_.u.begin());
    compute_elastic_forces(*model_, scratch_);
    std::copy(scratch_.force.begin(), scratch_.force.end(), f.begin());
    return {};
  }

 protected:
  Status check_upload(const Model& model, const State& state) const override {
    if (state.u.size() != model.vertex_count())
      return make_error("cpu backend: the state has %zu vertices, the model %zu", state.u.size(),
                        model.vertex_count());
    return {};
  }
  StepStatus advance(const Model& model, State& state) override { return zona::step(model, state); }

 private:
  BackendOptions options_;
  State scratch_;
};

}  // namespace

std::unique_ptr<Backend> make_cpu_backend(const BackendOptions& options) {
  return std::make_unique<CpuBackend>(options);
}

}  // namespace zona
