// The injection experiment's setup: a Scene turned into a running simulation by a list of named
// setup stages (Simulation::build: body, surface, needle, holding, model, mass scaling, state,
// tools, end, scratch, quasi-static, job, backend, damping, start). The step is
// simulation_step.cpp, the penalty step's setup simulation_job.cpp, the run driver run.cpp.
#include "engine/sim/simulation.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <limits>
#include <numbers>
#include <set>
#include <utility>

#include "engine/core/parallel.h"
#include "engine/fem/mass_scaling.h"
#include "engine/scene/scene_mesh.h"
#include "engine/sim/boundary_runner.h"
#include "engine/solver/linear_solver.h"

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
  desc.nodal_stabilisation = scene.volumetric_stabilisation;
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
  if (options.backend_substeps < 1)
    return make_error("simulation: backend_substeps must be >= 1, got %d", options.backend_substeps);

  // The setup stages, in order; each is timed, and the times are reported as one note
  // ("setup: mesh 3.1 s, ..."): a fine mesh's setup is a third of its run to the puncture.
  using Stage = Status (Simulation::*)(SetupContext&);
  // clang-format off
  static constexpr std::pair<const char*, Stage> kStages[] = {
      {"mesh",         &Simulation::setup_body},          // mesh (scene or particle body)
      {"surface",      &Simulation::setup_surface},       // boundary surface
      {"needle",       &Simulation::setup_needle},        // needle axis, entry point, script
      {"holding",      &Simulation::setup_holding},       // holding pipette, fixed, indented
      {"model",        &Simulation::setup_model},         // the immutable model
      {"mass scaling", &Simulation::setup_mass_scaling},  // selective mass scaling
      {"state",        &Simulation::setup_state},         // the mutable state
      {"end",          &Simulation::setup_end_time},      // when the run ends
      {"scratch",      &Simulation::setup_scratch},       // the host step's scratch
      {"quasi-static", &Simulation::setup_quasi_static},  // the quasi-static check's limits
      {"job",          &Simulation::setup_job},           // the penalty step's parameters
      {"backend",      &Simulation::setup_backend},       // CPU in place or a Backend
      {"damping",      &Simulation::setup_damping},       // stiffness damping history
      {"start",        &Simulation::setup_runner},        // the runner the run driver steps
  };
  // clang-format on
  SetupContext setup;
  setup.direction = scene.needle.direction / norm(scene.needle.direction);
  std::string times;
  for (const auto& [stage, run] : kStages) {
    const auto start = std::chrono::steady_clock::now();
    if (Status s = (this->*run)(setup); !s) return s;
    char item[64];
    std::snprintf(item, sizeof item, "%s%s %.2f s", times.empty() ? "" : ", ", stage,
                  std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count());
    times += item;
  }
  notes_.push_back("setup: " + times);
  if (scene.solver.method == SolverMethod::kStatic &&
      (scene.solver.linear == LinearSolverKind::kDirect || scene.solver.oracle))
    if (std::string note = direct_solver_note(); !note.empty()) notes_.push_back(std::move(note));
  return Status::ok_status();
}

// The body's mesh: the scene's (generated or read), or the particle model's body mesh.
Status Simulation::setup_body(SetupContext&) {
  // The particle model (Asgari et al.) builds its own body mesh: the membrane
  // triangulation plus fan tetrahedra to the centre particle (engine/particles/particle_model.h).
  if (scene_.model == ModelKind::kParticles) {
    Result<ParticleModelDesc> pd = particle_desc_from_scene(scene_);
    if (!pd.ok()) return pd.error();
    Result<ParticleModel> pm = build_particle_model(*pd);
    if (!pm.ok()) return make_error("%s: %s", scene_.name.c_str(), pm.error().message.c_str());
    particles_ = std::make_unique<ParticleModel>(std::move(*pm));
    mesh_ = particle_body_mesh(*particles_);
  } else {
    Result<Mesh> mesh = build_scene_mesh(scene_, &notes_);
    if (!mesh.ok()) return mesh.error();
    mesh_ = std::move(*mesh);
  }
  return Status::ok_status();
}

// The boundary surface the tools touch, ray casts hit and frames draw.
Status Simulation::setup_surface(SetupContext&) {
  Result<ContactSurface> surface = build_contact_surface(mesh_);
  if (!surface.ok())
    return make_error("%s: %s", scene_.name.c_str(), surface.error().message.c_str());
  surface_ = std::move(*surface);
  return Status::ok_status();
}

// The needle's axis, entry point and script: rays along the axis on the rest surface.
Status Simulation::setup_needle(SetupContext& setup) {
  // A generated cell is centred at the origin; a file mesh at its centroid.
  centre_ = scene_.mesh.source == MeshSource::kGenerate ? Vec3d{0, 0, 0} : mesh_centroid(mesh_);
  const double diagonal = bounding_diagonal(mesh_);
  const std::vector<Vec3d> zero(mesh_.vertex_count(), Vec3d{0, 0, 0});

  // Needle axis, entry point and automatic start: rays along the axis on the rest surface.
  has_needle_ = scene_.needle.enabled;
  const Vec3d d = setup.direction;
  if (has_needle_) {
    script_.direction = d;
    script_.speed = scene_.needle.speed;
    script_.max_travel = scene_.needle.max_travel;
    if (!scene_.needle.trajectory.empty()) {
      Result<NeedleTrajectory> tr = read_needle_trajectory(scene_.needle.trajectory);
      if (!tr.ok()) return tr.error();
      script_.trajectory = std::move(*tr);
    }
    const Vec3d through = scene_.needle.start ? *scene_.needle.start : centre_;
    const RayHit in = cast_ray(surface_, mesh_.rest_positions, zero, through - 2 * diagonal * d, d, -1);
    const RayHit out =
        cast_ray(surface_, mesh_.rest_positions, zero, through + 2 * diagonal * d, -1.0 * d, -1);
    if (in.triangle < 0 || out.triangle < 0) {
      if (!scene_.needle.start)
        return make_error("%s: needle: the axis through the cell centre misses the surface",
                          scene_.name.c_str());
      notes_.push_back("needle: the axis misses the cell; deformation is reported as 0");
      entry_point_ = *scene_.needle.start;
    } else {
      entry_point_ = in.point;
      cell_diameter_ = dot(out.point - in.point, d);
      rest_hit_triangle_ = in.triangle;
    }
    script_.start =
        scene_.needle.start ? *scene_.needle.start : entry_point_ - scene_.needle.standoff * d;
    if (!script_.trajectory.time.empty()) script_.start = script_.trajectory.position.front();
  } else {
    const Aabb box = mesh_bounds(mesh_);
    cell_diameter_ = box.hi.x - box.lo.x;
  }
  if (!(cell_diameter_ > 0)) cell_diameter_ = scene_.mesh.generate.diameter;
  return Status::ok_status();
}

// The holding pipette and the boundary conditions: fixed vertices, indentation patches.
Status Simulation::setup_holding(SetupContext& setup) {
  // Holding pipette and boundary conditions -> fixed vertices.
  std::vector<int32_t>& fixed = setup.fixed;
  if (scene_.holding_pipette.enabled) {
    Result<HoldingSetup> h = make_holding(scene_.holding_pipette, surface_, mesh_.rest_positions,
                                          centre_, setup.direction);
    if (!h.ok()) return make_error("%s: %s", scene_.name.c_str(), h.error().message.c_str());
    holding_ = std::move(*h);
    if (holding_->mode == HoldingMode::kFixed)
      fixed.insert(fixed.end(), holding_->patch_vertices.begin(), holding_->patch_vertices.end());
  }
  for (size_t i = 0; i < scene_.boundary.size(); ++i) {
    const BoundaryDef& b = scene_.boundary[i];
    if (b.type == BoundaryKind::kFixed) {
      const std::vector<int32_t> sel = select_vertices(mesh_, surface_, b.where);
      if (sel.empty())
        return make_error("%s: boundary[%zu]: selects no vertex", scene_.name.c_str(), i);
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
      if (n == 0)
        return make_error("%s: boundary[%zu]: the indent patch holds no surface vertex",
                          scene_.name.c_str(), i);
    }
  }
  std::sort(fixed.begin(), fixed.end());
  fixed.erase(std::unique(fixed.begin(), fixed.end()), fixed.end());
  {
    std::vector<int32_t> sorted_indent = indent_vertices_;
    std::sort(sorted_indent.begin(), sorted_indent.end());
    if (std::adjacent_find(sorted_indent.begin(), sorted_indent.end()) != sorted_indent.end())
      return make_error("%s: boundary: indent patches overlap", scene_.name.c_str());
    for (int32_t v : sorted_indent)
      if (std::binary_search(fixed.begin(), fixed.end(), v))
        return make_error("%s: boundary: vertex %d is both fixed and indented", scene_.name.c_str(),
                          v);
  }
  // The indentation is the run's tool: a prescribed patch, stepped on the host. The needle and
  // the suction rim are the job's terms, which has no prescribed vertices.
  if (!indent_vertices_.empty() &&
      (has_needle_ || (holding_ && holding_->mode == HoldingMode::kSuction)))
    return make_error("%s: boundary: an indent patch is the run's only tool (set needle.enabled "
                      "false and a fixed holding pipette, or use the needle)",
                      scene_.name.c_str());
  return Status::ok_status();
}

// The immutable model: materials, masses, element data, the stable step.
Status Simulation::setup_model(SetupContext& setup) {
  if (particles_) {
    Result<Model> model = particle_body_model(*particles_, mesh_, setup.fixed);
    if (!model.ok())
      return make_error("%s: %s", scene_.name.c_str(), model.error().message.c_str());
    model_ = std::move(*model);
    if (scene_.integrator.mass_scaling_mode == MassScalingMode::kSelective)
      notes_.push_back("particles: mass scaling is uniform (selective scaling is FEM-only)");
    if (scene_.puncture.criterion == PunctureCriterion::kStrain)
      return make_error(
          "%s: puncture.criterion 'strain' needs FEM elements; use force or energy "
          "with model 'particles'",
          scene_.name.c_str());
  } else {
    Result<ModelDesc> desc = model_desc_from_scene(scene_, mesh_, options_, &notes_);
    if (!desc.ok()) return desc.error();
    desc->fixed_vertices = setup.fixed;
    Result<Model> model = build_model(mesh_, *desc);
    if (!model.ok())
      return make_error("%s: %s", scene_.name.c_str(), model.error().message.c_str());
    model_ = std::move(*model);
  }
  return Status::ok_status();
}

// Selective mass scaling to the scene's target step (FEM only).
Status Simulation::setup_mass_scaling(SetupContext&) {
  const int setup_threads = setup_thread_count(options_.threads);
  if (particles_ || !scene_.integrator.target_dt ||
      scene_.integrator.mass_scaling_mode != MassScalingMode::kSelective)
    return Status::ok_status();
  double target = *scene_.integrator.target_dt;
  // The step lowered until the cell's swing on its holder is no slower than the needle's
  // quasi_static_travel (the swing's period grows with the added mass, which grows as dt^2).
  const double travel = scene_.integrator.quasi_static_travel;
  if (travel > 0 && has_needle_ && script_.speed > 0 && holding_ &&
      holding_->mode == HoldingMode::kSuction) {
    // Timed at the faster of the needle and quasi_static_speed: a slower needle keeps the
    // step (the same discretisation, loaded more slowly), a faster one lowers it.
    const double speed = std::max(script_.speed, scene_.integrator.quasi_static_speed);
    const double loading = travel / speed;  // [s]
    const double safety = scene_.integrator.dt_safety;
    const double bore = holding_->geometry.inner_radius;
    std::vector<double> need;
    auto period = [&](double dt) {
      const double w = holder_swing_omega(
          model_.materials, bore,
          selective_scaling_total_mass(model_, dt, safety, &need, setup_threads));
      return w > 0 ? 2.0 * std::numbers::pi / w : 0.0;
    };
    const double at_target = period(target);
    if (at_target > loading) {
      double lo = target * 1e-3, hi = target;  // period(lo) <= loading < period(hi)
      if (period(lo) > loading)
        return make_error(
            "%s: integrator.quasi_static_travel: even at a %.3g us step the "
            "cell's swing on its holder (%.3g ms) outlasts the %.3g ms of "
            "%.3g um at %.3g mm/s; lengthen the travel",
            scene_.name.c_str(), lo * 1e6, period(lo) * 1e3, loading * 1e3, travel * 1e6,
            speed * 1e3);
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
      note_explicit(line);
      target = lo;
    }
  }
  Result<SelectiveScalingReport> r =
      apply_selective_mass_scaling(model_, target, scene_.integrator.dt_safety, setup_threads);
  if (!r.ok()) return make_error("%s: %s", scene_.name.c_str(), r.error().message.c_str());
  char line[200];
  std::snprintf(line, sizeof line,
                "selective mass scaling: total mass x %.4g, largest vertex factor %.4g, %.1f %% of "
                "vertices raised",
                r->mass_after / r->mass_before, r->max_vertex_factor, 100.0 * r->scaled_fraction);
  note_explicit(line);
  return Status::ok_status();
}

// The mutable state and its thread pool.
Status Simulation::setup_state(SetupContext&) {
  state_ = make_state(model_, particles_ ? 1 : options_.threads);  // particle_step is serial
  return Status::ok_status();
}

// When the run ends: the scene's duration, the needle's script or the indentation.
Status Simulation::setup_end_time(SetupContext&) {
  if (scene_.integrator.duration > 0) {
    end_time_ = scene_.integrator.duration;
  } else if (has_needle_) {
    end_time_ = needle_script_end_time(script_);
  } else {
    for (size_t i = 0; i < indent_vertices_.size(); ++i)
      end_time_ = std::max(end_time_, indent_depth_[i] / indent_speed_[i]);
  }
  if (!(end_time_ > 0))
    return make_error("%s: nothing ends the run: set integrator.duration or needle.max_travel",
                      scene_.name.c_str());
  return Status::ok_status();
}

// The prescribed boundary's host step: the patch and its targets, sized once.
Status Simulation::setup_scratch(SetupContext&) {
  if (indent_vertices_.empty()) return Status::ok_status();
  targets_.assign(indent_vertices_.size(), Vec3d{0, 0, 0});
  indent_before_.assign(indent_vertices_.size(), Vec3d{0, 0, 0});
  return set_prescribed_vertices(model_, state_, indent_vertices_);
}

// The quasi-static check's limits, the same on both step paths.
Status Simulation::setup_quasi_static(SetupContext&) {
  // The quasi-static check (engine/sim/quasi_static.h): the imbalance needs the holder's force,
  // which the rim contact and the suction measure; a cell held by fixed vertices has only the
  // kinetic share. The floor: 3 E_max r_tip^2, about the Hertz force of the tip pressed 1.4
  // radii into the stiffest material (docs/outputs.md says why).
  const QuasiStaticDef& qd = scene_.quasi_static;
  QuasiStaticLimits& q = quasi_limits_;
  double young_max = 0;
  for (const Material& m : model_.materials) young_max = std::max(young_max, m.young);
  q.enforce = scene_.experiment == Experiment::kQuasiStatic && has_needle_ ? 1 : 0;
  q.has_holder = holding_ && holding_->mode == HoldingMode::kSuction ? 1 : 0;
  q.max_imbalance = qd.max_imbalance;
  q.max_kinetic_share = qd.max_kinetic_share;
  q.force_floor = qd.force_floor
                      ? *qd.force_floor
                      : 3.0 * young_max * scene_.needle.tip_radius * scene_.needle.tip_radius;
  q.energy_floor = model_.energy_floor;
  return Status::ok_status();
}

// The device-resident job (penalty contact): its setup may raise masses for the contact's
// stable step, so it comes before the backend takes the model (simulation_job.cpp).
Status Simulation::setup_job(SetupContext& setup) {
  setup.job_path = indent_vertices_.empty();
  return setup.job_path ? prepare_job() : Status::ok_status();
}

// The backend: the CPU reference in place, or one behind the Backend interface.
Status Simulation::setup_backend(SetupContext&) {
  backend_description_ = "cpu reference in place: " + std::to_string(state_.pool->thread_count()) +
                         " thread(s), float64";
  if (particles_) backend_description_ = "particles: cpu reference in place, 1 thread, float64";
  if (particles_ ? bool(options_.particle_backend_factory) : bool(options_.backend_factory)) {
    std::string notice;
    Result<std::unique_ptr<Backend>> backend =
        particles_ ? options_.particle_backend_factory(*particles_, &notice)
                   : options_.backend_factory(&notice);
    if (!backend.ok()) return backend.error();
    if (!notice.empty()) notes_.push_back(notice);
    if (std::string((*backend)->name()) != "cpu" || options_.keep_cpu_backend) {
      backend_ = std::move(*backend);
      if (Status s = backend_->upload(model_, state_); !s) return s;
      backend_description_ = backend_->description();
    }
  }
  return Status::ok_status();
}

// Stiffness damping's history (the host step; the job keeps its own).
Status Simulation::setup_damping(SetupContext&) {
  // Stiffness damping rewrites every load each step (Backend::set_external_forces on the
  // Backend path; with several sub-steps per call its term is held over the call).
  stiffness_damping_ = scene_.integrator.stiffness_damping;
  if (stiffness_damping_ > 0) {
    force_prev_.assign(model_.vertex_count(), Vec3d{0, 0, 0});
    damping_load_.assign(model_.vertex_count(), Vec3d{0, 0, 0});
  }
  return Status::ok_status();
}

// The runner the run driver steps: the job's (CPU or the backend's) or the host step's.
Status Simulation::setup_runner(SetupContext& setup) {
  report_.tip = has_needle_ ? script_.start : Vec3d{0, 0, 0};
  if (setup.job_path) {
    if (Status s = start_job(); !s) return s;
    sample_capacity_ = job_setup_.sample_capacity;
  } else {
    // One row per output interval (or step) over the run, sized once: a full buffer is
    // reported, not grown.
    const double row_dt = std::max(std::max(scene_.output.sample_interval, 0.0), model_.dt);
    sample_capacity_ = static_cast<size_t>(std::ceil(end_time_ / row_dt * (1 + 1e-9))) + 4;
    boundary_runner_ = make_boundary_runner(*this, sample_capacity_);
    // The local stiffness is the job's record-stage function (job_local_stiffness), which reads
    // the stiffness window alone; the patch's reaction is not filtered.
    record_params_.record.stiffness_window = options_.stiffness_window;
  }
  return Status::ok_status();
}

void Simulation::note_explicit(std::string line) {
  if (scene_.solver.method != SolverMethod::kStatic) notes_.push_back(std::move(line));
}

}  // namespace zona
