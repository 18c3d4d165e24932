// The prescribed boundary's host step as a JobRunner (boundary_runner.h).
#include "engine/sim/boundary_runner.h"

#include <vector>

#include "engine/sim/simulation.h"

namespace zona {

JobRecord boundary_record(const Simulation& sim) {
  const NeedleReport& n = sim.report();
  JobRecord r;
  r.step = sim.state().step_count;
  r.time = n.time;
  r.tip = n.tip;
  r.travel = n.travel;
  r.deformation = n.deformation;
  r.force = n.force;
  r.raw_force = n.raw_force;
  r.force_vector = n.force_vector;
  r.holding_force = n.holding_force;
  r.stiffness = n.stiffness;
  r.elastic_energy = n.elastic_energy;
  r.kinetic_energy = n.kinetic_energy;
  r.contacts = n.contacts;
  r.holding_contacts = n.holding_contacts;
  r.status = n.status;
  const bool above = (n.status & kStepDtAboveCritical) && !sim.model().unsafe_allow_dt_above_critical;
  r.halted = (n.status & kStepFailed) || above ? 1 : 0;
  r.first_bad = sim.state().diag.first_nonfinite >= 0 ? sim.state().diag.first_nonfinite
                                                       : sim.state().diag.first_inverted;
  const PunctureRecord& p = sim.puncture();
  r.puncture.punctured = p.punctured ? 1 : 0;
  r.puncture.step = p.step;
  r.puncture.time = p.time;
  r.puncture.needle_travel = p.needle_travel;
  r.puncture.deformation = p.deformation;
  r.puncture.force = p.force;
  r.puncture.energy = p.energy;
  r.puncture.force_vector = p.force_vector;
  r.quasi = n.quasi;
  return r;
}

namespace {

class BoundaryRunner final : public HostJobRunner {
 public:
  BoundaryRunner(Simulation& sim, size_t capacity) : HostJobRunner(capacity), sim_(sim) {
    const double interval = sim.scene().output.sample_interval;
    sample_params_.dt = sim.model().dt;
    sample_params_.record.sample_interval = interval > 0 ? interval : 0;
  }

  Status advance(int64_t steps) override {
    const int64_t target = advanced_ + steps;
    advanced_ = target;
    while (!halted_ && sim_.state().step_count < target) {
      const int64_t before = sim_.state().step_count;
      sim_.step2();
      // A step that did not advance the state (it failed its check, or the scene's end was
      // reached) ends the advance: asking again would not move it either.
      if (sim_.state().step_count == before) {
        JobRecord r = boundary_record(sim_);
        r.halted = 1;
        halted_ = true;
        records_.publish(r, true, r);
        break;
      }
      const JobRecord r = boundary_record(sim_);
      seen_status_ |= r.status;
      halted_ = r.halted != 0;
      // Sampled by the job's record stage's rule (job_sample_due): the step whose time
      // reaches the next sample time, and a failed step. Its status carries every flag seen
      // since the last sample, so that a flag between samples is not lost.
      sample_state_.time = r.time;
      sample_state_.halted = halted_ ? 1 : 0;
      const bool due = job_sample_due(sample_params_, sample_state_);
      JobRecord sample = r;
      if (due) {
        sample.status = seen_status_;
        seen_status_ = 0;
      }
      records_.publish(r, due, sample);
    }
    return {};
  }

  void set_tip(Vec3d) override {}  // no needle on this path (Simulation refuses one)

  int64_t steps_advanced() const override { return sim_.state().step_count; }
  int64_t mass_raises() override { return 0; }
  std::string description() const override { return sim_.backend_description(); }

 private:
  Simulation& sim_;
  bool halted_ = false;
  int64_t advanced_ = 0;
  JobParams sample_params_;  // dt and the sample interval (job_sample_due)
  JobState sample_state_;    // time, halted, the next sample time
  uint32_t seen_status_ = 0;
};

}  // namespace

std::unique_ptr<JobRunner> make_boundary_runner(Simulation& sim, size_t sample_capacity) {
  return std::make_unique<BoundaryRunner>(sim, sample_capacity);
}

}  // namespace zona
