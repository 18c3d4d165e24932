// The CPU backend: owns a State and runs the reference step() over it, sub-step by sub-step,
// moving prescribed vertices linearly towards the targets of the call.
#include "engine/backend_cpu.h"

#include <algorithm>
#include <chrono>
#include <cmath>

#include "engine/forces_cpu.h"

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

namespace {

class CpuBackend final : public Backend {
 public:
  explicit CpuBackend(const BackendOptions& options) : options_(options) {}

  const char* name() const override { return "cpu"; }

  std::string description() const override {
    return "cpu: " + std::to_string(state_.pool ? state_.pool->thread_count() : 0) +
           " thread(s), float64";
  }

  Status upload(const Model& model, const State& state) override {
    if (state.u.size() != model.vertex_count())
      return make_error("cpu backend: the state has %zu vertices, the model %zu", state.u.size(),
                        model.vertex_count());
    model_ = &model;
    state_ = make_state(model, options_.cpu_threads);
    copy_state_fields(state, state_);
    start_.assign(state_.prescribed_displacement.begin(), state_.prescribed_displacement.end());
    target_ = start_;
    delta_.assign(start_.size(), Vec3d{0, 0, 0});
    return {};
  }

  Status set_prescribed_targets(std::span<const Vec3d> targets) override {
    if (targets.size() != target_.size())
      return make_error("cpu backend: %zu prescribed targets given for %zu prescribed vertices",
                        targets.size(), target_.size());
    for (size_t k = 0; k < targets.size(); ++k) {
      if (!(std::isfinite(targets[k].x) && std::isfinite(targets[k].y) &&
            std::isfinite(targets[k].z)))
        return make_error("cpu backend: prescribed target %zu is not finite", k);
      target_[k] = targets[k];
    }
    return {};
  }

  StepReport step(int substeps) override {
    StepReport report;
    if (!model_ || substeps < 1) return report;
    const auto t0 = std::chrono::steady_clock::now();
    // Sub-step i moves each prescribed vertex to start + (i + 1) * delta: the same arithmetic
    // as the CUDA backend, so both backends see the same targets.
    const double n = static_cast<double>(substeps);
    for (size_t k = 0; k < target_.size(); ++k) {
      start_[k] = state_.prescribed_displacement[k];
      delta_[k] = (target_[k] - start_[k]) / n;
    }
    for (int i = 0; i < substeps; ++i) {
      for (size_t k = 0; k < target_.size(); ++k)
        state_.prescribed_displacement[k] = start_[k] + static_cast<double>(i + 1) * delta_[k];
      const StepStatus s = zona::step(*model_, state_);
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

  Status download(State& state) override {
    if (!model_) return make_error("cpu backend: nothing uploaded");
    copy_state_fields(state_, state);
    return {};
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

  Result<StateSummary> summarize() override {
    if (!model_) return make_error("cpu backend: nothing uploaded");
    StateSummary s;
    const double inv_dt = 1.0 / model_->dt;
    for (size_t v = 0; v < state_.u.size(); ++v) {
      s.max_displacement = std::max(s.max_displacement, norm(state_.u[v]));
      const Vec3d vel = inv_dt * (state_.u[v] - state_.u_prev[v]);
      s.kinetic_energy += 0.5 * model_->vertex_mass[v] * dot(vel, vel);
    }
    return s;
  }

 private:
  BackendOptions options_;
  const Model* model_ = nullptr;
  State state_;
  State scratch_;
  std::vector<Vec3d> start_, target_, delta_;  // prescribed: per call, (prescribed count)
};

}  // namespace

std::unique_ptr<Backend> make_cpu_backend(const BackendOptions& options) {
  return std::make_unique<CpuBackend>(options);
}

}  // namespace zona
