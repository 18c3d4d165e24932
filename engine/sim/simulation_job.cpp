// The injection experiment on the job path: the device-resident step (engine/sim/job.h) built from
// the scene and its runner (CPU or the backend's). The run driver is engine/sim/run.cpp.
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
  if (particles_) young_max = particles_->membrane_modulus;  // the body's material is a placeholder
  const bool suction = holding_ && holding_->mode == HoldingMode::kSuction;
  const double radius =
      has_needle_ ? scene_.needle.tip_radius : (suction ? holding_->geometry.inner_radius : 0.0);
  if (!(radius > 0) || !(young_max > 0))
    return make_error("%s: contact: no tool radius or material modulus to scale the contact "
                      "stiffness with", name.c_str());
  double kappa = scene_.contact.stiffness * young_max / radius;
  if (particles_) {
    // The particle model's membrane is as stiff as its explicit step carries (dt_safety up to
    // 0.9 of the springs' limit), and its masses are already scaled for it: raising them for a
    // contact spring of the FEM's scale would multiply the membrane's inertia (by 168 on the
    // 642-particle cell). Its penalty is the stiffest that the step carries without a raise,
    // kappa A_v dt^2 <= m_v / 4 at every free membrane vertex (omega^2 dt^2 grows by at most
    // 1/4 over the springs' own); contact.stiffness does not apply.
    double cap = std::numeric_limits<double>::infinity();
    for (size_t i = 0; i < surface_.vertices.size(); ++i) {
      const size_t v = static_cast<size_t>(surface_.vertices[i]);
      const double area = surface_.vertex_area[i];
      if (model_.vertex_fixed[v] || !(area > 0)) continue;
      cap = std::min(cap, 0.25 * model_.vertex_mass[v] / (area * model_.dt * model_.dt));
    }
    if (!std::isfinite(cap))
      return make_error("%s: contact: no free membrane particle for the needle to touch", name.c_str());
    kappa = cap;
    char line[200];
    std::snprintf(line, sizeof line,
                  "contact: the particle membrane's penalty %.4g Pa/m (the stiffest its step "
                  "carries without a mass raise)", kappa);
    notes_.push_back(line);
  }

  if (has_needle_) {
    if (!script_.trajectory.time.empty()) {
      p.needle.path_count = static_cast<int32_t>(script_.trajectory.time.size());
      p.needle.path_time = script_.trajectory.time.data();
      p.needle.path_position = script_.trajectory.position.data();
    }
    p.needle.on = 1;
    p.needle.flat = scene_.needle.shape == NeedleShape::kFlat ? 1 : 0;
    p.needle.start = script_.start;
    p.needle.direction = script_.direction;
    p.needle.speed = script_.speed;
    p.needle.max_travel = script_.max_travel;
    p.needle.external_tip_max_speed = options_.external_tip_max_speed;
    p.needle.radius = scene_.needle.tip_radius;
    p.needle.pressure_stiffness = kappa;
    p.needle.friction = scene_.needle.friction;
    p.needle.stick_length = scene_.needle.stick_length;
    p.needle.breach_depth = kNeedleBreachFraction * p.needle.radius;
    p.record.force_filter = scene_.needle.force_filter;
    p.record.force_filter_weight =
        p.record.force_filter > 0 ? 1.0 - std::exp(-model_.dt / p.record.force_filter) : 1.0;
    const PunctureDef& pd = scene_.puncture;
    switch (pd.criterion) {
      case PunctureCriterion::kNone: p.puncture.criterion = kJobCriterionNone; break;
      case PunctureCriterion::kForce: p.puncture.criterion = kJobCriterionForce; break;
      case PunctureCriterion::kEnergy: p.puncture.criterion = kJobCriterionEnergy; break;
      case PunctureCriterion::kStrain:
        // The membrane's stretch on the triangles the needle touches (needle_face_strain).
        if (!scene_.contact.needle_on_faces)
          return make_error("%s: puncture.criterion 'strain' takes the stretch of the surface "
                            "triangles the needle touches; this scene's needle loads vertices "
                            "(use force or energy)", name.c_str());
        p.puncture.criterion = kJobCriterionStrain;
        break;
    }
    p.puncture.threshold = pd.threshold;
    p.puncture.force_drop = pd.force_drop;
    p.puncture.drop_time = pd.drop_time;
    p.puncture.shaft_friction = pd.shaft_friction;
    // The entry point's barycentric weights on its rest triangle (the deformation measure).
    if (rest_hit_triangle_ >= 0) {
      const Triangle& tri = surface_.triangles[static_cast<size_t>(rest_hit_triangle_)];
      const Vec3d a = mesh_.rest_positions[static_cast<size_t>(tri[0])];
      const Vec3d b = mesh_.rest_positions[static_cast<size_t>(tri[1])];
      const Vec3d c = mesh_.rest_positions[static_cast<size_t>(tri[2])];
      double t = 0, b1 = 0, b2 = 0;
      const Vec3d d = script_.direction;
      if (ray_triangle(entry_point_ - cell_diameter_ * d, d, a, b, c, &t, &b1, &b2)) {
        p.record.has_entry = 1;
        for (int k = 0; k < 3; ++k) p.record.entry_vertex[k] = tri[k];
        p.record.entry_weight[0] = 1.0 - b1 - b2;
        p.record.entry_weight[1] = b1;
        p.record.entry_weight[2] = b2;
      }
    }
  }
  if (suction) {
    p.rim.on = 1;
    p.rim.mouth = holding_->geometry.mouth;
    p.rim.axis = holding_->geometry.axis;
    p.rim.inner_radius = holding_->geometry.inner_radius;
    p.rim.outer_radius = holding_->geometry.outer_radius;
    p.rim.edge_radius = holding_->geometry.edge_radius;
    p.rim.pressure_stiffness = kappa;
    p.rim.friction = holding_->friction;
    p.rim.stick_length = holding_->stick_length;
    p.rim.damping = scene_.contact.rim_damping;
    // Suction ramped in over half the needle's approach, so the cell settles without ringing.
    double ramp_time = 0.05 * end_time_;
    if (has_needle_ && script_.speed > 0)
      ramp_time = std::min(ramp_time, 0.5 * scene_.needle.standoff / script_.speed);
    p.rim.suction_ramp_time = ramp_time;
  }
  p.quasi = quasi_limits_;
  p.damping.stiffness_rate = scene_.integrator.stiffness_damping / model_.dt;
  p.record.sample_interval = std::max(scene_.output.sample_interval, 0.0);
  p.record.stiffness_window = options_.stiffness_window;
  p.health.energy_blowup_factor = model_.energy_blowup_factor;
  p.health.energy_floor = model_.energy_floor;

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
    p.needle.on_faces = 1;
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
  const double row_dt = std::max(p.record.sample_interval, model_.dt);
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
    set_vertex_mass(model_, v, need);  // (never the particle model's: its kappa is capped above)
    added += need - m;
    ++raised;
  }
  if (raised > 0) {
    char line[200];
    std::snprintf(line, sizeof line,
                  "contact: %lld surface vertices' masses raised for the contact stiffness "
                  "(total mass x %.4g)",
                  static_cast<long long>(raised), total > 0 ? (total + added) / total : 1.0);
    note_explicit(line);
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
    p.damping.drift = in.drift_damping ? *in.drift_damping : 2.0 * omega;
    p.damping.drift_window = in.drift_window ? *in.drift_window : (omega > 0 ? 3.0 / omega : 0.05);
    if (p.damping.drift > 0 && (!in.drift_damping || !in.drift_window)) {
      char line[200];
      std::snprintf(line, sizeof line,
                    "drift damping: %.4g 1/s over a %.3g ms window (the swing on the holder "
                    "estimated at a %.3g ms period)",
                    p.damping.drift, p.damping.drift_window * 1e3,
                    omega > 0 ? 2e3 * std::numbers::pi / omega : 0.0);
      note_explicit(line);
    }
  }

  // Dynamic mass scaling: each element's density need at rest for the scaling's safety, with
  // the conservative stiffness measure (lambda_s + 2 mu) sum_j |g_j|^2 (>= the build bound's
  // lambda_s sum|g|^2 + 2 mu lambda_max(G G^T), without its eigenvalue), and the stiffening
  // that the current masses carry for every element (the gate: below it no element asks).
  const double safety = scene_.integrator.dynamic_mass_safety;
  const ConstitutiveModel law = model_.constitutive;
  if (safety > 0 && law != ConstitutiveModel::kLinear) {
    p.mass.interval = 24;
    p.mass.law = static_cast<int32_t>(law == ConstitutiveModel::kStableNeoHookean
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
    p.mass.gate = std::isfinite(gate) ? std::max(1.0, gate) : 1.0;
  }
  return Status::ok_status();
}

Status Simulation::start_job() {
  // A CPU backend object is only a test hook of the Backend path (SimulationOptions::
  // keep_cpu_backend): an FEM runner works on the simulation's own state in place; the particle
  // model's body stages take it, as they would a GPU backend.
  if (backend_ && std::string(backend_->name()) == "cpu" && !particles_) backend_.reset();
  if (particles_) {
    // The particle model: the job's tool, measure and record stages on the host around its
    // own elastic and integrate stages (in place, or on its Backend: ParticleBody).
    particle_body_ = std::make_unique<ParticleBody>(*particles_, backend_.get());
    cpu_job_ = make_cpu_job_runner(model_, state_, job_setup_, particle_body_.get());
    job_ = cpu_job_.get();
  } else if (backend_) {
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
  o.stiffness = r.stiffness;
  o.contacts = r.contacts;
  o.holding_contacts = r.holding_contacts;
  o.holding_force = r.holding_force;
  o.elastic_energy = r.elastic_energy;
  o.kinetic_energy = r.kinetic_energy;
  o.max_strain = r.max_strain;
  o.punctured = r.puncture.punctured != 0;
  o.status = r.status;
  o.quasi = r.quasi;
  last_status_ = r.status;
  job_halted_ = r.halted != 0;
  if (r.puncture.punctured && !job_puncture_.punctured) {
    PunctureRecord& q = job_puncture_;
    q.punctured = true;
    q.step = r.puncture.step;
    q.time = r.puncture.time;
    q.needle_travel = r.puncture.needle_travel;
    q.deformation = r.puncture.deformation;
    q.force = r.puncture.force;
    q.energy = r.puncture.energy;
    q.max_strain = r.puncture.max_strain;
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

}  // namespace zona
