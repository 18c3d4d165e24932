// The injection experiment on the job path: the device-resident step (engine/sim/job.h) built from
// the scene, its runner (CPU or the backend's), and the run driver that hands it steps in
// batches and takes back samples.
#include <algorithm>
#include <chrono>
#include <cmath>
#include <numbers>
#include <limits>

#include "engine/fem/fem_element.h"
#include "engine/fem/mass_scaling.h"
#include "engine/sim/simulation.h"

namespace zona {

double holder_swing_omega(const std::vector<Material>& materials, double bore_radius,
                          double mass) {
  if (materials.empty() || !(mass > 0) || !(bore_radius > 0)) return 0;
  const Material* stiff = &materials.front();
  for (const Material& m : materials)
    if (m.young > stiff->young) stiff = &m;
  const double k = 2.0 * stiff->young * bore_radius / (1.0 - stiff->poisson * stiff->poisson);
  return std::sqrt(k / mass);
}

Status Simulation::prepare_job() {
  const std::string& name = scene_.name;
  JobSetup& js = job_setup_;
  JobParams& p = js.params;
  p.dt = model_.dt;

  // The contact pressure stiffness: a multiple of the stiffest material's modulus over the
  // tool's radius, so that it is a property of the tool and the cell, not of the mesh.
  double young_max = 0;
  for (const Material& m : model_.materials) young_max = std::max(young_max, m.young);
  const bool suction = holding_ && holding_->mode == HoldingMode::kSuction;
  const double radius =
      has_needle_ ? scene_.needle.tip_radius : (suction ? holding_->geometry.inner_radius : 0.0);
  if (!(radius > 0) || !(young_max > 0))
    return make_error("%s: contact: no tool radius or material modulus to scale the contact "
                      "stiffness with", name.c_str());
  const double kappa = scene_.contact.stiffness * young_max / radius;

  if (has_needle_) {
    if (!script_.trajectory.time.empty())
      return make_error("%s: needle.trajectory needs contact.model 'kinematic' (the penalty "
                        "step scripts straight insertions)", name.c_str());
    p.has_needle = 1;
    p.needle_flat = scene_.needle.shape == NeedleShape::kFlat ? 1 : 0;
    p.needle_start = script_.start;
    p.needle_direction = script_.direction;
    p.needle_speed = script_.speed;
    p.needle_max_travel = script_.max_travel;
    p.external_tip_max_speed = options_.external_tip_max_speed;
    p.needle_radius = scene_.needle.tip_radius;
    p.needle_pressure_stiffness = kappa;
    p.needle_friction = scene_.needle.friction;
    p.needle_breach_depth = kNeedleBreachFraction * p.needle_radius;
    p.force_filter = scene_.needle.force_filter;
    p.force_filter_weight =
        p.force_filter > 0 ? 1.0 - std::exp(-model_.dt / p.force_filter) : 1.0;
    const PunctureDef& pd = scene_.puncture;
    switch (pd.criterion) {
      case PunctureCriterion::kNone: p.criterion = kJobCriterionNone; break;
      case PunctureCriterion::kForce: p.criterion = kJobCriterionForce; break;
      case PunctureCriterion::kEnergy: p.criterion = kJobCriterionEnergy; break;
      case PunctureCriterion::kStrain:
        return make_error("%s: puncture.criterion 'strain' needs contact.model 'kinematic' (use "
                          "force or energy)", name.c_str());
    }
    p.threshold = pd.threshold;
    p.force_drop = pd.force_drop;
    p.drop_time = pd.drop_time;
    p.shaft_friction = pd.shaft_friction;
    // The entry point's barycentric weights on its rest triangle (the deformation measure).
    if (rest_hit_triangle_ >= 0) {
      const Triangle& tri = surface_.triangles[static_cast<size_t>(rest_hit_triangle_)];
      const Vec3d a = mesh_.rest_positions[static_cast<size_t>(tri[0])];
      const Vec3d b = mesh_.rest_positions[static_cast<size_t>(tri[1])];
      const Vec3d c = mesh_.rest_positions[static_cast<size_t>(tri[2])];
      double t = 0, b1 = 0, b2 = 0;
      const Vec3d d = script_.direction;
      if (ray_triangle(entry_point_ - cell_diameter_ * d, d, a, b, c, &t, &b1, &b2)) {
        p.has_entry = 1;
        for (int k = 0; k < 3; ++k) p.entry_vertex[k] = tri[k];
        p.entry_weight[0] = 1.0 - b1 - b2;
        p.entry_weight[1] = b1;
        p.entry_weight[2] = b2;
      }
    }
  }
  if (suction) {
    p.has_rim = 1;
    p.rim_mouth = holding_->geometry.mouth;
    p.rim_axis = holding_->geometry.axis;
    p.rim_inner_radius = holding_->geometry.inner_radius;
    p.rim_outer_radius = holding_->geometry.outer_radius;
    p.rim_edge_radius = holding_->geometry.edge_radius;
    p.rim_pressure_stiffness = kappa;
    p.rim_friction = holding_->friction;
    p.rim_damping = scene_.contact.rim_damping;
    // Suction ramped in over half the needle's approach, so the cell settles without ringing.
    double ramp_time = 0.05 * end_time_;
    if (has_needle_ && script_.speed > 0)
      ramp_time = std::min(ramp_time, 0.5 * scene_.needle.standoff / script_.speed);
    p.suction_ramp_time = ramp_time;
  }
  p.quasi = quasi_limits_;
  p.stiffness_damping_rate = scene_.integrator.stiffness_damping / model_.dt;
  p.sample_interval = std::max(scene_.output.sample_interval, 0.0);
  p.stiffness_window = options_.stiffness_window;
  p.energy_blowup_factor = model_.energy_blowup_factor;
  p.energy_floor = model_.energy_floor;

  // Tool vertices: the boundary surface, with its areas and the suction loads.
  const size_t ns = surface_.vertices.size();
  js.tool_vertices = surface_.vertices;
  js.tool_area = surface_.vertex_area;
  js.tool_suction.assign(ns, Vec3d{0, 0, 0});
  if (suction)
    for (size_t i = 0; i < holding_->patch_vertices.size(); ++i) {
      const int32_t k = surface_.surface_index[static_cast<size_t>(holding_->patch_vertices[i])];
      if (k >= 0) js.tool_suction[static_cast<size_t>(k)] = holding_->suction_force[i];
    }
  if (has_needle_ && scene_.contact.needle_on_faces) {
    p.needle_on_faces = 1;
    const size_t nf = surface_.triangles.size();
    js.tool_faces.resize(nf);
    js.tool_face_area.resize(nf);
    for (size_t f = 0; f < nf; ++f) {
      const Triangle& tri = surface_.triangles[f];
      for (int c = 0; c < 3; ++c)
        js.tool_faces[f][static_cast<size_t>(c)] =
            surface_.surface_index[static_cast<size_t>(tri[static_cast<size_t>(c)])];
      const Vec3d a = mesh_.rest_positions[static_cast<size_t>(tri[0])];
      const Vec3d b = mesh_.rest_positions[static_cast<size_t>(tri[1])];
      const Vec3d c = mesh_.rest_positions[static_cast<size_t>(tri[2])];
      js.tool_face_area[f] = 0.5 * norm(cross(b - a, c - a));
    }
  }
  const double row_dt = std::max(p.sample_interval, model_.dt);
  js.sample_capacity = std::min<size_t>(
      static_cast<size_t>(std::ceil(end_time_ / row_dt * (1 + 1e-9))) + 8, size_t{1} << 22);

  // The contact's stable step: a vertex inside a tool carries the spring kappa * area on top of
  // its elements; its mass is raised where needed so that this spring alone is stable with
  // margin at the model's step (m >= k dt^2, i.e. omega dt <= 1), like selective mass scaling
  // does for small elements.
  const double dt = model_.dt;
  int64_t raised = 0;
  double added = 0, total = 0;
  for (double m : model_.vertex_mass) total += m;
  for (size_t i = 0; i < ns; ++i) {
    const size_t v = static_cast<size_t>(js.tool_vertices[i]);
    const double need = kappa * js.tool_area[i] * dt * dt;
    const double m = model_.vertex_mass[v];
    if (!(need > m) || model_.vertex_fixed[v]) continue;
    set_vertex_mass(model_, v, need);
    added += need - m;
    ++raised;
  }
  if (raised > 0) {
    char line[200];
    std::snprintf(line, sizeof line,
                  "contact: %lld surface vertices' masses raised for the contact stiffness "
                  "(total mass x %.4g)",
                  static_cast<long long>(raised), total > 0 ? (total + added) / total : 1.0);
    notes_.push_back(line);
  }

  // Drift damping (job_drift_update). "auto" matches it to the cell's swing on its holder: the
  // whole scaled mass M (after the raises above) on the stiffness of the held side, taken as
  // Boussinesq's rigid flat punch of the bore's radius a on an elastic half-space,
  // k = 2 E a / (1 - nu^2); omega_s = sqrt(k / M), damping 2 omega_s (critical), window
  // 3 / omega_s. On the mouse cells the estimate is within a factor of about 1.5 of the swing
  // the runs show (a 20k cell at 5 us: 36 ms measured, 50 ms estimated).
  {
    const IntegratorDef& in = scene_.integrator;
    double omega = 0;
    if (suction && (!in.drift_damping || !in.drift_window)) {
      double mass = 0;
      for (size_t v = 0; v < model_.vertex_count(); ++v)
        if (!model_.vertex_fixed[v]) mass += model_.vertex_mass[v];
      omega = holder_swing_omega(model_.materials, holding_->geometry.inner_radius, mass);
    }
    p.drift_damping = in.drift_damping ? *in.drift_damping : 2.0 * omega;
    p.drift_window = in.drift_window ? *in.drift_window : (omega > 0 ? 3.0 / omega : 0.05);
    if (p.drift_damping > 0 && (!in.drift_damping || !in.drift_window)) {
      char line[200];
      std::snprintf(line, sizeof line,
                    "drift damping: %.4g 1/s over a %.3g ms window (the swing on the holder "
                    "estimated at a %.3g ms period)",
                    p.drift_damping, p.drift_window * 1e3,
                    omega > 0 ? 2e3 * std::numbers::pi / omega : 0.0);
      notes_.push_back(line);
    }
  }

  // Dynamic mass scaling: each element's density need at rest for the scaling's safety, with
  // the conservative stiffness measure (lambda_s + 2 mu) sum_j |g_j|^2 (>= the build bound's
  // lambda_s sum|g|^2 + 2 mu lambda_max(G G^T), without its eigenvalue), and the stiffening
  // that the current masses carry for every element (the gate: below it no element asks).
  const double safety = scene_.integrator.dynamic_mass_safety;
  const ConstitutiveModel law = model_.constitutive;
  if (safety > 0 && law != ConstitutiveModel::kLinear) {
    p.mass_interval = 24;
    p.mass_law = static_cast<int32_t>(law == ConstitutiveModel::kStableNeoHookean
                                          ? StiffeningLaw::kStableNeoHookean
                                          : StiffeningLaw::kSvk);
    const size_t nt = model_.tet_count();
    js.vertex_volume = vertex_lumped_volumes(model_);
    js.tet_rest_need.assign(nt, 0.0);
    const double scale = (dt / safety) * (dt / safety);
    double gate = std::numeric_limits<double>::infinity();
    for (size_t t = 0; t < nt; ++t) {
      const Lame& lame = model_.tet_lame(t);
      const double lam = law == ConstitutiveModel::kStableNeoHookean
                             ? snh_lambda(lame.lambda, lame.mu)
                             : lame.lambda;
      double g_sq = 0;
      for (const Vec3d& g : model_.tet_shape[t].grad) g_sq += dot(g, g);
      const double need = (lam + 2.0 * lame.mu) * g_sq * scale;
      js.tet_rest_need[t] = need;
      double rho = std::numeric_limits<double>::infinity();
      for (int32_t v : model_.tets[t]) {
        const size_t k = static_cast<size_t>(v);
        if (js.vertex_volume[k] > 0) rho = std::min(rho, model_.vertex_mass[k] / js.vertex_volume[k]);
      }
      if (need > 0) gate = std::min(gate, rho / need);
    }
    p.mass_gate = std::isfinite(gate) ? std::max(1.0, gate) : 1.0;
  }
  return Status::ok_status();
}

Status Simulation::start_job() {
  // A CPU backend object is only a test hook of the kinematic path: the CPU runner works on the
  // simulation's own state in place.
  if (backend_ && std::string(backend_->name()) == "cpu") backend_.reset();
  if (backend_) {
    Result<JobRunner*> runner = backend_->start_job(job_setup_);
    if (!runner.ok()) return make_error("%s: %s", scene_.name.c_str(), runner.error().message.c_str());
    job_ = *runner;
  } else {
    cpu_job_ = make_cpu_job_runner(model_, state_, job_setup_);
    job_ = cpu_job_.get();
  }
  backend_description_ = job_->description();
  return Status::ok_status();
}

void Simulation::report_from_record(const JobRecord& r) {
  NeedleReport& o = report_;
  o.time = r.time;
  o.step = r.step;
  o.tip = r.tip;
  o.travel = r.travel;
  o.deformation = r.deformation;
  o.force = r.force;
  o.raw_force = r.raw_force;
  o.force_vector = r.force_vector;
  o.constraint_force = r.force_vector;
  o.stiffness = r.stiffness;
  o.contacts = r.contacts;
  o.holding_contacts = r.holding_contacts;
  o.holding_force = r.holding_force;
  o.elastic_energy = r.elastic_energy;
  o.kinetic_energy = r.kinetic_energy;
  o.punctured = r.puncture.punctured != 0;
  o.status = r.status;
  o.quasi = r.quasi;
  last_status_ = r.status;
  job_halted_ = r.halted != 0;
  tip_ = r.tip;
  if (r.puncture.punctured && !job_puncture_.punctured) {
    PunctureRecord& q = job_puncture_;
    q.punctured = true;
    q.step = r.puncture.step;
    q.time = r.puncture.time;
    q.needle_travel = r.puncture.needle_travel;
    q.deformation = r.puncture.deformation;
    q.force = r.puncture.force;
    q.energy = r.puncture.energy;
    q.force_vector = r.puncture.force_vector;
  }
}

StepStatus Simulation::step_job() {
  if (job_halted_) return report_.status | kStepNotAdvanced;
  if (Status s = job_->advance(1); !s) {
    notes_.push_back(s.error().message);
    job_halted_ = true;
    return kStepNonFinite;
  }
  JobRecord r;
  if (job_->latest(&r)) report_from_record(r);
  return report_.status;
}

Status Simulation::sync_state() {
  if (!job_) return Status::ok_status();
  if (Status s = job_->finish(); !s) return s;
  if (Status s = job_->download(state_); !s) return s;
  JobRecord r;
  if (job_->latest(&r)) report_from_record(r);
  return Status::ok_status();
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
  const Vec3d axis = sim.job_setup().params.needle_direction;
  const Vec3d d = c - tip;
  const double along = dot(d, axis);
  char line[160];
  std::snprintf(line, sizeof line, " (its centroid %.3g um %s the needle tip, %.3g um off the "
                "needle axis)", std::fabs(along) * 1e6, along >= 0 ? "ahead of" : "behind",
                norm(d - along * axis) * 1e6);
  return line;
}

}  // namespace

RunResult run_job_simulation(Simulation& sim, const RunOptions& options) {
  RunResult result;
  const auto wall_start = std::chrono::steady_clock::now();
  auto wall = [&] {
    return std::chrono::duration<double>(std::chrono::steady_clock::now() - wall_start).count();
  };
  JobRunner& job = *sim.job();
  const Scene& scene = sim.scene();
  const double dt = sim.model().dt;
  const double end = sim.end_time();
  const Vec3d direction = sim.job_setup().params.needle_direction;
  // The whole run in steps: the step whose time reaches end - dt/2.
  const int64_t total = std::max<int64_t>(1, static_cast<int64_t>(std::ceil(end / dt - 0.5)));
  result.samples.reserve(sim.job_setup().sample_capacity + 2);

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
  batch.reserve(sim.job_setup().sample_capacity);
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
  auto frame_now = [&](int k) -> bool {
    if (Status s = sim.sync_state(); !s) {
      result.stopped_early = true;
      result.stop_reason = s.error().message;
      return false;
    }
    // The GPU runs ahead of the host: a step that failed after the last record seen is known
    // only now, and its state is not drawn.
    if (sim.job_halted_) return false;
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
    if (have) sim.report_from_record(latest);
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
    sim.report_from_record(last);
    warn_once(last);
    result.quasi = last.quasi;
    result.steps = last.step;
    result.simulated_time = last.time;
    result.status |= last.status;
    result.peak_force = std::max(result.peak_force, last.force);
    result.peak_deformation = std::max(result.peak_deformation, last.deformation);
    if (last.halted) {
      result.stopped_early = true;
      result.stop_reason = describe_failure(last);
      if (!(last.status & (kStepNonFinite | kStepToolBreach)) && last.first_bad >= 0 &&
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

}  // namespace zona
