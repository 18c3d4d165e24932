// The run driver: one loop for every scene. Steps go to the simulation's runner (the job's, CPU
// or GPU, or the prescribed boundary's host step, engine/sim/boundary_runner.h) in batches;
// samples come back as JobRecords and become force.csv rows through one builder (sample_of);
// the state comes to the host only for frames.
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>

#include "engine/sim/simulation.h"
#include "engine/sim/static_run.h"

namespace zona {

FrameSchedule frame_schedule(const Scene& scene, double end) {
  FrameSchedule f;
  f.count = scene.output.frames;
  if (scene.output.frame_interval) {
    f.interval = *scene.output.frame_interval;
    f.count = static_cast<int>(std::floor(end / f.interval + 1e-9)) + 1;
  } else if (f.count > 1) {
    f.interval = end / (f.count - 1);
  }
  return f;
}

namespace {

ForceSample sample_of(const JobRecord& r, Vec3d direction) {
  ForceSample s;
  s.time = r.time;
  s.travel = r.travel;
  s.deformation = r.deformation;
  s.force = r.force;
  s.raw_force = r.raw_force;
  s.force_vector = r.force_vector;
  s.holding_force = dot(r.holding_force, direction);
  s.contacts = r.contacts;
  s.holding_contacts = r.holding_contacts;
  s.elastic_energy = r.elastic_energy;
  s.kinetic_energy = r.kinetic_energy;
  s.punctured = r.puncture.punctured != 0;
  s.status = static_cast<StepStatus>(r.status);
  s.imbalance = r.quasi.imbalance;
  s.kinetic_share = r.quasi.kinetic_share;
  return s;
}

// One line naming the step and the first offender of a failed step.
std::string describe_failure(const JobRecord& r) {
  char line[512];
  if (r.status & kStepNonFinite)
    std::snprintf(line, sizeof line,
                  "step %lld (t %.6g s): a non-finite value (first vertex %lld); nothing after "
                  "it is a result",
                  static_cast<long long>(r.step), r.time, static_cast<long long>(r.first_bad));
  else if (r.status & kStepToolBreach)
    std::snprintf(line, sizeof line,
                  "step %lld (t %.6g s): the needle went through the cell surface without a "
                  "puncture (a surface point %.3g um inside the tip, at %.3g um of deformation "
                  "and %.3g uN): the triangles around the tip stretched until it passed between "
                  "them; a smaller integrator.target_dt, a finer mesh at the needle or an earlier "
                  "puncture may move it; nothing after it is a result",
                  static_cast<long long>(r.step), r.time, r.needle_depth * 1e6,
                  r.deformation * 1e6, r.force * 1e6);
  else {
    char element[64] = "";
    if (r.first_bad >= 0)
      std::snprintf(element, sizeof element, "; first inverted element %lld",
                    static_cast<long long>(r.first_bad));
    std::snprintf(line, sizeof line,
                  "step %lld (t %.6g s): energy blow-up: kinetic %.3g J + elastic %.3g J "
                  "exceeds 10 x the work put in (%.3g J)%s; nothing after it is a result",
                  static_cast<long long>(r.step), r.time, r.kinetic_energy, r.elastic_energy,
                  r.energy_budget, element);
  }
  return line;
}

// Where element t of a halted run lies against the needle: its centroid's distance ahead of the
// tip along the needle axis and off the axis, in the state the run stopped in.
std::string element_place(const Simulation& sim, size_t t, Vec3d tip) {
  const Model& m = sim.model();
  Vec3d c{0, 0, 0};
  for (int32_t v : m.tets[t]) {
    const size_t k = static_cast<size_t>(v);
    c += 0.25 * (sim.mesh().rest_positions[k] + sim.state().u[k]);
  }
  const Vec3d axis = sim.needle_direction();
  const Vec3d d = c - tip;
  const double along = dot(d, axis);
  char line[160];
  std::snprintf(line, sizeof line, " (its centroid %.3g um %s the needle tip, %.3g um off the "
                "needle axis)", std::fabs(along) * 1e6, along >= 0 ? "ahead of" : "behind",
                norm(d - along * axis) * 1e6);
  return line;
}

}  // namespace

RunResult run_simulation(Simulation& sim, const RunOptions& options) {
  if (sim.scene().solver.method == SolverMethod::kStatic) return run_static(sim, options);
  RunResult result;
  const auto wall_start = std::chrono::steady_clock::now();
  auto wall = [&] {
    return std::chrono::duration<double>(std::chrono::steady_clock::now() - wall_start).count();
  };
  JobRunner& job = sim.runner();
  const Scene& scene = sim.scene();
  const double dt = sim.model().dt;
  const double end = sim.end_time();
  const Vec3d direction = sim.needle_direction();
  // The whole run in steps: the step whose time reaches end - dt/2.
  const int64_t total = std::max<int64_t>(1, static_cast<int64_t>(std::ceil(end / dt - 0.5)));
  result.samples.reserve(sim.sample_capacity() + 2);

  // Frames at evenly spaced steps (t = 0 and the end included).
  const FrameSchedule schedule = frame_schedule(scene, end);
  const int frame_count = schedule.count;
  const double frame_dt = schedule.interval;
  const bool frames = options.frame && frame_count > 0;
  int next_frame = 0;
  auto frame_step = [&](int k) {
    return std::min<int64_t>(total, static_cast<int64_t>(std::llround(k * frame_dt / dt)));
  };

  // The initial state as the first sample (a run that starts at step 0).
  // Every recorded sample also goes to RunOptions::on_sample (streamed output).
  auto keep = [&](const ForceSample& s) {
    result.samples.push_back(s);
    if (options.on_sample) options.on_sample(s);
  };
  if (job.steps_advanced() == 0) keep(ForceSample{});
  // The quasi-static warning, said once when a record first shows a failed check (records
  // carry the run's count, so a failure between samples shows in the next one).
  bool warned = false;
  auto warn_once = [&](const JobRecord& r) {
    if (warned || r.quasi.failed_steps == 0 || !sim.quasi_limits().enforce) return;
    warned = true;
    if (options.warning) options.warning(quasi_static_warning(r.quasi, sim.quasi_limits()));
  };
  std::vector<JobRecord> batch;
  batch.reserve(sim.sample_capacity());
  auto drain = [&]() {
    batch.clear();
    if (!job.take_samples(batch)) result.sample_buffer_full = true;
    for (const JobRecord& r : batch) {
      if (result.samples.size() == result.samples.capacity()) {
        result.sample_buffer_full = true;
        break;
      }
      keep(sample_of(r, direction));
      warn_once(r);
      result.peak_force = std::max(result.peak_force, r.force);
      result.peak_deformation = std::max(result.peak_deformation, r.deformation);
      result.status |= r.status;
    }
  };
  bool halted = false;  // the host step's last record failed its check
  auto frame_now = [&](int k) -> bool {
    if (Status s = sim.sync_state(); !s) {
      result.stopped_early = true;
      result.stop_reason = s.error().message;
      return false;
    }
    // The GPU runs ahead of the host: a step that failed after the last record seen is known
    // only now, and its state is not drawn.
    if (sim.job_mode() ? sim.job_halted_ : halted) return false;
    options.frame(sim, k);
    return true;
  };

  // Steps go to the runner in batches: the GPU queues them and returns at once (it bounds what
  // is in flight itself), the CPU runs them. The batch is short enough for progress, frames and
  // the puncture stop to be taken within ~a batch of their step.
  const int64_t batch_steps = 256;
  int64_t done = job.steps_advanced();
  double next_progress = options.progress_interval;
  if (frames && frame_step(0) == 0) {
    if (!frame_now(0)) return result;
    next_frame = 1;
  }
  while (done < total) {
    if (options.stop && options.stop->load(std::memory_order_relaxed)) {
      result.interrupted = true;
      break;
    }
    int64_t target = std::min(total, done + batch_steps);
    if (frames && next_frame < frame_count) target = std::min(target, frame_step(next_frame));
    if (target > done) {
      if (Status s = job.advance(target - done); !s) {
        result.stopped_early = true;
        result.stop_reason = s.error().message;
        break;
      }
      done = target;
    }
    drain();
    JobRecord latest;
    const bool have = job.latest(&latest);
    if (have && sim.job_mode()) sim.report_from_record(latest);
    if (have) halted = latest.halted != 0;
    // A failed step ends the run before anything of it is drawn or written.
    if (have && latest.halted) break;
    while (frames && next_frame < frame_count && frame_step(next_frame) <= done) {
      if (!frame_now(next_frame)) break;
      ++next_frame;
    }
    if (options.progress) {
      const double w = wall();
      if (w >= next_progress && have) {
        options.progress(RunProgress{latest.time, end, w, &sim.report()});
        next_progress = w + options.progress_interval;
      }
    }
    if (options.stop_after_puncture >= 0 && have && latest.puncture.punctured &&
        latest.time >= latest.puncture.time + options.stop_after_puncture)
      break;
  }
  // Everything asked for has run: take the rest.
  if (Status s = job.finish(); !s && !result.stopped_early) {
    result.stopped_early = true;
    result.stop_reason = s.error().message;
  }
  drain();
  result.mass_raises = std::max<int64_t>(0, job.mass_raises());
  JobRecord last;
  if (job.latest(&last)) {
    if (sim.job_mode()) sim.report_from_record(last);
    warn_once(last);
    result.quasi = last.quasi;
    result.steps = last.step;
    result.simulated_time = last.time;
    result.status |= last.status;
    result.peak_force = std::max(result.peak_force, last.force);
    result.peak_deformation = std::max(result.peak_deformation, last.deformation);
    if (last.halted) {
      result.stopped_early = true;
      result.stop_reason = sim.job_mode()
                               ? describe_failure(last)
                               : describe_step_status(static_cast<StepStatus>(last.status),
                                                      sim.model(), sim.state());
      if (sim.job_mode() && !(last.status & (kStepNonFinite | kStepToolBreach)) &&
          last.first_bad >= 0 &&
          static_cast<size_t>(last.first_bad) < sim.model().tet_count() && sim.sync_state())
        result.stop_reason += element_place(sim, static_cast<size_t>(last.first_bad), last.tip);
    }
    if ((result.samples.empty() || result.samples.back().time < last.time) &&
        !result.sample_buffer_full &&
        result.samples.size() < result.samples.capacity())
      keep(sample_of(last, direction));
  }
  if (frames && next_frame < frame_count && !result.stopped_early) {
    frame_now(frame_count - 1);
  }
  result.puncture = sim.puncture();
  result.quasi_limits = sim.quasi_limits();
  result.wall_seconds = wall();
  if (options.progress)
    options.progress(RunProgress{sim.report().time, end, result.wall_seconds, &sim.report()});
  return result;
}


Result<RunResult> run_scene(const Scene& scene, const RunOptions& options) {
  Result<std::unique_ptr<Simulation>> sim = Simulation::create(scene, options.simulation);
  if (!sim.ok()) return sim.error();
  return run_simulation(**sim, options);
}

}  // namespace zona
