// The particle model's stages on the injection step (particle_body.h).
#include "engine/sim/particle_body.h"

#include <algorithm>
#include <cmath>

namespace zona {

StepStatus ParticleBody::step(const Model& body, State& state) {
  StepStatus status = kStepOk;
  if (!backend_) {
    status = particle_step(model_, body, state, nullptr);
  } else {
    // The tools' loads of this step go down, one step is taken there, the state comes back
    // (the tool stage of the next step reads it on the host).
    // (A backend without set_external_forces takes the whole state instead.)
    if (!backend_->set_external_forces(state.external_force) && !backend_->upload(body, state))
      return kStepNonFinite;
    status = backend_->step(1).status;
    if (!backend_->download(state)) return status | kStepNonFinite;
  }
  if (!(status & kStepNonFinite)) {
    volume_change_rel_ = particle_volume(model_, state.u) / model_.rest_volume - 1.0;
    volume_change_max_rel_ = std::max(volume_change_max_rel_, std::fabs(volume_change_rel_));
  }
  return status;
}

std::string ParticleBody::description() const {
  return backend_ ? backend_->description() : "particles: cpu reference in place, 1 thread, float64";
}

}  // namespace zona
