// The injection experiment: building it from a scene, and the kinematic-contact split step.
// (Over 800 lines: the kinematic-contact step shares the Simulation's private state with the
// setup; the penalty step's setup is in simulation_job.cpp, the run driver in run.cpp.)
#include "engine/sim/simulation.h"

#include "engine/sim/kinematic_runner.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <numbers>
#include <limits>
#include <set>

#include "engine/core/parallel.h"
#include "engine/fem/mass_scaling.h"
#include "engine/scene/scene_mesh.h"

namespace zona {
namespace {

// Volume-weighted centroid of the mesh [m].
Vec3d mesh_centroid(const Mesh& mesh) {
  Vec3d sum{0, 0, 0};
  double volume = 0;
  for (size_t t = 0; t < mesh.tet_count(); ++t) {
    const Tet& e = mesh.tets[t];
    const double v = std::fabs(tet_rest_volume(mesh, t));
    sum += (v / 4.0) * (mesh.rest_positions[e[0]] + mesh.rest_positions[e[1]] +
                        mesh.rest_positions[e[2]] + mesh.rest_positions[e[3]]);
    volume += v;
  }
  return volume > 0 ? sum / volume : Vec3d{0, 0, 0};
}

double bounding_diagonal(const Mesh& mesh) {
  const Aabb box = mesh_bounds(mesh);
  return norm(box.hi - box.lo);
}

// Vertices a VertexSelect picks (rest positions).
std::vector<int32_t> select_vertices(const Mesh& mesh, const ContactSurface& surface,
                                     const VertexSelect& w) {
  std::vector<uint8_t> in_region;
  if (!w.region.empty()) {
    in_region.assign(mesh.vertex_count(), 0);
    for (size_t t = 0; t < mesh.tet_count(); ++t)
      if (mesh.region_name(mesh.tet_region.empty() ? 0 : mesh.tet_region[t]) == w.region)
        for (int32_t v : mesh.tets[t]) in_region[static_cast<size_t>(v)] = 1;
  }
  std::vector<int32_t> out;
  for (size_t v = 0; v < mesh.vertex_count(); ++v) {
    const Vec3d x = mesh.rest_positions[v];
    if (w.surface_only && surface.surface_index[v] < 0) continue;
    if (!in_region.empty() && !in_region[v]) continue;
    const double h = dot(x, w.normal);
    if (h > w.below || h < w.above) continue;
    if (w.center && norm(x - *w.center) > w.radius) continue;
    out.push_back(static_cast<int32_t>(v));
  }
  return out;
}

// The model descriptor of a scene: constitutive law, materials per region (with masses from
// density, total mass or vertex mass), time stepping. Fixed vertices are added by the caller.
Result<ModelDesc> model_desc_from_scene(const Scene& scene, const Mesh& mesh,
                                        const SimulationOptions& options,
                                        std::vector<std::string>* notes) {
  ModelDesc desc;
  switch (scene.model) {
    case ModelKind::kSvk: desc.constitutive = ConstitutiveModel::kSvk; break;
    case ModelKind::kLinear: desc.constitutive = ConstitutiveModel::kLinear; break;
    case ModelKind::kStableNeoHookean:
      desc.constitutive = ConstitutiveModel::kStableNeoHookean;
      break;
    case ModelKind::kParticles:
      return make_error(
          "%s: model 'particles' is not supported by the FEM simulation (use svk, "
          "linear or neohookean)",
          scene.name.c_str());
  }
  desc.nodal_pressure = scene.nodal_pressure;
  desc.precompute_threads = setup_thread_count(options.threads);
  desc.inversion = desc.constitutive == ConstitutiveModel::kSvk ? options.inversion
                                                                 : InversionHandling::kReport;

  // Which material entry each tetrahedron takes: its region's own, else "default".
  const MaterialDef* fallback = find_material(scene, "default");
  std::set<int32_t> tags;
  for (size_t t = 0; t < mesh.tet_count(); ++t) tags.insert(mesh.tet_region.empty() ? 0 : mesh.tet_region[t]);
  std::vector<std::pair<int32_t, const MaterialDef*>> entries;  // tag -> definition
  for (int32_t tag : tags) {
    const MaterialDef* m = nullptr;
    for (const RegionMaterialDef& r : scene.materials)
      if (r.region == mesh.region_name(tag)) m = &r.material;
    if (!m) m = fallback;
    if (!m)
      return make_error("%s: materials: region '%s' has no material and there is no 'default'",
                        scene.name.c_str(), mesh.region_name(tag).c_str());
    entries.emplace_back(tag, m);
  }
  for (const RegionMaterialDef& r : scene.materials) {
    if (r.region == "default") continue;
    bool used = false;
    for (int32_t tag : tags) used = used || mesh.region_name(tag) == r.region;
    if (!used) notes->push_back("materials." + r.region + ": the mesh has no such region (skipped)");
  }

  // Mass: density as given, or a total mass spread over the entry's volume; a per-vertex mass
  // is one value for the whole model (ModelDesc::vertex_mass).
  auto volume_of = [&](const MaterialDef* m) {
    double v = 0;
    for (size_t t = 0; t < mesh.tet_count(); ++t) {
      const int32_t tag = mesh.tet_region.empty() ? 0 : mesh.tet_region[t];
      for (const auto& [et, em] : entries)
        if (et == tag && em == m) v += std::fabs(tet_rest_volume(mesh, t));
    }
    return v;
  };
  auto to_material = [&](const MaterialDef* m) -> Result<Material> {
    Material out;
    out.young = m->young;
    out.poisson = m->poisson;
    out.damping = m->damping;
    switch (m->mass_spec) {
      case MassSpec::kDensity: out.density = m->density; break;
      case MassSpec::kTotalMass: {
        const double v = volume_of(m);
        if (!(v > 0)) return make_error("%s: materials: a 'mass' covers no volume", scene.name.c_str());
        out.density = m->total_mass / v;
        // A mass is of one cell size: said with its density, so that a resized cell that keeps
        // it (a lighter or heavier material) does not go unnoticed.
        char line[240];
        std::snprintf(line, sizeof line,
                      "materials: a mass of %.5g kg over %.5g m^3 of mesh is a density of %.4g "
                      "kg/m^3 (give \"density\" to keep it when the cell's size changes)",
                      m->total_mass, v, out.density);
        notes->push_back(line);
        break;
      }
      case MassSpec::kVertexMass:
        if (desc.vertex_mass > 0 && desc.vertex_mass != m->vertex_mass)
          return make_error("%s: materials: different vertex_mass values per region are not "
                            "supported", scene.name.c_str());
        desc.vertex_mass = m->vertex_mass;
        break;
    }
    return out;
  };
  bool default_set = false;
  for (const auto& [tag, m] : entries) {
    Result<Material> mat = to_material(m);
    if (!mat.ok()) return mat.error();
    if (m == fallback && !default_set) {
      desc.material = *mat;
      default_set = true;
    }
    if (m != fallback) desc.region_materials.push_back({tag, *mat});
  }
  if (!default_set && !entries.empty()) desc.material = desc.region_materials.front().material;

  const IntegratorDef& in = scene.integrator;
  desc.dt = in.dt ? *in.dt : 0.0;
  desc.dt_safety = in.dt_safety;
  desc.mass_scaling = in.mass_scaling;
  // Selective scaling is applied after the build (engine/fem/mass_scaling.h).
  desc.target_dt = in.target_dt && in.mass_scaling_mode == MassScalingMode::kUniform ? *in.target_dt : 0.0;
  return desc;
}

}  // namespace

Result<std::unique_ptr<Simulation>> Simulation::create(const Scene& scene,
                                                       const SimulationOptions& options) {
  std::unique_ptr<Simulation> sim(new Simulation());
  if (Status s = sim->build(scene, options); !s) return s.error();
  return sim;
}

Simulation::~Simulation() = default;

Status Simulation::build(const Scene& scene, const SimulationOptions& options) {
  scene_ = scene;
  options_ = options;
  const std::string& name = scene.name;
  if (options.backend_substeps < 1)
    return make_error("simulation: backend_substeps must be >= 1, got %d", options.backend_substeps);
  if (!(options.slip_relax > 0 && options.slip_relax <= 1))
    return make_error("simulation: slip_relax must be in (0, 1], got %g", options.slip_relax);

  // Wall time of each setup stage, reported as one note ("setup: mesh 3.1 s, ..."): a fine
  // mesh's setup is a third of its run to the puncture.
  using SetupClock = std::chrono::steady_clock;
  SetupClock::time_point stage_start = SetupClock::now();
  std::string stage_times;
  auto stage_done = [&](const char* stage) {
    const SetupClock::time_point now = SetupClock::now();
    char item[64];
    std::snprintf(item, sizeof item, "%s%s %.2f s", stage_times.empty() ? "" : ", ", stage,
                  std::chrono::duration<double>(now - stage_start).count());
    stage_times += item;
    stage_start = now;
  };

  // Mesh and surface. The particle model (Asgari et al.) builds its own body mesh: the membrane
  // triangulation plus fan tetrahedra to the centre particle (engine/particles/particle_model.h).
  if (scene.model == ModelKind::kParticles) {
    Result<ParticleModelDesc> pd = particle_desc_from_scene(scene);
    if (!pd.ok()) return pd.error();
    Result<ParticleModel> pm = build_particle_model(*pd);
    if (!pm.ok()) return make_error("%s: %s", name.c_str(), pm.error().message.c_str());
    particles_ = std::make_unique<ParticleModel>(std::move(*pm));
    mesh_ = particle_body_mesh(*particles_);
  } else {
    Result<Mesh> mesh = build_scene_mesh(scene, &notes_);
    if (!mesh.ok()) return mesh.error();
    mesh_ = std::move(*mesh);
  }
  stage_done("mesh");
  Result<ContactSurface> surface = build_contact_surface(mesh_);
  if (!surface.ok()) return make_error("%s: %s", name.c_str(), surface.error().message.c_str());
  surface_ = std::move(*surface);
  stage_done("surface");
  // A generated cell is centred at the origin; a file mesh at its centroid.
  centre_ = scene.mesh.source == MeshSource::kGenerate ? Vec3d{0, 0, 0} : mesh_centroid(mesh_);
  const double diagonal = bounding_diagonal(mesh_);
  const std::vector<Vec3d> zero(mesh_.vertex_count(), Vec3d{0, 0, 0});

  // Needle axis, entry point and automatic start: rays along the axis on the rest surface.
  has_needle_ = scene.needle.enabled;
  Vec3d d = scene.needle.direction / norm(scene.needle.direction);
  if (has_needle_) {
    script_.direction = d;
    script_.speed = scene.needle.speed;
    script_.max_travel = scene.needle.max_travel;
    if (!scene.needle.trajectory.empty()) {
      Result<NeedleTrajectory> tr = read_needle_trajectory(scene.needle.trajectory);
      if (!tr.ok()) return tr.error();
      script_.trajectory = std::move(*tr);
    }
    const Vec3d through = scene.needle.start ? *scene.needle.start : centre_;
    const RayHit in = cast_ray(surface_, mesh_.rest_positions, zero, through - 2 * diagonal * d, d, -1);
    const RayHit out =
        cast_ray(surface_, mesh_.rest_positions, zero, through + 2 * diagonal * d, -1.0 * d, -1);
    if (in.triangle < 0 || out.triangle < 0) {
      if (!scene.needle.start)
        return make_error("%s: needle: the axis through the cell centre misses the surface", name.c_str());
      notes_.push_back("needle: the axis misses the cell; deformation is reported as 0");
      entry_point_ = *scene.needle.start;
    } else {
      entry_point_ = in.point;
      cell_diameter_ = dot(out.point - in.point, d);
      rest_hit_triangle_ = in.triangle;
    }
    script_.start = scene.needle.start ? *scene.needle.start : entry_point_ - scene.needle.standoff * d;
    if (!script_.trajectory.time.empty()) script_.start = script_.trajectory.position.front();
  } else {
    const Aabb box = mesh_bounds(mesh_);
    cell_diameter_ = box.hi.x - box.lo.x;
  }
  if (!(cell_diameter_ > 0)) cell_diameter_ = scene.mesh.generate.diameter;

  // Holding pipette and boundary conditions -> fixed vertices.
  std::vector<int32_t> fixed;
  if (scene.holding_pipette.enabled) {
    Result<HoldingSetup> h = make_holding(scene.holding_pipette, surface_, mesh_.rest_positions, centre_, d);
    if (!h.ok()) return make_error("%s: %s", name.c_str(), h.error().message.c_str());
    holding_ = std::move(*h);
    if (holding_->mode == HoldingMode::kFixed)
      fixed.insert(fixed.end(), holding_->patch_vertices.begin(), holding_->patch_vertices.end());
  }
  for (size_t i = 0; i < scene.boundary.size(); ++i) {
    const BoundaryDef& b = scene.boundary[i];
    if (b.type == BoundaryKind::kFixed) {
      const std::vector<int32_t> sel = select_vertices(mesh_, surface_, b.where);
      if (sel.empty()) return make_error("%s: boundary[%zu]: selects no vertex", name.c_str(), i);
      fixed.insert(fixed.end(), sel.begin(), sel.end());
    } else {
      const Vec3d dir = b.direction / norm(b.direction);
      size_t n = 0;
      for (int32_t v : surface_.vertices)
        if (norm(mesh_.rest_positions[static_cast<size_t>(v)] - b.center) <= b.radius) {
          indent_vertices_.push_back(v);
          indent_direction_.push_back(dir);
          indent_depth_.push_back(b.depth);
          indent_speed_.push_back(b.speed);
          ++n;
        }
      if (n == 0) return make_error("%s: boundary[%zu]: the indent patch holds no surface vertex", name.c_str(), i);
    }
  }
  std::sort(fixed.begin(), fixed.end());
  fixed.erase(std::unique(fixed.begin(), fixed.end()), fixed.end());
  {
    std::vector<int32_t> sorted_indent = indent_vertices_;
    std::sort(sorted_indent.begin(), sorted_indent.end());
    if (std::adjacent_find(sorted_indent.begin(), sorted_indent.end()) != sorted_indent.end())
      return make_error("%s: boundary: indent patches overlap", name.c_str());
    for (int32_t v : sorted_indent)
      if (std::binary_search(fixed.begin(), fixed.end(), v))
        return make_error("%s: boundary: vertex %d is both fixed and indented", name.c_str(), v);
  }

  // Model.
  if (particles_) {
    Result<Model> model = particle_body_model(*particles_, mesh_, fixed);
    if (!model.ok()) return make_error("%s: %s", name.c_str(), model.error().message.c_str());
    model_ = std::move(*model);
    if (scene.integrator.mass_scaling_mode == MassScalingMode::kSelective)
      notes_.push_back("particles: mass scaling is uniform (selective scaling is FEM-only)");
    if (scene.puncture.criterion == PunctureCriterion::kStrain)
      return make_error("%s: puncture.criterion 'strain' needs FEM elements; use force or energy "
                        "with model 'particles'", name.c_str());
  } else {
    Result<ModelDesc> desc = model_desc_from_scene(scene, mesh_, options, &notes_);
    if (!desc.ok()) return desc.error();
    desc->fixed_vertices = fixed;
    Result<Model> model = build_model(mesh_, *desc);
    if (!model.ok()) return make_error("%s: %s", name.c_str(), model.error().message.c_str());
    model_ = std::move(*model);
  }
  stage_done("model");
  const int setup_threads = setup_thread_count(options.threads);
  if (!particles_ && scene.integrator.target_dt &&
      scene.integrator.mass_scaling_mode == MassScalingMode::kSelective) {
    double target = *scene.integrator.target_dt;
    // The step lowered until the cell's swing on its holder is no slower than the needle's
    // quasi_static_travel (the swing's period grows with the added mass, which grows as dt^2).
    const double travel = scene.integrator.quasi_static_travel;
    if (travel > 0 && has_needle_ && script_.speed > 0 && holding_ &&
        holding_->mode == HoldingMode::kSuction) {
      // Timed at the faster of the needle and quasi_static_speed: a slower needle keeps the
      // step (the same discretisation, loaded more slowly), a faster one lowers it.
      const double speed = std::max(script_.speed, scene.integrator.quasi_static_speed);
      const double loading = travel / speed;  // [s]
      const double safety = scene.integrator.dt_safety;
      const double bore = holding_->geometry.inner_radius;
      std::vector<double> need;
      auto period = [&](double dt) {
        const double w = holder_swing_omega(
            model_.materials, bore, selective_scaling_total_mass(model_, dt, safety, &need,
                                                                setup_threads));
        return w > 0 ? 2.0 * std::numbers::pi / w : 0.0;
      };
      const double at_target = period(target);
      if (at_target > loading) {
        double lo = target * 1e-3, hi = target;  // period(lo) <= loading < period(hi)
        if (period(lo) > loading)
          return make_error("%s: integrator.quasi_static_travel: even at a %.3g us step the "
                            "cell's swing on its holder (%.3g ms) outlasts the %.3g ms of "
                            "%.3g um at %.3g mm/s; lengthen the travel",
                            name.c_str(), lo * 1e6, period(lo) * 1e3, loading * 1e3,
                            travel * 1e6, speed * 1e3);
        for (int i = 0; i < 60 && hi - lo > 1e-4 * hi; ++i) {
          const double mid = 0.5 * (lo + hi);
          (period(mid) > loading ? hi : lo) = mid;
        }
        char line[240];
        std::snprintf(line, sizeof line,
                      "target step %.3g us (from %.3g us): the cell's swing on its holder "
                      "(%.3g ms at %.3g us) within the %.3g ms of quasi_static_travel "
                      "%.3g um at %.3g mm/s",
                      lo * 1e6, target * 1e6, at_target * 1e3, target * 1e6, loading * 1e3,
                      travel * 1e6, speed * 1e3);
        notes_.push_back(line);
        target = lo;
      }
    }
    Result<SelectiveScalingReport> r =
        apply_selective_mass_scaling(model_, target, scene.integrator.dt_safety, setup_threads);
    if (!r.ok()) return make_error("%s: %s", name.c_str(), r.error().message.c_str());
    char line[200];
    std::snprintf(line, sizeof line,
                  "selective mass scaling: total mass x %.4g, largest vertex factor %.4g, %.1f %% of "
                  "vertices raised",
                  r->mass_after / r->mass_before, r->max_vertex_factor, 100.0 * r->scaled_fraction);
    notes_.push_back(line);
  }
  stage_done("mass scaling");
  state_ = make_state(model_, particles_ ? 1 : options.threads);  // particle_step is serial
  stage_done("state");

  // Tools on the surface.
  const size_t capacity = model_.vertex_count();
  if (has_needle_) {
    ContactTool tool;
    tool.kind = ContactTool::Kind::kNeedle;
    tool.needle = {scene.needle.shape, scene.needle.tip_radius, d};
    tool.friction = scene.needle.friction;
    needle_contacts_ = std::make_unique<ContactSet>(tool, surface_, model_.vertex_count(), capacity);
  }
  if (holding_ && holding_->mode == HoldingMode::kSuction) {
    ContactTool tool;
    tool.kind = ContactTool::Kind::kHolding;
    tool.holding = holding_->geometry;
    tool.friction = holding_->friction;
    rim_contacts_ = std::make_unique<ContactSet>(tool, surface_, model_.vertex_count(), capacity);
  }
  puncture_ = std::make_unique<Puncture>(scene.puncture, d, capacity);
  if (scene.puncture.criterion == PunctureCriterion::kStrain) {
    tet_in_zona_.assign(mesh_.tet_count(), 0);
    bool any = false;
    for (size_t t = 0; t < mesh_.tet_count(); ++t)
      if (!mesh_.tet_region.empty() && mesh_.region_name(mesh_.tet_region[t]) == "zona")
        tet_in_zona_[t] = 1, any = true;
    if (!any) {
      tet_in_zona_.clear();
      notes_.push_back("puncture: strain criterion over every element at the tip (no 'zona' region)");
    }
  }

  // When the run ends.
  if (scene.integrator.duration > 0) {
    end_time_ = scene.integrator.duration;
  } else if (has_needle_) {
    end_time_ = needle_script_end_time(script_);
  } else {
    for (size_t i = 0; i < indent_vertices_.size(); ++i)
      end_time_ = std::max(end_time_, indent_depth_[i] / indent_speed_[i]);
  }
  if (!(end_time_ > 0))
    return make_error("%s: nothing ends the run: set integrator.duration or needle.max_travel", name.c_str());

  // Scratch.
  const size_t nv = model_.vertex_count();
  taken_.assign(nv, 0);
  for (int32_t v : model_.fixed_vertices) taken_[static_cast<size_t>(v)] = 1;
  for (int32_t v : indent_vertices_) taken_[static_cast<size_t>(v)] = 1;
  prescribed_.reserve(nv);
  targets_.assign(nv, Vec3d{0, 0, 0});
  loaded_.reserve(nv);
  uploaded_prescribed_.reserve(nv);
  contact_vertices_.reserve(nv);
  zero_u_.assign(nv, Vec3d{0, 0, 0});
  indent_before_.assign(indent_vertices_.size(), Vec3d{0, 0, 0});
  if (options.snapshot_interval > 0) {
    SurfaceSnapshot initial;
    initial.positions.resize(surface_.vertices.size());
    for (size_t i = 0; i < surface_.vertices.size(); ++i)
      initial.positions[i] = model_.rest_positions[static_cast<size_t>(surface_.vertices[i])];
    snapshots_ = std::make_unique<TripleBuffer<SurfaceSnapshot>>(initial);
  }

  // The device-resident job (penalty contact): its setup may raise masses for the contact's
  // stable step, so it comes before the backend takes the model.
  const bool job_path = scene.contact.model == ContactModel::kPenalty && !particles_ &&
                        indent_vertices_.empty() &&
                        (has_needle_ || (holding_ && holding_->mode == HoldingMode::kSuction));
  stage_done("tools");
  // The quasi-static check (engine/sim/quasi_static.h): the imbalance needs the holder's force,
  // which the rim contact and the suction measure; a cell held by fixed vertices has only the
  // kinetic share. The floor: 3 E_max r_tip^2, about the Hertz force of the tip pressed 1.4
  // radii into the stiffest material (docs/outputs.md says why).
  {
    const QuasiStaticDef& qd = scene.quasi_static;
    QuasiStaticLimits& q = quasi_limits_;
    double young_max = 0;
    for (const Material& m : model_.materials) young_max = std::max(young_max, m.young);
    q.enforce = scene.experiment == Experiment::kQuasiStatic && has_needle_ ? 1 : 0;
    q.has_holder = rim_contacts_ != nullptr ? 1 : 0;
    q.max_imbalance = qd.max_imbalance;
    q.max_kinetic_share = qd.max_kinetic_share;
    q.force_floor = qd.force_floor ? *qd.force_floor
                                   : 3.0 * young_max * scene.needle.tip_radius * scene.needle.tip_radius;
    q.energy_floor = model_.energy_floor;
  }
  if (job_path)
    if (Status s = prepare_job(); !s) return s;
  stage_done("job");

  // Backend: the CPU reference in place, or one behind the Backend interface.
  backend_description_ = "cpu reference in place: " + std::to_string(state_.pool->thread_count()) +
                         " thread(s), float64";
  if (particles_) backend_description_ = "particles: cpu reference in place, 1 thread, float64";
  if (particles_ ? bool(options.particle_backend_factory) : bool(options.backend_factory)) {
    std::string notice;
    Result<std::unique_ptr<Backend>> backend = particles_
                                                   ? options.particle_backend_factory(*particles_, &notice)
                                                   : options.backend_factory(&notice);
    if (!backend.ok()) return backend.error();
    if (!notice.empty()) notes_.push_back(notice);
    if (std::string((*backend)->name()) != "cpu" || options.keep_cpu_backend) {
      backend_ = std::move(*backend);
      if (Status s = backend_->upload(model_, state_); !s) return s;
      backend_description_ = backend_->description();
    }
  }

  // Stiffness damping rewrites every load each step (Backend::set_external_forces on the
  // Backend path; with several sub-steps per call its term is held over the call).
  stiffness_damping_ = scene.integrator.stiffness_damping;
  if (stiffness_damping_ > 0) {
    force_prev_.assign(nv, Vec3d{0, 0, 0});
    damping_load_.assign(nv, Vec3d{0, 0, 0});
  }

  stage_done("backend");
  tip_ = tip_next_ = has_needle_ ? script_.start : Vec3d{0, 0, 0};
  report_.tip = tip_;
  if (job_path) {
    if (Status s = start_job(); !s) return s;
    sample_capacity_ = job_setup_.sample_capacity;
  } else {
    // One row per output interval (or step) over the run, sized once: a full buffer is
    // reported, not grown.
    const double row_dt = std::max(std::max(scene.output.sample_interval, 0.0), model_.dt);
    sample_capacity_ = static_cast<size_t>(std::ceil(end_time_ / row_dt * (1 + 1e-9))) + 4;
    kinematic_runner_ = make_kinematic_runner(*this, sample_capacity_);
  }
  stage_done("start");
  notes_.push_back("setup: " + stage_times);
  return Status::ok_status();
}

// ---------------------------------------------------------------------------------------------
// The step.

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
  test_puncture();                       // 2. puncture criterion on the last measurement
  update_contacts();                     // 3. contact sets and prescribed targets
  apply_loads();                         // 4. suction, released tip force, shaft drag
  const StepStatus status = integrate(); // 5. internal forces + integrate (backend)
  if (status & kStepFailed) {
    // A failed health check (non-finite, energy blow-up): the run stops here, and nothing of
    // this state is measured or published (no puncture, frame or haptic sample from it).
    report_.status = status;
    last_status_ = status;
    return status;
  }
  measure();                             // 6. reactions, needle force, deformation
  const StepStatus measured = status | (quasi_blocks_puncture_ ? kStepNotQuasiStatic : kStepOk);
  report_.status = measured;
  last_status_ = measured;
  publish();                             // 7. report, local stiffness, snapshot
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
          const Vec3d x = model_.rest_positions[static_cast<size_t>(v)] + state_.u[static_cast<size_t>(v)];
          needle_contacts_->hold(v, x + penetration * d - tip_, d, state_.u[static_cast<size_t>(v)]);
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
  const bool same_set = uploaded_prescribed_.size() == np &&
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
    report_.constraint_force = puncture_->punctured() ? report_.force_vector
                                                      : needle_contacts_->total_reaction();
    report_.raw_force = dot(report_.force_vector, d);
    // First-order low-pass (exact for a constant input over the step).
    const double tau = scene_.needle.force_filter;
    const double h = time - filter_time_;
    report_.force = tau > 0 && filter_started_
                        ? report_.force + (1.0 - std::exp(-h / tau)) * (report_.raw_force - report_.force)
                        : report_.raw_force;
    filter_started_ = true;
    filter_time_ = time;
    report_.contacts = static_cast<int32_t>(needle_contacts_->size());
    // Ladjal et al.'s contact point: the needle axis against the deformed surface, searched from the
    // last hit triangle; the deformation is its advance over the same ray's rest hit.
    const Vec3d origin = tip_ - 2.0 * cell_diameter_ * d;
    const RayHit now = cast_ray(surface_, model_.rest_positions, u, origin, d, hit_triangle_);
    const RayHit at_rest = cast_ray(surface_, model_.rest_positions, std::span<const Vec3d>(zero_u_),
                                    origin, d, rest_hit_triangle_);
    hit_valid_ = now.triangle >= 0;
    hit_point_ = now.point;
    if (now.triangle >= 0) {
      hit_triangle_ = now.triangle;
      for (int c = 0; c < 3; ++c) seeds_[c] = surface_.triangles[static_cast<size_t>(now.triangle)][c];
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
    for (int32_t v : holding_->patch_vertices) holding -= f[static_cast<size_t>(v)] + ext[static_cast<size_t>(v)];
  }
  report_.holding_force = holding;
  report_.elastic_energy = state_.diag.elastic_energy;
  report_.kinetic_energy = state_.diag.kinetic_energy;
  // The quasi-static check on the measured state, through the needle force's filter (as the
  // job's record stage does).
  if (has_needle_) {
    const double axial = dot(holding, d);
    const double tau = scene_.needle.force_filter;
    filtered_holding_ = tau > 0 && holding_filter_started_
                            ? filtered_holding_ + (1.0 - std::exp(-model_.dt / tau)) * (axial - filtered_holding_)
                            : axial;
    holding_filter_started_ = true;
    quasi_blocks_puncture_ = quasi_static_step(
        quasi_limits_, report_.quasi, !puncture_->punctured(), report_.force, filtered_holding_,
        report_.kinetic_energy, report_.elastic_energy, state_.step_count, time,
        report_.deformation);
  }
  // Particle model: the enclosed volume against its rest value (Asgari et al. eq. 6's constraint).
  if (particles_) {
    volume_change_rel_ = particle_volume(*particles_, state_.u) / particles_->rest_volume - 1.0;
    volume_change_max_rel_ = std::max(volume_change_max_rel_, std::fabs(volume_change_rel_));
  }
}

void Simulation::publish() {
  // Local stiffness for the haptic thread: the slope of force over travel, taken over at least
  // options.stiffness_window of travel (a finite difference of the published samples).
  // From the puncture on the load no longer follows the tip's travel into the cell: the slope is
  // the shaft's drag per metre inserted (job_finish_step does the same).
  if (!stiffness_anchor_set_ || report_.punctured) {
    stiffness_anchor_set_ = true;
    stiffness_force_ = report_.force;
    stiffness_travel_ = report_.travel;
    if (report_.punctured) report_.stiffness = scene_.puncture.shaft_friction;
  } else if (std::fabs(report_.travel - stiffness_travel_) >= options_.stiffness_window) {
    report_.stiffness = (report_.force - stiffness_force_) / (report_.travel - stiffness_travel_);
    stiffness_force_ = report_.force;
    stiffness_travel_ = report_.travel;
  }
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
