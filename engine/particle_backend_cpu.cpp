// The particle model's CPU reference behind the Backend interface: particle_step over its own
// State, prescribed particles moved linearly towards each call's targets (the CPU FEM backend's
// arithmetic, engine/backend_cpu.cpp), so the GPU backend has a like-for-like reference.
#include <chrono>
#include <cmath>

#include "engine/backend_cpu.h"
#include "engine/particle_model.h"

namespace zona {
namespace {

class ParticleCpuBackend final : public Backend {
 public:
  explicit ParticleCpuBackend(const ParticleModel& particles) : particles_(particles) {}

  // "cpu": the simulation steps the CPU reference in place instead (no copies).
  const char* name() const override { return "cpu"; }
  std::string description() const override { return "particles: cpu reference, 1 thread, float64"; }

  Status upload(const Model& model, const State& state) override {
    if (model.vertex_count() != particles_.particle_count() || state.u.size() != model.vertex_count())
      return make_error("particle cpu backend: the model has %zu vertices, the state %zu, the "
                        "particle model %zu", model.vertex_count(), state.u.size(),
                        particles_.particle_count());
    model_ = &model;
    state_ = make_state(model, 1);
    copy_state_fields(state, state_);
    start_.assign(state_.prescribed_displacement.begin(), state_.prescribed_displacement.end());
    target_ = start_;
    delta_.assign(start_.size(), Vec3d{0, 0, 0});
    return {};
  }

  Status set_prescribed_targets(std::span<const Vec3d> targets) override {
    if (targets.size() != target_.size())
      return make_error("particle cpu backend: %zu prescribed targets given for %zu prescribed "
                        "vertices", targets.size(), target_.size());
    for (size_t k = 0; k < targets.size(); ++k) {
      if (!(std::isfinite(targets[k].x) && std::isfinite(targets[k].y) && std::isfinite(targets[k].z)))
        return make_error("particle cpu backend: prescribed target %zu is not finite", k);
      target_[k] = targets[k];
    }
    return {};
  }

  StepReport step(int substeps) override {
    StepReport report;
    if (!model_ || substeps < 1) return report;
    const auto t0 = std::chrono::steady_clock::now();
    const double n = static_cast<double>(substeps);
    for (size_t k = 0; k < target_.size(); ++k) {
      start_[k] = state_.prescribed_displacement[k];
      delta_[k] = (target_[k] - start_[k]) / n;
    }
    for (int i = 0; i < substeps; ++i) {
      for (size_t k = 0; k < target_.size(); ++k)
        state_.prescribed_displacement[k] = start_[k] + static_cast<double>(i + 1) * delta_[k];
      const StepStatus s = particle_step(particles_, *model_, state_, nullptr);
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
    if (!model_) return make_error("particle cpu backend: nothing uploaded");
    copy_state_fields(state_, state);
    return {};
  }

  Status elastic_forces(std::span<const Vec3d> u, std::span<Vec3d> f) override {
    if (!model_) return make_error("particle cpu backend: nothing uploaded");
    if (u.size() != model_->vertex_count() || f.size() != model_->vertex_count())
      return make_error("particle cpu backend: elastic_forces needs %zu vertices, got u %zu, f %zu",
                        model_->vertex_count(), u.size(), f.size());
    particle_forces(particles_, u, u, 0.0, f);
    return {};
  }

  Result<StateSummary> summarize() override {
    if (!model_) return make_error("particle cpu backend: nothing uploaded");
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
  const ParticleModel& particles_;
  const Model* model_ = nullptr;
  State state_;
  std::vector<Vec3d> start_, target_, delta_;  // prescribed: per call, (prescribed count)
};

}  // namespace

std::unique_ptr<Backend> make_particle_cpu_backend(const ParticleModel& model) {
  return std::make_unique<ParticleCpuBackend>(model);
}

}  // namespace zona
