// Scene writer: a Scene back to JSON in SI units, readable by parse_scene.
#include <cstdio>
#include <nlohmann/json.hpp>

#include "engine/scene/scene.h"
#include "engine/scene/scene_reader.h"
#include "engine/core/units.h"

namespace zona {
namespace {

using json = nlohmann::json;
using scene_detail::kInf;

// Length unit name for a file unit factor, for scene_to_json.
const char* length_unit_name(double factor) {
  static constexpr struct {
    double factor;
    const char* name;
  } kNames[] = {{1.0, "m"}, {1e-2, "cm"}, {1e-3, "mm"}, {1e-6, "um"}, {1e-9, "nm"}, {1e-12, "pm"},
                {1e3, "km"}};
  for (const auto& n : kNames) {
    if (n.factor == factor) return n.name;
  }
  return nullptr;
}

json quantity_json(double v, Dimension d) { return format_quantity(v, d, 0); }

json vec_json(Vec3d v, Dimension d) {
  return json::array({quantity_json(v.x, d), quantity_json(v.y, d), quantity_json(v.z, d)});
}

json direction_json(Vec3d v) { return json::array({v.x, v.y, v.z}); }

}  // namespace

const char* frame_format_name(FrameFormat format) {
  switch (format) {
    case FrameFormat::kXdmf: return "xdmf";
    case FrameFormat::kVtuAndXdmf: return "vtu+xdmf";
    case FrameFormat::kVtu: break;
  }
  return "vtu";
}

json scene_to_json(const Scene& scene) {
  using namespace dim;
  json j = json::object();
  j["version"] = 1;
  j["name"] = scene.name;
  j["description"] = scene.description;

  json mesh = json::object();
  if (scene.mesh.source == MeshSource::kFile) {
    mesh["file"] = scene.mesh.file;
    const char* unit = length_unit_name(scene.mesh.file_unit);
    mesh["unit"] = unit ? unit : "m";
  } else {
    const MeshGenerateDef& g = scene.mesh.generate;
    json gen = json::object();
    gen["diameter"] = quantity_json(g.diameter, kLength);
    gen["radii_scale"] = direction_json(g.radii_scale);
    gen["zona_thickness"] = quantity_json(g.zona_thickness, kLength);
    gen["nucleus_diameter"] = quantity_json(g.nucleus_diameter, kLength);
    if (g.target_vertices > 0) gen["vertices"] = g.target_vertices;
    if (g.edge_length > 0.0) gen["edge_length"] = quantity_json(g.edge_length, kLength);
    if (g.refine_edge_length > 0.0) {
      gen["refine_edge_length"] = quantity_json(g.refine_edge_length, kLength);
      gen["refine_radius"] = quantity_json(g.refine_radius, kLength);
      gen["refine_at"] = g.refine_at_needle ? json("needle") : vec_json(g.refine_at, kLength);
    }
    mesh["generate"] = gen;
  }
  j["mesh"] = mesh;
  j["model"] = model_name(scene.model);
  j["volumetric"] = scene.nodal_pressure ? "nodal" : "element";
  if (scene.volumetric_stabilisation > 0)
    j["volumetric_stabilisation"] = scene.volumetric_stabilisation;

  json materials = json::object();
  for (const RegionMaterialDef& entry : scene.materials) {
    const MaterialDef& m = entry.material;
    json e = json::object();
    if (m.young_by_speed.empty()) {
      e["young"] = quantity_json(m.young, kPressure);
    } else {
      json table = json::array();
      for (const SpeedModulusPoint& p : m.young_by_speed) {
        table.push_back({{"speed", quantity_json(p.speed, kSpeed)},
                         {"young", quantity_json(p.young, kPressure)}});
      }
      e["young_by_speed"] = table;
    }
    e["poisson"] = m.poisson;
    switch (m.mass_spec) {
      case MassSpec::kDensity: e["density"] = quantity_json(m.density, kDensity); break;
      case MassSpec::kTotalMass: e["mass"] = quantity_json(m.total_mass, kMass); break;
      case MassSpec::kVertexMass: e["vertex_mass"] = quantity_json(m.vertex_mass, kMass); break;
    }
    e["damping"] = quantity_json(m.damping, kFrequency);
    materials[entry.region] = e;
  }
  // A particle scene may have no materials (an empty object would not read back).
  if (scene.model != ModelKind::kParticles || !scene.materials.empty()) j["materials"] = materials;
  if (scene.model == ModelKind::kParticles) {
    // Units without a name in units.cpp are written out by hand (parse_unit reads them back).
    const ParticlesDef& p = scene.particles;
    auto with_unit = [](double v, const char* unit) {
      char text[64];
      std::snprintf(text, sizeof text, "%.17g %s", v, unit);
      return json(text);
    };
    json particles = json::object();
    particles["layout"] = p.layout == ParticleLayout::kIcosphere ? "icosphere" : "latlong";
    particles["particles"] = p.particles;
    particles["pole_axis"] = direction_json(p.pole_axis);
    particles["membrane_modulus"] = quantity_json(p.membrane_modulus, kStiffness);
    particles["membrane_relaxation_time"] = quantity_json(p.membrane_relaxation_time, kTime);
    particles["radial_stiffness"] = with_unit(p.radial_stiffness, "N/m^3");
    particles["radial_damping"] = with_unit(p.radial_damping, "N*s/m^3");
    particles["damping"] = json::array({with_unit(p.damping.x, "N*s/m^3"),
                                        with_unit(p.damping.y, "N*s/m^3"),
                                        with_unit(p.damping.z, "N*s/m^3")});
    particles["compressibility"] = with_unit(p.compressibility, "1/Pa");
    particles["areal_density"] = with_unit(p.areal_density, "kg/m^2");
    particles["centre_mass"] = quantity_json(p.centre_mass, kMass);
    j["particles"] = particles;
  }

  const IntegratorDef& in = scene.integrator;
  json integrator = json::object();
  integrator["dt"] = in.dt ? quantity_json(*in.dt, kTime) : json("auto");
  integrator["dt_safety"] = in.dt_safety;
  integrator["mass_scaling"] = in.mass_scaling;
  if (in.target_dt) integrator["target_dt"] = quantity_json(*in.target_dt, kTime);
  integrator["mass_scaling_mode"] =
      in.mass_scaling_mode == MassScalingMode::kSelective ? "selective" : "uniform";
  integrator["stiffness_damping"] = quantity_json(in.stiffness_damping, kTime);
  integrator["drift_damping"] =
      in.drift_damping ? quantity_json(*in.drift_damping, kFrequency) : json("auto");
  integrator["drift_window"] = in.drift_window ? quantity_json(*in.drift_window, kTime) : json("auto");
  integrator["quasi_static_travel"] = quantity_json(in.quasi_static_travel, kLength);
  integrator["quasi_static_speed"] = quantity_json(in.quasi_static_speed, kSpeed);
  integrator["dynamic_mass_safety"] = in.dynamic_mass_safety;
  integrator["duration"] = quantity_json(in.duration, kTime);
  j["integrator"] = integrator;

  const SolverDef& sv = scene.solver;
  json solver = json::object();
  solver["method"] = sv.method == SolverMethod::kStatic ? "static" : "explicit";
  solver["travel_step"] = quantity_json(sv.travel_step, kLength);
  solver["min_travel_step"] = quantity_json(sv.min_travel_step, kLength);
  solver["tolerance"] = sv.tolerance;
  solver["max_iterations"] = sv.max_iterations;
  solver["linear"] = sv.linear == LinearSolverKind::kDirect ? "direct" : "cg";
  solver["preconditioner"] = preconditioner_name(sv.preconditioner);
  solver["barrier_volume"] = sv.barrier_volume;
  solver["medium_viscosity"] = quantity_json(sv.medium_viscosity, kPressure * kTime);
  solver["puncture_tolerance"] = quantity_json(sv.puncture_tolerance, kLength);
  solver["suction_steps"] = sv.suction_steps;
  solver["oracle"] = sv.oracle;
  j["solver"] = solver;

  json boundary = json::array();
  for (const BoundaryDef& b : scene.boundary) {
    json e = json::object();
    if (b.type == BoundaryKind::kFixed) {
      e["type"] = "fixed";
      json w = json::object();
      const VertexSelect& s = b.where;
      if (s.surface_only) w["surface"] = true;
      if (!s.region.empty()) w["region"] = s.region;
      const bool below = s.below != kInf;
      const bool above = s.above != -kInf;
      if (below || above) w["normal"] = direction_json(s.normal);
      if (below) w["below"] = quantity_json(s.below, kLength);
      if (above) w["above"] = quantity_json(s.above, kLength);
      if (s.center) {
        w["center"] = vec_json(*s.center, kLength);
        w["radius"] = quantity_json(s.radius, kLength);
      }
      e["where"] = w;
    } else {
      e["type"] = "indent";
      e["center"] = vec_json(b.center, kLength);
      e["radius"] = quantity_json(b.radius, kLength);
      e["depth"] = quantity_json(b.depth, kLength);
      e["speed"] = quantity_json(b.speed, kSpeed);
      e["direction"] = direction_json(b.direction);
    }
    boundary.push_back(e);
  }
  j["boundary"] = boundary;

  const NeedleDef& n = scene.needle;
  json needle = json::object();
  needle["enabled"] = n.enabled;
  if (n.enabled) {
    static constexpr const char* kShapes[] = {"point", "sphere", "flat"};
    needle["shape"] = kShapes[static_cast<int>(n.shape)];
    needle["tip_radius"] = quantity_json(n.tip_radius, kLength);
    needle["direction"] = direction_json(n.direction);
    needle["start"] = n.start ? vec_json(*n.start, kLength) : json("auto");
    needle["standoff"] = quantity_json(n.standoff, kLength);
    needle["speed"] = quantity_json(n.speed, kSpeed);
    needle["max_travel"] = quantity_json(n.max_travel, kLength);
    needle["friction"] = n.friction;
    needle["stick_length"] = quantity_json(n.stick_length, kLength);
    needle["force_filter"] = quantity_json(n.force_filter, kTime);
    if (!n.trajectory.empty()) needle["trajectory"] = n.trajectory;
  }
  j["needle"] = needle;

  const PunctureDef& p = scene.puncture;
  static constexpr const char* kCriteria[] = {"none", "force", "strain", "energy"};
  json puncture = json::object();
  puncture["criterion"] = kCriteria[static_cast<int>(p.criterion)];
  if (p.criterion == PunctureCriterion::kForce) puncture["threshold"] = quantity_json(p.threshold, kForce);
  if (p.criterion == PunctureCriterion::kStrain) puncture["threshold"] = p.threshold;
  if (p.criterion == PunctureCriterion::kEnergy) puncture["threshold"] = quantity_json(p.threshold, kEnergy);
  puncture["force_drop"] = p.force_drop;
  puncture["drop_time"] = quantity_json(p.drop_time, kTime);
  puncture["shaft_friction"] = quantity_json(p.shaft_friction, kStiffness);
  j["puncture"] = puncture;

  json contact = json::object();
  contact["model"] = "penalty";
  contact["stiffness"] = scene.contact.stiffness;
  contact["needle_quadrature"] = scene.contact.needle_on_faces ? "faces" : "vertices";
  contact["rim_damping"] = scene.contact.rim_damping;
  j["contact"] = contact;

  const HoldingPipetteDef& h = scene.holding_pipette;
  json holding = json::object();
  holding["enabled"] = h.enabled;
  if (h.enabled) {
    holding["mode"] = h.mode == HoldingMode::kSuction ? "suction" : "fixed";
    holding["inner_radius"] = quantity_json(h.inner_radius, kLength);
    holding["outer_radius"] = quantity_json(h.outer_radius, kLength);
    holding["edge_radius"] = quantity_json(h.edge_radius, kLength);
    holding["suction"] = quantity_json(h.suction, kPressure);
    holding["friction"] = h.friction;
    holding["stick_length"] = quantity_json(h.stick_length, kLength);
    if (h.side) holding["side"] = direction_json(*h.side);
    holding["position"] = h.position ? vec_json(*h.position, kLength) : json("auto");
  }
  j["holding_pipette"] = holding;

  const HapticsDef& hp = scene.haptics;
  static constexpr const char* kDevices[] = {"none", "scripted", "emulated", "replay", "network"};
  json haptics = json::object();
  haptics["device"] = kDevices[static_cast<int>(hp.device)];
  haptics["rate"] = quantity_json(hp.rate, kFrequency);
  haptics["workspace_scale"] = hp.workspace_scale;
  haptics["force_scale"] = hp.force_scale;
  haptics["max_force"] = quantity_json(hp.max_force, kForce);
  haptics["max_stiffness"] = quantity_json(hp.max_stiffness, kStiffness);
  haptics["interpolation"] =
      hp.interpolation == HapticInterpolation::kStiffness ? "stiffness" : "first_order_hold";
  haptics["stall_timeout"] = quantity_json(hp.stall_timeout, kTime);
  haptics["coupling_stiffness"] =
      hp.coupling_stiffness ? quantity_json(*hp.coupling_stiffness, kStiffness) : json("auto");
  haptics["max_tip_speed"] =
      hp.max_tip_speed ? quantity_json(*hp.max_tip_speed, kSpeed) : json("auto");
  haptics["coupling_damping"] =
      hp.coupling_damping ? quantity_json(*hp.coupling_damping, kDamping) : json("auto");
  if (!hp.replay_file.empty()) haptics["replay_file"] = hp.replay_file;
  haptics["network_host"] = hp.network_host;
  haptics["network_port"] = hp.network_port;
  j["haptics"] = haptics;

  const OutputDef& o = scene.output;
  json output = json::object();
  if (o.frame_interval) {
    output["frame_interval"] = quantity_json(*o.frame_interval, kTime);
  } else {
    output["frames"] = o.frames;
  }
  output["sample_interval"] = quantity_json(o.sample_interval, kTime);
  output["format"] = frame_format_name(o.format);
  j["output"] = output;
  j["experiment"] = scene.experiment == Experiment::kDynamic ? "dynamic" : "quasi_static";
  const QuasiStaticDef& q = scene.quasi_static;
  j["quasi_static"] = {
      {"max_imbalance", q.max_imbalance},
      {"max_kinetic_share", q.max_kinetic_share},
      {"force_floor", q.force_floor ? quantity_json(*q.force_floor, kForce) : json("auto")}};
  return j;
}

double end_run_with_needle(Scene& scene) {
  const NeedleDef& needle = scene.needle;
  const double needle_end = needle.enabled && needle.trajectory.empty() && needle.max_travel > 0 &&
                                    needle.speed > 0
                                ? needle.max_travel / needle.speed
                                : 0.0;
  const double duration = scene.integrator.duration;
  if (!(needle_end > 0) || !(duration > 2 * needle_end) || !(duration > needle_end + 1.0)) return 0;
  scene.integrator.duration = 0;  // 0: the run ends when the needle's script does
  return needle_end;
}

}  // namespace zona
