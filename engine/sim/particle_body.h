// The particle model's elastic and integrate stages on the injection step (engine/sim/job.h):
// Asgari et al.'s springs, dashpots and hydraulic pressure with eq. 5's damping
// (particle_step), in place on the host state, or on a particle Backend (the GPU's force
// kernels) with the tools' loads handed over and the state handed back every step. The job's
// tool, measure and record stages run on the host around it (docs/architecture.md, "One engine").
#pragma once

#include <string>

#include "engine/particles/particle_model.h"
#include "engine/sim/backend.h"
#include "engine/sim/job_runner.h"

namespace zona {

class ParticleBody final : public BodyStep {
 public:
  /// `model` and `backend` (null: particle_step in place) are kept by reference. The backend
  /// has the model and the starting state uploaded.
  ParticleBody(const ParticleModel& model, Backend* backend) : model_(model), backend_(backend) {}

  StepStatus step(const Model& body, State& state) override;
  std::string description() const override;

  /// The enclosed volume after the last step against its rest value, V / V0 - 1 (eq. 6's
  /// constraint), and the largest |V / V0 - 1| over the steps so far. (Not on the step path:
  /// the last state's volume is taken when asked.)
  double volume_change_rel() const;
  double volume_change_max_rel() const;

 private:
  const ParticleModel& model_;
  Backend* backend_;
  const State* state_ = nullptr;  // the state the steps advance (the last one's volume)
  double max_before_ = 0;  // largest |V / V0 - 1| of the states the steps started from
};

}  // namespace zona
