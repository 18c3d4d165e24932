// The injection experiment's split step (step1 / step2, as mj_step1 / mj_step2): the job's
// stages (engine/sim/job.h, through Simulation::runner()) for every scene with a tool, else the
// host step of the prescribed boundary: an indentation patch moved at its speed to its depth
// (docs/architecture.md, "One engine").
// Setup is engine/sim/simulation.cpp, the run driver engine/sim/run.cpp.
#include <algorithm>
#include <cmath>

#include "engine/sim/simulation.h"

namespace zona {

void Simulation::set_needle_tip(Vec3d tip) {
  if (job_) job_->set_tip(tip);  // the host path has no needle
}

StepStatus Simulation::step2() {
  if (job_) return step_job();
  apply_loads();                          // stiffness damping
  set_targets();                          // the patch's displacement at t_{n+1}
  const StepStatus status = integrate();  // internal forces + integrate (backend)
  if (status & kStepFailed) {
    // A failed health check (non-finite, energy blow-up): the run stops here, and nothing of
    // this state is measured or published.
    report_.status = status;
    last_status_ = status;
    return status;
  }
  measure();  // the patch's reaction, the holder, energies
  report_.status = status;
  last_status_ = status;
  publish();  // local stiffness
  return status;
}

void Simulation::apply_loads() {
  if (!(stiffness_damping_ > 0)) return;
  // Stiffness-proportional (Kelvin-Voigt) damping, -beta K v, as the job's loads stage.
  const double k = stiffness_damping_ / model_.dt;
  double before = 0;
  for (size_t v = 0; v < state_.force.size(); ++v) {
    const Vec3d load = job_stiffness_damping_load(k, state_.force[v], &force_prev_[v]);
    state_.external_force[v] = load;
    damping_load_[v] = load;
    before += dot(load, state_.u[v] + state_.u_prev[v]);
  }
  damping_before_ = before;
}

void Simulation::set_targets() {
  const int substeps = backend_ ? options_.backend_substeps : 1;
  const double t_next = state_.time + substeps * model_.dt;
  for (size_t i = 0; i < indent_vertices_.size(); ++i) {
    const double depth = std::min(indent_depth_[i], indent_speed_[i] * t_next);
    targets_[i] = depth * indent_direction_[i];
    indent_before_[i] = state_.u_prev[static_cast<size_t>(indent_vertices_[i])];
  }
}

StepStatus Simulation::integrate() {
  if (!backend_) {
    std::copy(targets_.begin(), targets_.end(), state_.prescribed_displacement.begin());
    if (particles_) return energy_verdict(particle_step(*particles_, model_, state_, nullptr));
    return energy_verdict(zona::step(model_, state_));
  }
  // Backend: the patch goes up once; the damping loads through set_external_forces (an upload
  // where the backend lacks it), the targets every step. The patch starts from where it is
  // and reaches its targets at the last sub-step.
  bool upload = !uploaded_;
  if (!upload && stiffness_damping_ > 0 && !backend_->set_external_forces(state_.external_force).ok())
    upload = true;
  if (upload) {
    if (Status s = backend_->upload(model_, state_); !s) return kStepNonFinite;
    uploaded_ = true;
  }
  if (Status s = backend_->set_prescribed_targets(targets_); !s) return kStepNonFinite;
  const StepReport r = backend_->step(options_.backend_substeps);
  if (Status s = backend_->download(state_); !s) return r.status | kStepNonFinite;
  return energy_verdict(r.status);
}

StepStatus Simulation::energy_verdict(StepStatus status) {
  // The energy test compares against the work put in by loads and prescribed vertices. The
  // stiffness damping's loads are among them, and their work is no energy put in (lagged by a
  // step it can be either sign): it is taken out of the budget here and the verdict taken again
  // on the patch's work alone, as the job's record stage does. Over a step or a window of
  // sub-steps with the loads held, the centred work telescopes to
  // 1/2 load . ((u + u_prev)_after - (u + u_prev)_before).
  if (stiffness_damping_ > 0 && !particles_ && !(status & kStepNonFinite)) {
    double after = 0;
    for (size_t v = 0; v < damping_load_.size(); ++v)
      after += dot(damping_load_[v], state_.u[v] + state_.u_prev[v]);
    damping_work_ += 0.5 * (after - damping_before_);
    const StepDiagnostics& d = state_.diag;
    const double energy = d.kinetic_energy + d.elastic_energy;
    const double budget = d.energy_budget - damping_work_;
    status &= ~kStepEnergyBlowUp;
    if (energy > model_.energy_blowup_factor * std::max(budget, model_.energy_floor))
      status |= kStepEnergyBlowUp;
    return status;
  }
  // Without a budget (nothing has put work in yet) the verdict is not taken.
  if ((status & kStepEnergyBlowUp) && !(state_.diag.energy_budget > 0))
    status &= ~kStepEnergyBlowUp;
  return status;
}

void Simulation::measure() {
  const std::span<const Vec3d> u(state_.u), u_prev(state_.u_prev), f(state_.force),
      ext(state_.external_force);
  const double time = state_.time;
  report_.time = time;
  report_.step = state_.step_count;
  // The patch is the tool: its reaction, the constraint force of the prescribed motion.
  Vec3d reaction{0, 0, 0};
  const Vec3d dir = indent_direction_.front();
  for (size_t i = 0; i < indent_vertices_.size(); ++i) {
    const size_t v = static_cast<size_t>(indent_vertices_[i]);
    const Vec3d acc = (u[v] - 2.0 * u_prev[v] + indent_before_[i]) / (model_.dt * model_.dt);
    const Vec3d vel = (u[v] - indent_before_[i]) / (2.0 * model_.dt);
    reaction += model_.vertex_mass[v] * acc + model_.vertex_damping[v] * vel - f[v] - ext[v];
  }
  report_.force_vector = reaction;
  report_.force = report_.raw_force = dot(reaction, dir);
  report_.travel = std::min(indent_depth_.front(), indent_speed_.front() * time);
  report_.deformation = report_.travel;
  // What the fixed vertices hold (quasi-static: minus the elastic and applied forces on them).
  Vec3d holding{0, 0, 0};
  for (int32_t v : model_.fixed_vertices)
    holding -= f[static_cast<size_t>(v)] + ext[static_cast<size_t>(v)];
  report_.holding_force = holding;
  report_.elastic_energy = state_.diag.elastic_energy;
  report_.kinetic_energy = state_.diag.kinetic_energy;
  // Particle model: the enclosed volume against its rest value (Asgari et al. eq. 6's constraint).
  if (particles_) {
    volume_change_rel_ = particle_volume(*particles_, state_.u) / particles_->rest_volume - 1.0;
    volume_change_max_rel_ = std::max(volume_change_max_rel_, std::fabs(volume_change_rel_));
  }
}

void Simulation::publish() {
  // Local stiffness: the job's record stage (job_local_stiffness: the slope of force over at
  // least options.stiffness_window of travel).
  JobRecord published;
  published.force = report_.force;
  published.travel = report_.travel;
  job_local_stiffness(record_params_, record_state_, published);
  report_.stiffness = record_state_.stiffness;
}

bool Simulation::finished() const {
  if (job_)
    return job_halted_ ||
           static_cast<double>(job_->steps_advanced()) * model_.dt >= end_time_ - 0.5 * model_.dt;
  if (last_status_ & kStepFailed) return true;
  if ((last_status_ & kStepDtAboveCritical) && !model_.unsafe_allow_dt_above_critical) return true;
  return state_.time >= end_time_ - 0.5 * model_.dt;
}

}  // namespace zona
