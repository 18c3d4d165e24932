// The particle model's stages on the injection step (particle_body.h).
#include "engine/sim/particle_body.h"

#include <algorithm>
#include <cmath>

namespace zona {

StepStatus ParticleBody::step(const Model& body, State& state) {
  state_ = &state;
  // The volume of the state the step starts from: particle_step's own (its pressure's) in
  // place, else taken here; the last state's comes when asked.
  double volume = 0;
  StepStatus status = kStepOk;
  if (!backend_) {
    ParticleStepInfo info;  // (volume 0 where the step is refused before its forces)
    status = particle_step(model_, body, state, &info);
    volume = info.volume;
  } else {
    volume = particle_volume(model_, state.u);
    // The tools' loads of this step go down, one step is taken there, the state comes back
    // (the tool stage of the next step reads it on the host).
    // (A backend without set_external_forces takes the whole state instead.)
    if (!backend_->set_external_forces(state.external_force) && !backend_->upload(body, state))
      return kStepNonFinite;
    status = backend_->step(1).status;
    if (!backend_->download(state)) return status | kStepNonFinite;
  }
  if (volume > 0) max_before_ = std::max(max_before_, std::fabs(volume / model_.rest_volume - 1.0));
  return status;
}

double ParticleBody::volume_change_rel() const {
  return state_ ? particle_volume(model_, state_->u) / model_.rest_volume - 1.0 : 0.0;
}

double ParticleBody::volume_change_max_rel() const {
  return std::max(max_before_, std::fabs(volume_change_rel()));
}

std::string ParticleBody::description() const {
  return backend_ ? backend_->description() : "particles: cpu reference in place, 1 thread, float64";
}

}  // namespace zona
