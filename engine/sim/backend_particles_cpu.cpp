// The particle model's CPU reference behind the Backend interface: particle_step over the
// CpuBackendBase's own State (the CPU FEM backend's sub-stepping and hand-over,
// engine/sim/backend_cpu_base.h), so the GPU backend has a like-for-like reference. It lives in
// engine/sim/ (the Backend interface's folder), so that engine/particles/ does not depend on it.
#include "engine/sim/backend_cpu.h"
#include "engine/sim/backend_cpu_base.h"

namespace zona {
namespace {

class ParticleCpuBackend final : public CpuBackendBase {
 public:
  explicit ParticleCpuBackend(const ParticleModel& particles)
      : CpuBackendBase("particle cpu backend", 1), particles_(particles) {}

  // "cpu" (the base's name): the simulation steps the CPU reference in place instead (no copies).
  std::string description() const override { return "particles: cpu reference, 1 thread, float64"; }

  Status elastic_forces(std::span<const Vec3d> u, std::span<Vec3d> f) override {
    if (!model_) return make_error("particle cpu backend: nothing uploaded");
    if (u.size() != model_->vertex_count() || f.size() != model_->vertex_count())
      return make_error("particle cpu backend: elastic_forces needs %zu vertices, got u %zu, f %zu",
                        model_->vertex_count(), u.size(), f.size());
    particle_forces(particles_, u, u, 0.0, f);
    return {};
  }

 protected:
  Status check_upload(const Model& model, const State& state) const override {
    if (model.vertex_count() != particles_.particle_count() || state.u.size() != model.vertex_count())
      return make_error("particle cpu backend: the model has %zu vertices, the state %zu, the "
                        "particle model %zu", model.vertex_count(), state.u.size(),
                        particles_.particle_count());
    return {};
  }
  StepStatus advance(const Model& model, State& state) override {
    return particle_step(particles_, model, state, nullptr);
  }

 private:
  const ParticleModel& particles_;
};

}  // namespace

std::unique_ptr<Backend> make_particle_cpu_backend(const ParticleModel& model) {
  return std::make_unique<ParticleCpuBackend>(model);
}

}  // namespace zona
