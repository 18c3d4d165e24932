// What every CPU backend shares: its own State, prescribed vertices moved linearly towards each
// call's targets sub-step by sub-step (the CUDA backends' arithmetic, so both see the same
// targets), downloads and summaries. A concrete backend supplies the step of its model, its
// elastic forces and its description (engine/sim/backend_cpu.cpp: FEM;
// engine/sim/backend_particles_cpu.cpp: particles).
#pragma once

#include <string>
#include <vector>

#include "engine/sim/backend.h"

namespace zona {

/// The shared part of the CPU backends (sub-stepping, targets, hand-over of the State).
class CpuBackendBase : public Backend {
 public:
  /// `label` starts every error message ("cpu backend"); `threads` sizes the owned State's pool.
  CpuBackendBase(const char* label, int threads) : label_(label), threads_(threads) {}

  const char* name() const override { return "cpu"; }
  Status upload(const Model& model, const State& state) final;
  Status set_prescribed_targets(std::span<const Vec3d> targets) final;
  Status set_external_forces(std::span<const Vec3d> forces) final;
  StepReport step(int substeps) final;
  Status download(State& state) final;
  Result<StateSummary> summarize() final;

 protected:
  /// Refuses a model/state pair this backend cannot step (one-line error).
  virtual Status check_upload(const Model& model, const State& state) const = 0;
  /// One step of the model over `state` (zona::step, particle_step).
  virtual StepStatus advance(const Model& model, State& state) = 0;

  const char* label_;
  int threads_;
  const Model* model_ = nullptr;
  State state_;

 private:
  std::vector<Vec3d> start_, target_, delta_;  // prescribed: per call, (prescribed count)
};

}  // namespace zona
