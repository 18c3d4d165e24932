// The injection experiment's split step (step1 / step2, as mj_step1 / mj_step2): the job's
// stages (engine/sim/job.h, through Simulation::runner()) on the penalty-contact path, else the
// host step of the kinematic contact (engine/tools/contact.h), which the indentation boundary
// and contact.model "kinematic" take (docs/architecture.md, "One engine").
// Setup is engine/sim/simulation.cpp, the run driver engine/sim/run.cpp.
#include <algorithm>
#include <cmath>

#include "engine/sim/simulation.h"

namespace zona {

void Simulation::step1() {
  // 1. tools: the scripted pose at the end of this step.
  const int substeps = backend_ ? options_.backend_substeps : 1;
  if (has_needle_) tip_next_ = needle_tip_at(script_, state_.time + substeps * model_.dt);
}

void Simulation::set_needle_tip(Vec3d tip) {
  tip_next_ = tip;
  if (job_) job_->set_tip(tip);
}

StepStatus Simulation::step2() {
  if (job_) return step_job();
  test_puncture();                        // 2. puncture criterion on the last measurement
  update_contacts();                      // 3. contact sets and prescribed targets
  apply_loads();                          // 4. suction, released tip force, shaft drag
  const StepStatus status = integrate();  // 5. internal forces + integrate (backend)
  if (status & kStepFailed) {
    // A failed health check (non-finite, energy blow-up): the run stops here, and nothing of
    // this state is measured or published (no puncture, frame or haptic sample from it).
    report_.status = status;
    last_status_ = status;
    return status;
  }
  measure();  // 6. reactions, needle force, deformation
  const StepStatus measured = status | (quasi_blocks_puncture_ ? kStepNotQuasiStatic : kStepOk);
  report_.status = measured;
  last_status_ = measured;
  publish();  // 7. report, local stiffness, snapshot
  return measured;
}

void Simulation::test_puncture() {
  if (!has_needle_ || puncture_->punctured() || quasi_blocks_puncture_) return;
  const PunctureInputs in{report_.force, report_.max_strain, report_.elastic_energy};
  if (!puncture_->criterion_met(in)) return;
  PunctureRecord r;
  r.step = state_.step_count;
  r.time = report_.time;
  r.needle_travel = report_.travel;
  r.deformation = report_.deformation;
  r.force = report_.force;
  r.max_strain = report_.max_strain;
  r.energy = report_.elastic_energy;
  r.force_vector = report_.force_vector;
  puncture_->trigger(r, needle_contacts_->contacts());
  // The needle is now inside: it no longer touches the (hole-less) mesh.
  needle_contacts_->clear();
}

void Simulation::update_contacts() {
  const std::span<const Vec3d> u(state_.u);
  const bool full_scan =
      options_.full_scan_interval > 0 && state_.step_count % options_.full_scan_interval == 0;
  const double margin = surface_.max_edge;
  auto mark = [this](const ContactSet* set, uint8_t value) {
    if (!set) return;
    for (const Contact& c : set->contacts()) taken_[static_cast<size_t>(c.vertex)] = value;
  };
  // Each tool skips the other's contacts (and fixed / indented vertices).
  if (needle_contacts_ && !puncture_->punctured()) {
    mark(rim_contacts_.get(), 1);
    needle_contacts_->update(model_, u, tip_, std::span<const int32_t>(seeds_, 3), taken_,
                             full_scan, margin, options_.slip_relax);
    // Ladjal et al.'s contact: where the tip point has passed the surface point the axis hits, the
    // hit triangle is carried along with the tip even if none of its corners lies inside the
    // tool (a coarse mesh, a tip smaller than the triangles).
    if (hit_valid_) {
      const Vec3d d = script_.direction;
      const double penetration = -dot(hit_point_ - tip_, d);
      if (penetration > 0)
        for (int c = 0; c < 3; ++c) {
          const int32_t v = seeds_[c];
          if (v < 0 || taken_[static_cast<size_t>(v)] || needle_contacts_->holds(v)) continue;
          const Vec3d x =
              model_.rest_positions[static_cast<size_t>(v)] + state_.u[static_cast<size_t>(v)];
          needle_contacts_->hold(v, x + penetration * d - tip_, d,
                                 state_.u[static_cast<size_t>(v)]);
        }
    }
    mark(rim_contacts_.get(), 0);
  }
  if (rim_contacts_) {
    mark(needle_contacts_.get(), 1);
    rim_contacts_->update(model_, u, Vec3d{0, 0, 0}, holding_->patch_vertices, taken_, full_scan,
                          margin, options_.slip_relax);
    mark(needle_contacts_.get(), 0);
  }

  // The prescribed set: needle contacts, rim contacts, indent patches; their targets at t_{n+1}.
  prescribed_.clear();
  size_t k = 0;
  const std::span<Vec3d> targets(targets_);
  if (needle_contacts_) {
    needle_contacts_->targets(model_, state_.u_prev, tip_next_, targets.subspan(k));
    for (const Contact& c : needle_contacts_->contacts()) prescribed_.push_back(c.vertex);
    k = prescribed_.size();
  }
  if (rim_contacts_) {
    rim_contacts_->targets(model_, state_.u_prev, Vec3d{0, 0, 0}, targets.subspan(k));
    for (const Contact& c : rim_contacts_->contacts()) prescribed_.push_back(c.vertex);
    k = prescribed_.size();
  }
  const int substeps = backend_ ? options_.backend_substeps : 1;
  const double t_next = state_.time + substeps * model_.dt;
  for (size_t i = 0; i < indent_vertices_.size(); ++i) {
    const double depth = std::min(indent_depth_[i], indent_speed_[i] * t_next);
    targets_[k + i] = depth * indent_direction_[i];
    indent_before_[i] = state_.u_prev[static_cast<size_t>(indent_vertices_[i])];
    prescribed_.push_back(indent_vertices_[i]);
  }
}

void Simulation::apply_loads() {
  loads_changed_ = false;
  if (stiffness_damping_ > 0) {
    // Stiffness-proportional (Kelvin-Voigt) damping, -beta K v, from the change of the elastic
    // forces over the last step: beta (f(u_{n-1}) - f(u_{n-2})) / dt (lagged one step). It damps
    // the element-scale ringing that contact events excite, which mass-proportional damping
    // cannot reach without dragging the slow, quasi-static motion too.
    const double k = stiffness_damping_ / model_.dt;
    double before = 0;
    for (size_t v = 0; v < state_.force.size(); ++v) {
      const Vec3d load = k * (state_.force[v] - force_prev_[v]);
      state_.external_force[v] = load;
      damping_load_[v] = load;
      force_prev_[v] = state_.force[v];
      before += dot(load, state_.u[v] + state_.u_prev[v]);
    }
    damping_before_ = before;
    loaded_.clear();
    loads_changed_ = true;
  } else {
    // Clear last step's loads (only the entries that had any).
    for (int32_t v : loaded_) state_.external_force[static_cast<size_t>(v)] = Vec3d{0, 0, 0};
    loaded_.clear();
  }
  // Suction, ramped in over half the needle's approach so the cell settles without ringing.
  if (holding_ && holding_->mode == HoldingMode::kSuction) {
    double ramp_time = 0.05 * end_time_;
    if (has_needle_ && script_.speed > 0)
      ramp_time = std::min(ramp_time, 0.5 * scene_.needle.standoff / script_.speed);
    const double ramp = ramp_time > 0 ? std::min(1.0, state_.time / ramp_time) : 1.0;
    loads_changed_ = loads_changed_ || ramp < 1.0 || state_.step_count == 0;
    for (size_t i = 0; i < holding_->patch_vertices.size(); ++i) {
      const int32_t v = holding_->patch_vertices[i];
      state_.external_force[static_cast<size_t>(v)] += ramp * holding_->suction_force[i];
      loaded_.push_back(v);
    }
  }
  // After puncture: the released tip force and the shaft drag.
  if (puncture_->punctured()) {
    const double travel = dot(tip_ - script_.start, script_.direction);
    puncture_->apply_loads(state_.time, travel, state_.external_force);
    for (int32_t v : puncture_->released_vertices()) loaded_.push_back(v);
    loads_changed_ = true;
  }
}

StepStatus Simulation::integrate() {
  const size_t np = prescribed_.size();
  const std::span<const Vec3d> targets(targets_.data(), np);
  if (!backend_) {
    // In place: the set changes without allocating (capacity reserved by make_state).
    if (Status s = set_prescribed_vertices(model_, state_, prescribed_); !s) return kStepNonFinite;
    std::copy(targets.begin(), targets.end(), state_.prescribed_displacement.begin());
    if (particles_) return energy_verdict(particle_step(*particles_, model_, state_, nullptr));
    return energy_verdict(zona::step(model_, state_));
  }
  // Backend: a new prescribed set needs a fresh upload (the interface has no call for it);
  // new loads go through set_external_forces, or an upload where the backend lacks it.
  // Otherwise only the targets move. The prescribed vertices start from where they are and
  // reach their targets at the last sub-step.
  const bool same_set =
      uploaded_prescribed_.size() == np &&
      std::equal(prescribed_.begin(), prescribed_.end(), uploaded_prescribed_.begin());
  bool upload = !same_set;
  if (same_set && loads_changed_ && !backend_->set_external_forces(state_.external_force).ok())
    upload = true;
  if (upload) {
    if (Status s = set_prescribed_vertices(model_, state_, prescribed_); !s) return kStepNonFinite;
    if (Status s = backend_->upload(model_, state_); !s) return kStepNonFinite;
    uploaded_prescribed_.assign(prescribed_.begin(), prescribed_.end());
  }
  if (Status s = backend_->set_prescribed_targets(targets); !s) return kStepNonFinite;
  const StepReport r = backend_->step(options_.backend_substeps);
  if (Status s = backend_->download(state_); !s) return r.status | kStepNonFinite;
  return energy_verdict(r.status);
}

StepStatus Simulation::energy_verdict(StepStatus status) {
  // The energy test compares against the work put in by loads and prescribed vertices. The
  // stiffness damping's loads are among them, and their work is no energy put in (lagged by a
  // step it can be either sign): it is taken out of the budget here and the verdict taken again
  // on the tools' work alone, as the job's record stage does. Over a step or a window of
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
  // With several sub-steps the prescribed vertices moved linearly: u_{n-1} = 2 u_n - u_{n+1}.
  const bool linear_history = backend_ && options_.backend_substeps > 1;
  for (ContactSet* set : {needle_contacts_.get(), rim_contacts_.get()}) {
    if (!set) continue;
    if (linear_history) set->set_linear_history(u, u_prev);
    set->measure_reactions(model_, u, u_prev, f, ext);
  }
  tip_ = tip_next_;
  const double time = state_.time;
  const Vec3d d = script_.direction;
  report_.time = time;
  report_.step = state_.step_count;
  report_.tip = tip_;
  report_.punctured = puncture_->punctured();
  if (has_needle_) {
    report_.travel = dot(tip_ - script_.start, d);
    report_.force_vector = puncture_->punctured() ? puncture_->body_force(time, report_.travel)
                                                  : needle_contacts_->total_static_reaction();
    report_.constraint_force =
        puncture_->punctured() ? report_.force_vector : needle_contacts_->total_reaction();
    report_.raw_force = dot(report_.force_vector, d);
    report_.contacts = static_cast<int32_t>(needle_contacts_->size());
    // Ladjal et al.'s contact point: the needle axis against the deformed surface, searched from
    // the last hit triangle; the deformation is its advance over the same ray's rest hit.
    const Vec3d origin = tip_ - 2.0 * cell_diameter_ * d;
    const RayHit now = cast_ray(surface_, model_.rest_positions, u, origin, d, hit_triangle_);
    const RayHit at_rest = cast_ray(surface_, model_.rest_positions,
                                    std::span<const Vec3d>(zero_u_), origin, d, rest_hit_triangle_);
    hit_valid_ = now.triangle >= 0;
    hit_point_ = now.point;
    if (now.triangle >= 0) {
      hit_triangle_ = now.triangle;
      for (int c = 0; c < 3; ++c)
        seeds_[c] = surface_.triangles[static_cast<size_t>(now.triangle)][c];
    }
    if (at_rest.triangle >= 0) rest_hit_triangle_ = at_rest.triangle;
    report_.deformation =
        now.triangle >= 0 && at_rest.triangle >= 0 ? dot(now.point - at_rest.point, d) : 0.0;
    if (scene_.puncture.criterion == PunctureCriterion::kStrain && !puncture_->punctured()) {
      // The contact vertices, copied into scratch (no allocation: capacity nv).
      contact_vertices_.clear();
      for (const Contact& c : needle_contacts_->contacts()) contact_vertices_.push_back(c.vertex);
      report_.max_strain = max_principal_strain_around(model_, u, contact_vertices_, tet_in_zona_);
    }
  } else if (!indent_vertices_.empty()) {
    // No needle: report the indentation patch as the tool (issue 3's prescribed indentation).
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
  }
  // Holding force: rim reactions, or what the fixed vertices hold (quasi-static: minus the
  // elastic and applied forces on them).
  Vec3d holding{0, 0, 0};
  if (rim_contacts_) {
    holding = rim_contacts_->total_static_reaction();
    report_.holding_contacts = static_cast<int32_t>(rim_contacts_->size());
  } else if (holding_) {
    for (int32_t v : holding_->patch_vertices)
      holding -= f[static_cast<size_t>(v)] + ext[static_cast<size_t>(v)];
  }
  report_.holding_force = holding;
  report_.elastic_energy = state_.diag.elastic_energy;
  report_.kinetic_energy = state_.diag.kinetic_energy;
  // The needle's and the holder's force through the load cell's low-pass, then the quasi-static
  // check on them: the job's record-stage functions (job_filter_forces, quasi_static_step).
  if (has_needle_) {
    JobRecord measured;
    measured.raw_force = report_.raw_force;
    measured.holding_force = holding;
    job_filter_forces(record_params_, record_state_, measured);
    report_.force = measured.force;
    quasi_blocks_puncture_ =
        quasi_static_step(quasi_limits_, report_.quasi, !puncture_->punctured(), report_.force,
                          record_state_.filtered_holding, report_.kinetic_energy,
                          report_.elastic_energy, state_.step_count, time, report_.deformation);
  }
  // Particle model: the enclosed volume against its rest value (Asgari et al. eq. 6's constraint).
  if (particles_) {
    volume_change_rel_ = particle_volume(*particles_, state_.u) / particles_->rest_volume - 1.0;
    volume_change_max_rel_ = std::max(volume_change_max_rel_, std::fabs(volume_change_rel_));
  }
}

void Simulation::publish() {
  // Local stiffness for the haptic thread: the job's record stage (job_local_stiffness: the
  // slope of force over at least options.stiffness_window of travel). From the puncture on the
  // load no longer follows the tip's travel into the cell: the slope is the shaft's drag per
  // metre inserted, re-anchored each step (as job_puncture_test does).
  JobRecord published;
  published.force = report_.force;
  published.travel = report_.travel;
  job_local_stiffness(record_params_, record_state_, published);
  if (report_.punctured) {
    record_state_.stiffness = record_params_.puncture.shaft_friction;
    record_state_.stiffness_force = report_.force;
    record_state_.stiffness_travel = report_.travel;
  }
  report_.stiffness = record_state_.stiffness;
  // Surface snapshot into the writer's slot, then publish (no allocation: slots are sized).
  if (snapshots_ && state_.step_count % options_.snapshot_interval == 0) {
    SurfaceSnapshot& out = snapshots_->write_slot();
    for (size_t i = 0; i < surface_.vertices.size(); ++i) {
      const size_t v = static_cast<size_t>(surface_.vertices[i]);
      out.positions[i] = model_.rest_positions[v] + state_.u[v];
    }
    out.time = state_.time;
    out.step = state_.step_count;
    snapshots_->publish();
  }
}

bool Simulation::finished() const {
  if (job_)
    return job_halted_ ||
           static_cast<double>(job_->steps_advanced()) * model_.dt >= end_time_ - 0.5 * model_.dt;
  if (last_status_ & kStepFailed) return true;
  if ((last_status_ & kStepDtAboveCritical) && !model_.unsafe_allow_dt_above_critical) return true;
  return state_.time >= end_time_ - 0.5 * model_.dt;
}

std::span<const Contact> Simulation::needle_contacts() const {
  return needle_contacts_ ? needle_contacts_->contacts() : std::span<const Contact>();
}

std::span<const Contact> Simulation::holding_contacts() const {
  return rim_contacts_ ? rim_contacts_->contacts() : std::span<const Contact>();
}

}  // namespace zona
