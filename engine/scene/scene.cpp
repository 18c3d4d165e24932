// Scene loader: JSON with units in the values -> validated Scene in SI, with --set overrides.
// (Over 800 lines: one reader function per scene section, each with its keys, units and ranges;
// scenes.md lists them in the same order.)
#include "engine/scene/scene.h"

#include <algorithm>
#include <cerrno>
#include <charconv>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <initializer_list>
#include <nlohmann/json.hpp>
#include <set>
#include <sstream>
#include <string_view>

#include "engine/mesh/xdmf_writer.h"
#include "engine/scene/scene_reader.h"
#include "engine/core/units.h"

namespace zona {
namespace {

using json = nlohmann::json;
namespace fs = std::filesystem;
using namespace scene_detail;

// ---------------------------------------------------------------------------------------------
// Sections.

constexpr std::initializer_list<Choice<ModelKind>> kModels = {
    {"svk", ModelKind::kSvk},
    {"linear", ModelKind::kLinear},
    {"neohookean", ModelKind::kStableNeoHookean},
    {"particles", ModelKind::kParticles}};

void read_mesh(Reader& root, Scene& scene) {
  if (!root.require("mesh")) return;
  Reader mesh = root.object("mesh", {"file", "unit", "generate"});
  if (!mesh.present()) return;
  const bool file = mesh.has("file");
  const bool generate = mesh.has("generate");
  if (file == generate) {
    mesh.fail("", "give exactly one of \"file\" or \"generate\"");
    return;
  }
  MeshDef& m = scene.mesh;
  if (file) {
    m.source = MeshSource::kFile;
    mesh.file_path("file", &m.file);
    if (!mesh.require("unit")) return;
    std::string unit;
    if (mesh.string("unit", &unit)) {
      Result<double> factor = parse_unit(unit, dim::kLength);
      if (!factor) {
        mesh.fail("unit", factor.error().message);
        return;
      }
      m.file_unit = *factor;
    }
    return;
  }
  if (mesh.has("unit")) {
    mesh.fail("unit", "only used with \"file\" (generator lengths carry their own units)");
    return;
  }
  m.source = MeshSource::kGenerate;
  Reader g = mesh.object("generate", {"diameter", "radii_scale", "zona_thickness",
                                      "nucleus_diameter", "vertices", "edge_length",
                                      "refine_edge_length", "refine_radius", "refine_at"});
  if (!g.present()) return;
  MeshGenerateDef& gen = m.generate;
  if (!g.require("diameter")) return;
  g.quantity("diameter", dim::kLength, &gen.diameter, Range::positive());
  if (g.vec3("radii_scale", dim::kNone, &gen.radii_scale)) {
    for (int a = 0; a < 3; ++a) {
      if (!(gen.radii_scale[a] > 0.0)) {
        g.fail("radii_scale", "each factor must be > 0");
        return;
      }
    }
  }
  // Layers are measured on the smallest semi-axis, where the cell is thinnest.
  const double min_scale =
      std::min({gen.radii_scale.x, gen.radii_scale.y, gen.radii_scale.z});
  const double min_diameter = gen.diameter * min_scale;
  g.quantity("zona_thickness", dim::kLength, &gen.zona_thickness,
             Range::closed_open(0.0, min_diameter / 2));
  const double inner = min_diameter - 2 * gen.zona_thickness;
  g.quantity("nucleus_diameter", dim::kLength, &gen.nucleus_diameter,
             Range{0.0, inner, false, true, "smaller than the cell inside the zona"});
  // Size: vertices alone (uniform), edge_length alone, or a graded mesh (edge lengths with
  // refinement), optionally scaled as a whole to a vertex count.
  const bool graded = g.has("refine_edge_length");
  if (g.has("vertices") && g.has("edge_length") && !graded) {
    g.fail("vertices", "give either \"vertices\" or \"edge_length\" for a uniform mesh, not "
                       "both (both only with refine_edge_length)");
    return;
  }
  gen.target_vertices = 0;
  gen.edge_length = 0.0;
  g.integer("vertices", &gen.target_vertices, 8, 2'000'000'000);
  if (!g.quantity("edge_length", dim::kLength, &gen.edge_length,
                  Range::open_closed(0.0, gen.diameter)) &&
      (gen.target_vertices == 0 || graded)) {
    // Not given: a coarse default, documented in docs/scenes.md.
    gen.edge_length = gen.diameter / 10;
  }
  const double coarse = gen.edge_length > 0.0 ? gen.edge_length : gen.diameter;
  g.quantity("refine_edge_length", dim::kLength, &gen.refine_edge_length,
             Range{0.0, coarse, true, false, "finer than edge_length"});
  g.quantity("refine_radius", dim::kLength, &gen.refine_radius, Range::positive());
  const bool refine = gen.refine_edge_length > 0.0;
  if (refine != g.has("refine_at")) {
    g.fail(refine ? "refine_edge_length" : "refine_at",
           "refine_edge_length and refine_at go together");
    return;
  }
  if (refine && !g.require("refine_radius")) return;
  if (!refine && g.has("refine_radius")) {
    g.fail("refine_radius", "has no effect without refine_edge_length and refine_at");
    return;
  }
  if (const json* at = g.find("refine_at"); at && at->is_string() && at->get<std::string>() ==
                                                                          "needle") {
    gen.refine_at_needle = true;  // resolved once the needle is read
  } else if (refine) {
    g.vec3("refine_at", dim::kLength, &gen.refine_at);
  }
}

void read_material(Reader& r, MaterialDef& m) {
  const bool by_speed = r.has("young_by_speed");
  if (by_speed == r.has("young")) {
    r.fail("", "give exactly one of \"young\" or \"young_by_speed\"");
    return;
  }
  if (!by_speed) {
    r.require("young");
    r.quantity("young", dim::kPressure, &m.young, Range::positive());
  } else {
    const json* table = r.find("young_by_speed");
    const std::string path = r.key_path("young_by_speed");
    if (!table->is_array() || table->size() < 2) {
      r.fail("young_by_speed", "expected an array of at least two {\"speed\", \"young\"} points");
      return;
    }
    for (size_t i = 0; i < table->size(); ++i) {
      Reader point(r.ctx(), &(*table)[i], join_path(path, std::to_string(i)), {"speed", "young"});
      if (!point.require("speed") || !point.require("young")) return;
      SpeedModulusPoint p;
      point.quantity("speed", dim::kSpeed, &p.speed, Range::non_negative());
      point.quantity("young", dim::kPressure, &p.young, Range::positive());
      if (!point.present()) return;
      if (!m.young_by_speed.empty() && p.speed <= m.young_by_speed.back().speed) {
        point.fail("speed", "speeds must increase along the table");
        return;
      }
      m.young_by_speed.push_back(p);
    }
  }
  if (!r.require("poisson")) return;
  r.number("poisson", &m.poisson,
           Range{0.0, 0.5, false, true, "0.5 is incompressible; explicit FEM needs nu < 0.5"});
  const int mass_keys = int(r.has("density")) + int(r.has("mass")) + int(r.has("vertex_mass"));
  if (mass_keys > 1) {
    r.fail("", "give at most one of \"density\", \"mass\" or \"vertex_mass\"");
    return;
  }
  if (r.quantity("density", dim::kDensity, &m.density, Range::positive())) {
    m.mass_spec = MassSpec::kDensity;
  } else if (r.quantity("mass", dim::kMass, &m.total_mass, Range::positive())) {
    m.mass_spec = MassSpec::kTotalMass;
  } else if (r.quantity("vertex_mass", dim::kMass, &m.vertex_mass, Range::positive())) {
    m.mass_spec = MassSpec::kVertexMass;
  }
  r.quantity("damping", dim::kFrequency, &m.damping, Range::non_negative());
}

void read_materials(Reader& root, Scene& scene) {
  // The particle model has no FEM materials (its parameters are in "particles").
  if (scene.model == ModelKind::kParticles && !root.has("materials")) return;
  if (!root.require("materials")) return;
  const json* node = root.find("materials");
  if (!node->is_object() || node->empty()) {
    root.fail("materials", "expected an object mapping region names to materials, e.g. "
                           "{\"default\": {\"young\": \"17.9 kPa\", \"poisson\": 0.49}}");
    return;
  }
  for (const auto& [region, value] : node->items()) {
    if (region == "note") continue;
    const std::string path = root.key_path("materials") + "." + region;
    if (region.empty()) {
      root.fail("materials", "empty region name");
      return;
    }
    Reader r(root.ctx(), &value, path,
             {"young", "young_by_speed", "poisson", "density", "mass", "vertex_mass", "damping"});
    if (!r.present()) return;
    RegionMaterialDef entry;
    entry.region = region;
    read_material(r, entry.material);
    scene.materials.push_back(std::move(entry));
  }
}

void read_integrator(Reader& root, Scene& scene) {
  Reader r = root.object("integrator", {"dt", "dt_safety", "mass_scaling", "target_dt",
                                        "mass_scaling_mode", "stiffness_damping", "dynamic_mass_safety",
                                        "drift_damping", "drift_window", "quasi_static_travel",
                                        "quasi_static_speed", "duration"});
  if (!r.present()) return;
  IntegratorDef& in = scene.integrator;
  r.auto_or_quantity("dt", dim::kTime, &in.dt, Range::positive());
  r.number("dt_safety", &in.dt_safety, Range::open_closed(0.0, 1.0));
  r.number("mass_scaling", &in.mass_scaling,
           Range{1.0, kInf, false, false, "1 is physical; larger values slow the dynamics down"});
  double target = 0.0;
  if (r.quantity("target_dt", dim::kTime, &target, Range::positive())) {
    if (in.dt) {
      r.fail("target_dt", "only with dt \"auto\" (an explicit dt fixes the step)");
      return;
    }
    in.target_dt = target;
  }
  r.choice("mass_scaling_mode",
           {Choice<MassScalingMode>{"uniform", MassScalingMode::kUniform},
            Choice<MassScalingMode>{"selective", MassScalingMode::kSelective}},
           &in.mass_scaling_mode);
  r.quantity("stiffness_damping", dim::kTime, &in.stiffness_damping, Range::non_negative());
  r.number("dynamic_mass_safety", &in.dynamic_mass_safety,
           Range{0.0, 1.0, false, false, "0 switches it off; at most 1 (the stability limit)"});
  r.auto_or_quantity("drift_damping", dim::kFrequency, &in.drift_damping, Range::non_negative());
  r.auto_or_quantity("drift_window", dim::kTime, &in.drift_window, Range::positive());
  r.quantity("quasi_static_travel", dim::kLength, &in.quasi_static_travel, Range::non_negative());
  r.quantity("quasi_static_speed", dim::kSpeed, &in.quasi_static_speed, Range::non_negative());
  r.quantity("duration", dim::kTime, &in.duration, Range::non_negative());
}

void read_solver(Reader& root, Scene& scene) {
  Reader r =
      root.object("solver", {"method", "note", "travel_step", "min_travel_step", "tolerance",
                             "max_iterations", "linear", "preconditioner", "barrier_volume",
                             "medium_viscosity", "puncture_tolerance", "suction_steps", "oracle"});
  if (!r.present()) return;
  SolverDef& s = scene.solver;
  r.choice("method",
           {Choice<SolverMethod>{"explicit", SolverMethod::kExplicit},
            Choice<SolverMethod>{"static", SolverMethod::kStatic}},
           &s.method);
  r.quantity("travel_step", dim::kLength, &s.travel_step, Range::positive());
  r.quantity("min_travel_step", dim::kLength, &s.min_travel_step, Range::positive());
  r.number("tolerance", &s.tolerance, Range::open_closed(0.0, 1.0));
  r.choice("linear",
           {Choice<LinearSolverKind>{"direct", LinearSolverKind::kDirect},
            Choice<LinearSolverKind>{"cg", LinearSolverKind::kCg}},
           &s.linear);
  r.choice("preconditioner",
           {Choice<PreconditionerKind>{"auto", PreconditionerKind::kAuto},
            Choice<PreconditionerKind>{"jacobi", PreconditionerKind::kJacobi},
            Choice<PreconditionerKind>{"multigrid", PreconditionerKind::kMultigrid}},
           &s.preconditioner);
  r.number("barrier_volume", &s.barrier_volume,
           Range{0.0, 1.0, false, true, "0 switches the barrier off; below 1 (rest)"});
  r.quantity("medium_viscosity", dim::kPressure * dim::kTime, &s.medium_viscosity,
             Range::non_negative());
  r.quantity("puncture_tolerance", dim::kLength, &s.puncture_tolerance, Range::positive());
  int64_t newton = s.max_iterations;
  if (r.integer("max_iterations", &newton, 1, 1000)) s.max_iterations = static_cast<int>(newton);
  int64_t steps = s.suction_steps;
  if (r.integer("suction_steps", &steps, 1, 1000)) s.suction_steps = static_cast<int>(steps);
  r.boolean("oracle", &s.oracle);
  if (s.oracle && s.linear == LinearSolverKind::kDirect)
    r.fail("oracle",
           "checks the CG solves against the direct solver; linear is already \"direct\"");
  if (s.min_travel_step > s.travel_step) r.fail("min_travel_step", "larger than travel_step");
}

// The particle model (Asgari et al.): only with "model": "particles".
void read_particles(Reader& root, Scene& scene) {
  Reader r = root.object("particles", {"layout", "particles", "pole_axis", "membrane_modulus",
                                       "membrane_relaxation_time", "radial_stiffness",
                                       "radial_damping", "damping", "compressibility",
                                       "areal_density", "centre_mass"});
  if (!r.present()) return;
  if (scene.model != ModelKind::kParticles) {
    r.fail("", "only used with \"model\": \"particles\"");
    return;
  }
  constexpr Dimension kPerArea{0, -2, 0};
  const Dimension radial_stiffness = dim::kStiffness * kPerArea;  // N/m^3
  const Dimension radial_damping = dim::kDamping * kPerArea;      // N*s/m^3
  const Dimension compressibility = dim::kNone / dim::kPressure;  // 1/Pa
  const Dimension areal_density = dim::kMass * kPerArea;          // kg/m^2
  ParticlesDef& p = scene.particles;
  r.choice("layout", {Choice<ParticleLayout>{"icosphere", ParticleLayout::kIcosphere},
                      Choice<ParticleLayout>{"latlong", ParticleLayout::kLatLong}},
           &p.layout);
  r.integer("particles", &p.particles, 12, 4'000'000);
  r.direction("pole_axis", &p.pole_axis);
  r.quantity("membrane_modulus", dim::kStiffness, &p.membrane_modulus, Range::positive());
  r.quantity("membrane_relaxation_time", dim::kTime, &p.membrane_relaxation_time, Range::non_negative());
  r.quantity("radial_stiffness", radial_stiffness, &p.radial_stiffness, Range::non_negative());
  r.quantity("radial_damping", radial_damping, &p.radial_damping, Range::non_negative());
  if (r.vec3("damping", radial_damping, &p.damping)) {
    for (int a = 0; a < 3; ++a)
      if (!(p.damping[a] >= 0.0)) {
        r.fail("damping", "each component must be >= 0");
        return;
      }
  }
  r.quantity("compressibility", compressibility, &p.compressibility, Range::positive());
  r.quantity("areal_density", areal_density, &p.areal_density, Range::positive());
  r.quantity("centre_mass", dim::kMass, &p.centre_mass, Range::non_negative());
}

void read_boundary(Reader& root, Scene& scene) {
  const json* node = root.find("boundary");
  if (!node) return;
  if (!node->is_array()) {
    root.fail("boundary", std::string("expected an array of conditions, got ") + node->type_name());
    return;
  }
  for (size_t i = 0; i < node->size(); ++i) {
    const json& item = (*node)[i];
    const std::string path = "boundary." + std::to_string(i);
    BoundaryDef b;
    {
      // The type decides which keys are allowed, so it is read first.
      Reader typed(root.ctx(), &item, path,
                   {"type", "where", "center", "radius", "depth", "speed", "direction"});
      if (!typed.present() || !typed.require("type")) return;
      if (!typed.choice("type", {Choice<BoundaryKind>{"fixed", BoundaryKind::kFixed},
                                 Choice<BoundaryKind>{"indent", BoundaryKind::kIndent}},
                        &b.type)) {
        return;
      }
    }
    if (b.type == BoundaryKind::kFixed) {
      Reader r(root.ctx(), &item, path, {"type", "where"});
      if (!r.require("where")) return;
      Reader w = r.object("where", {"surface", "region", "normal", "below", "above", "center",
                                    "radius"});
      if (!w.present()) return;
      VertexSelect& s = b.where;
      w.boolean("surface", &s.surface_only);
      w.string("region", &s.region);
      w.direction("normal", &s.normal);
      w.quantity("below", dim::kLength, &s.below);
      w.quantity("above", dim::kLength, &s.above);
      if (w.has("normal") && !w.has("below") && !w.has("above")) {
        w.fail("normal", "needs \"below\" or \"above\"");
        return;
      }
      if (w.has("below") && w.has("above") && s.below < s.above) {
        w.fail("below", "below < above selects no vertex");
        return;
      }
      if (w.has("center") != w.has("radius")) {
        w.fail(w.has("center") ? "radius" : "center", "\"center\" and \"radius\" go together");
        return;
      }
      if (w.has("center")) {
        Vec3d c{};
        w.vec3("center", dim::kLength, &c);
        s.center = c;
        w.quantity("radius", dim::kLength, &s.radius, Range::positive());
      }
      if (!w.has("region") && !w.has("below") && !w.has("above") && !w.has("center")) {
        w.fail("", "selects every vertex (or every surface vertex): give \"below\", \"above\", "
                   "\"center\"/\"radius\" or \"region\"");
        return;
      }
      if (w.has("region") && s.region.empty()) {
        w.fail("region", "empty region name");
        return;
      }
    } else {
      Reader r(root.ctx(), &item, path, {"type", "center", "radius", "depth", "speed", "direction"});
      if (!r.require("center") || !r.require("radius") || !r.require("depth") ||
          !r.require("speed")) {
        return;
      }
      r.vec3("center", dim::kLength, &b.center);
      r.quantity("radius", dim::kLength, &b.radius, Range::positive());
      r.quantity("depth", dim::kLength, &b.depth, Range::positive());
      r.quantity("speed", dim::kSpeed, &b.speed, Range::positive());
      if (!r.direction("direction", &b.direction) && r.present()) {
        const double distance = norm(b.center);
        if (!(distance > 0.0)) {
          r.fail("direction", "required when the centre is the origin (default: towards the origin)");
          return;
        }
        b.direction = -b.center / distance;
      }
    }
    scene.boundary.push_back(b);
  }
}

// "auto" (nullopt) or a point with units.
bool read_auto_point(Reader& r, std::string_view key, std::optional<Vec3d>* out) {
  const json* v = r.find(key);
  if (!v) return false;
  if (v->is_string() && v->get<std::string>() == "auto") {
    out->reset();
    return true;
  }
  Vec3d p{};
  if (!r.vec3(key, dim::kLength, &p)) return false;
  *out = p;
  return true;
}

void read_needle(Reader& root, Scene& scene) {
  Reader r = root.object("needle", {"enabled", "shape", "tip_radius", "direction", "start",
                                    "standoff", "speed", "max_travel", "friction", "stick_length",
                                    "force_filter", "trajectory"});
  if (!r.present()) return;
  NeedleDef& n = scene.needle;
  n.enabled = true;
  r.boolean("enabled", &n.enabled);
  r.choice("shape", {Choice<NeedleShape>{"point", NeedleShape::kPoint},
                     Choice<NeedleShape>{"sphere", NeedleShape::kSphere},
                     Choice<NeedleShape>{"flat", NeedleShape::kFlat}},
           &n.shape);
  r.quantity("tip_radius", dim::kLength, &n.tip_radius, Range::positive());
  r.direction("direction", &n.direction);
  read_auto_point(r, "start", &n.start);
  r.quantity("standoff", dim::kLength, &n.standoff, Range::non_negative());
  r.quantity("speed", dim::kSpeed, &n.speed, Range::positive());
  r.quantity("max_travel", dim::kLength, &n.max_travel, Range::non_negative());
  r.number("friction", &n.friction, Range::non_negative());
  r.quantity("stick_length", dim::kLength, &n.stick_length, Range::non_negative());
  r.quantity("force_filter", dim::kTime, &n.force_filter, Range::non_negative());
  r.file_path("trajectory", &n.trajectory);
}

void read_puncture(Reader& root, Scene& scene) {
  Reader r = root.object("puncture",
                         {"criterion", "threshold", "force_drop", "drop_time", "shaft_friction"});
  if (!r.present()) return;
  PunctureDef& p = scene.puncture;
  if (!r.require("criterion")) return;
  r.choice("criterion", {Choice<PunctureCriterion>{"none", PunctureCriterion::kNone},
                         Choice<PunctureCriterion>{"force", PunctureCriterion::kForce},
                         Choice<PunctureCriterion>{"strain", PunctureCriterion::kStrain},
                         Choice<PunctureCriterion>{"energy", PunctureCriterion::kEnergy}},
           &p.criterion);
  // The threshold's dimension follows the criterion; with "none" it is ignored, so that
  // --set puncture.criterion=none works on any scene.
  if (p.criterion != PunctureCriterion::kNone && r.require("threshold")) {
    const Dimension d = p.criterion == PunctureCriterion::kForce    ? dim::kForce
                        : p.criterion == PunctureCriterion::kEnergy ? dim::kEnergy
                                                                    : dim::kNone;
    r.quantity("threshold", d, &p.threshold, Range::positive());
  }
  r.number("force_drop", &p.force_drop, Range::open_closed(0.0, 1.0));
  r.quantity("drop_time", dim::kTime, &p.drop_time, Range::non_negative());
  r.quantity("shaft_friction", dim::kStiffness, &p.shaft_friction, Range::non_negative());
}

void read_contact(Reader& root, Scene& scene) {
  Reader r = root.object("contact", {"model", "stiffness", "needle_quadrature", "rim_damping",
                                     "note"});
  if (!r.present()) return;
  ContactDef& c = scene.contact;
  if (const nlohmann::json* m = r.find("model"); m && m->is_string() && *m == "kinematic") {
    r.fail("model", "'kinematic' was retired: every scene runs the penalty contact, whose load "
                    "does not depend on how many vertices the tip touches (docs/architecture.md, "
                    "\"One engine\")");
    return;
  }
  r.choice("model", {Choice<ContactModel>{"penalty", ContactModel::kPenalty}}, &c.model);
  r.number("stiffness", &c.stiffness, Range::positive());
  r.choice("needle_quadrature", {Choice<bool>{"faces", true}, Choice<bool>{"vertices", false}},
           &c.needle_on_faces);
  r.number("rim_damping", &c.rim_damping, Range::non_negative());
}

void read_holding_pipette(Reader& root, Scene& scene) {
  Reader r = root.object("holding_pipette", {"enabled", "mode", "inner_radius", "outer_radius",
                                             "edge_radius", "suction", "friction", "stick_length", "side",
                                             "position"});
  if (!r.present()) return;
  HoldingPipetteDef& h = scene.holding_pipette;
  h.enabled = true;
  r.boolean("enabled", &h.enabled);
  r.choice("mode", {Choice<HoldingMode>{"suction", HoldingMode::kSuction},
                    Choice<HoldingMode>{"fixed", HoldingMode::kFixed}},
           &h.mode);
  if (h.enabled && !r.require("inner_radius")) return;
  r.quantity("inner_radius", dim::kLength, &h.inner_radius, Range::positive());
  if (r.quantity("outer_radius", dim::kLength, &h.outer_radius, Range::non_negative()) &&
      h.outer_radius != 0.0 && h.outer_radius < h.inner_radius) {
    r.fail("outer_radius", "must be >= inner_radius (" +
                               format_quantity(h.inner_radius, dim::kLength) + ") or 0");
    return;
  }
  if (r.quantity("edge_radius", dim::kLength, &h.edge_radius, Range::non_negative())) {
    const double outer = h.outer_radius > h.inner_radius ? h.outer_radius : 1.25 * h.inner_radius;
    if (!(h.edge_radius < 0.5 * (outer - h.inner_radius))) {
      r.fail("edge_radius", "must be below half the rim's width (" +
                                format_quantity(0.5 * (outer - h.inner_radius), dim::kLength) +
                                ")");
      return;
    }
  }
  r.quantity("suction", dim::kPressure, &h.suction, Range::non_negative());
  r.number("friction", &h.friction, Range::non_negative());
  r.quantity("stick_length", dim::kLength, &h.stick_length, Range::non_negative());
  Vec3d side{};
  if (r.direction("side", &side)) h.side = side;
  read_auto_point(r, "position", &h.position);
}

void read_haptics(Reader& root, Scene& scene) {
  Reader r = root.object("haptics", {"device", "rate", "workspace_scale", "force_scale",
                                     "max_force", "max_stiffness", "interpolation", "stall_timeout",
                                     "max_tip_speed", "coupling_stiffness", "coupling_damping",
                                     "replay_file", "network_host", "network_port"});
  if (!r.present()) return;
  HapticsDef& h = scene.haptics;
  r.choice("device", {Choice<HapticDeviceKind>{"none", HapticDeviceKind::kNone},
                      Choice<HapticDeviceKind>{"scripted", HapticDeviceKind::kScripted},
                      Choice<HapticDeviceKind>{"emulated", HapticDeviceKind::kEmulated},
                      Choice<HapticDeviceKind>{"replay", HapticDeviceKind::kReplay},
                      Choice<HapticDeviceKind>{"network", HapticDeviceKind::kNetwork}},
           &h.device);
  r.quantity("rate", dim::kFrequency, &h.rate, Range::positive());
  r.number("workspace_scale", &h.workspace_scale, Range::positive());
  r.number("force_scale", &h.force_scale, Range::positive());
  r.quantity("max_force", dim::kForce, &h.max_force, Range::positive());
  r.quantity("max_stiffness", dim::kStiffness, &h.max_stiffness, Range::positive());
  r.choice("interpolation",
           {Choice<HapticInterpolation>{"first_order_hold", HapticInterpolation::kFirstOrderHold},
            Choice<HapticInterpolation>{"stiffness", HapticInterpolation::kStiffness}},
           &h.interpolation);
  r.quantity("stall_timeout", dim::kTime, &h.stall_timeout, Range::positive());
  r.auto_or_quantity("max_tip_speed", dim::kSpeed, &h.max_tip_speed, Range::positive());
  r.auto_or_quantity("coupling_stiffness", dim::kStiffness, &h.coupling_stiffness,
                     Range::positive());
  r.auto_or_quantity("coupling_damping", dim::kDamping, &h.coupling_damping,
                     Range::non_negative());
  r.file_path("replay_file", &h.replay_file);
  if (r.string("network_host", &h.network_host) && h.network_host.empty()) {
    r.fail("network_host", "empty host");
    return;
  }
  int64_t port = h.network_port;
  if (r.integer("network_port", &port, 1, 65535)) h.network_port = static_cast<int>(port);
  if (h.device == HapticDeviceKind::kReplay && h.replay_file.empty() && r.present()) {
    r.fail("replay_file", "required with device \"replay\"");
  }
}

void read_experiment(Reader& root, Scene& scene) {
  root.choice("experiment",
              {Choice<Experiment>{"quasi_static", Experiment::kQuasiStatic},
               Choice<Experiment>{"dynamic", Experiment::kDynamic}},
              &scene.experiment);
  Reader r = root.object("quasi_static",
                         {"max_imbalance", "max_kinetic_share", "force_floor", "note"});
  if (!r.present()) return;
  QuasiStaticDef& q = scene.quasi_static;
  r.number("max_imbalance", &q.max_imbalance, Range::positive());
  r.number("max_kinetic_share", &q.max_kinetic_share,
           Range{0.0, 1.0, true, false, "a share of the energy, in (0, 1]"});
  r.auto_or_quantity("force_floor", dim::kForce, &q.force_floor, Range::positive());
}

void read_output(Reader& root, Scene& scene) {
  Reader r = root.object("output", {"frames", "frame_interval", "sample_interval", "format"});
  if (!r.present()) return;
  OutputDef& o = scene.output;
  if (r.has("frames") && r.has("frame_interval")) {
    r.fail("frame_interval", "give either \"frames\" or \"frame_interval\", not both");
    return;
  }
  int64_t frames = o.frames;
  if (r.integer("frames", &frames, 0, 1'000'000)) o.frames = static_cast<int>(frames);
  double interval = 0.0;
  if (r.quantity("frame_interval", dim::kTime, &interval, Range::positive())) {
    o.frame_interval = interval;
  }
  r.quantity("sample_interval", dim::kTime, &o.sample_interval, Range::non_negative());
  if (r.choice("format", {Choice<FrameFormat>{"vtu", FrameFormat::kVtu},
                          Choice<FrameFormat>{"xdmf", FrameFormat::kXdmf},
                          Choice<FrameFormat>{"vtu+xdmf", FrameFormat::kVtuAndXdmf}},
               &o.format) &&
      writes_xdmf(o.format) && !xdmf_supported())
    r.fail("format", kXdmfUnsupportedMessage);  // at load, not when the first frame is due
}

// Where the needle axis first meets the generated ball (centred at the origin).
void resolve_refine_at(Context& ctx, Scene& scene) {
  MeshGenerateDef& g = scene.mesh.generate;
  if (scene.mesh.source != MeshSource::kGenerate || !g.refine_at_needle) return;
  const std::string path = "mesh.generate.refine_at";
  if (!scene.needle.enabled) {
    ctx.fail(path, "\"needle\" needs an enabled needle section");
    return;
  }
  // In coordinates divided by radii_scale the ellipsoid is the ball of radius diameter / 2, and
  // the ray p + t d stays a ray with the same parameter t.
  const double radius = g.diameter / 2;
  const Vec3d k = g.radii_scale;
  const Vec3d d = scene.needle.direction;
  const Vec3d ds{d.x / k.x, d.y / k.y, d.z / k.z};
  if (!scene.needle.start) {
    // The auto start lies on the axis through the centre: the entry is where -d meets the surface.
    g.refine_at = -(radius / norm(ds)) * d;
    return;
  }
  const Vec3d p = *scene.needle.start;
  const Vec3d ps{p.x / k.x, p.y / k.y, p.z / k.z};
  const double a = dot(ds, ds);
  const double b = dot(ps, ds);
  const double c = dot(ps, ps) - radius * radius;
  const double disc = b * b - a * c;
  if (c <= 0.0) {
    g.refine_at = p;  // the needle starts inside the cell
    return;
  }
  const double t = (-b - std::sqrt(std::max(disc, 0.0))) / a;
  if (disc < 0.0 || t < 0.0) {
    ctx.fail(path, "\"needle\": the needle axis (needle.start, needle.direction) misses the cell");
    return;
  }
  g.refine_at = p + t * d;
}

// Hajiyavand et al. 2019 eq. 9: modulus linear in speed through the table, extrapolated beyond its ends.
void resolve_speed_moduli(Context& ctx, Scene& scene) {
  for (RegionMaterialDef& entry : scene.materials) {
    std::vector<SpeedModulusPoint>& t = entry.material.young_by_speed;
    if (t.empty()) continue;
    const std::string path = "materials." + entry.region + ".young_by_speed";
    if (!scene.needle.enabled) {
      ctx.fail(path, "needs needle.speed, but the scene has no enabled needle");
      return;
    }
    const double v = scene.needle.speed;
    size_t i = 0;
    while (i + 2 < t.size() && v > t[i + 1].speed) ++i;
    const double young =
        t[i].young + (v - t[i].speed) * (t[i + 1].young - t[i].young) / (t[i + 1].speed - t[i].speed);
    if (!(young > 0.0)) {
      ctx.fail(path, "extrapolated modulus at needle.speed " +
                         format_quantity(v, dim::kSpeed) + " is " +
                         format_quantity(young, dim::kPressure) + ", must be > 0 Pa");
      return;
    }
    entry.material.young = young;
  }
}

// For generated meshes the regions are known: every material must name one, and every region
// must have a material.
void check_generated_regions(Context& ctx, const Scene& scene) {
  if (scene.mesh.source != MeshSource::kGenerate || ctx.failed()) return;
  const MeshGenerateDef& g = scene.mesh.generate;
  std::vector<std::string> regions = {"cytoplasm"};
  if (g.zona_thickness > 0.0) regions.push_back("zona");
  if (g.nucleus_diameter > 0.0) regions.push_back("nucleus");
  std::string list;
  for (const std::string& r : regions) list += (list.empty() ? "" : ", ") + r;
  for (const RegionMaterialDef& m : scene.materials) {
    if (m.region == "default" ||
        std::find(regions.begin(), regions.end(), m.region) != regions.end()) {
      continue;
    }
    std::string why;
    if (m.region == "zona") why = "mesh.generate.zona_thickness is 0; ";
    if (m.region == "nucleus") why = "mesh.generate.nucleus_diameter is 0; ";
    ctx.fail("materials." + m.region, "the generated mesh has no region '" + m.region + "' (" +
                                          why + "it has: " + list + ")");
    return;
  }
  for (const std::string& r : regions) {
    if (!find_material(scene, r)) {
      ctx.fail("materials", "no material for region '" + r + "': add materials." + r +
                                " or materials.default");
      return;
    }
  }
}

void check_scene(Context& ctx, Scene& scene) {
  if (ctx.failed()) return;
  resolve_refine_at(ctx, scene);
  resolve_speed_moduli(ctx, scene);
  if (scene.model != ModelKind::kParticles) check_generated_regions(ctx, scene);
  if (ctx.failed()) return;
  const bool generated = scene.mesh.source == MeshSource::kGenerate;
  const Vec3d k = scene.mesh.generate.radii_scale;
  const double cell_radius = scene.mesh.generate.diameter / 2 * std::min({k.x, k.y, k.z});
  if (generated && scene.holding_pipette.enabled &&
      scene.holding_pipette.inner_radius >= cell_radius) {
    ctx.fail("holding_pipette.inner_radius",
             format_quantity(scene.holding_pipette.inner_radius, dim::kLength) +
                 " must be smaller than the cell radius (" +
                 format_quantity(cell_radius, dim::kLength) + ")");
    return;
  }
  // Something must end the run.
  if (scene.integrator.duration == 0.0) {
    bool has_indent = false;
    for (const BoundaryDef& b : scene.boundary) has_indent |= b.type == BoundaryKind::kIndent;
    if (scene.needle.enabled && scene.needle.trajectory.empty() && scene.needle.max_travel == 0.0) {
      ctx.fail("needle.max_travel", "set it or integrator.duration: nothing else ends the run");
    } else if (!scene.needle.enabled && !has_indent) {
      ctx.fail("integrator.duration", "required: the scene has no needle or indent to end the run");
    }
  }
}

std::string trim(std::string_view s) {
  const size_t a = s.find_first_not_of(" \t");
  if (a == std::string_view::npos) return {};
  const size_t b = s.find_last_not_of(" \t");
  return std::string(s.substr(a, b - a + 1));
}

bool parse_index(const std::string& s, size_t* out) {
  if (s.empty()) return false;
  const auto [end, ec] = std::from_chars(s.data(), s.data() + s.size(), *out);
  return ec == std::errc() && end == s.data() + s.size();
}

// Collects the first duplicate key while nlohmann parses (it would silently keep the last one).
class DuplicateKeyFinder {
 public:
  bool operator()(int /*depth*/, json::parse_event_t event, json& parsed) {
    switch (event) {
      case json::parse_event_t::object_start:
        stack_.push_back(Frame{true, {}, {}, 0});
        break;
      case json::parse_event_t::array_start:
        stack_.push_back(Frame{false, {}, {}, 0});
        break;
      case json::parse_event_t::key: {
        Frame& top = stack_.back();
        top.key = parsed.get<std::string>();
        if (!top.keys.insert(top.key).second && duplicate_.empty()) {
          duplicate_ = path();
        }
        break;
      }
      case json::parse_event_t::object_end:
      case json::parse_event_t::array_end:
        stack_.pop_back();
        if (!stack_.empty() && !stack_.back().object) ++stack_.back().index;
        break;
      case json::parse_event_t::value:
        if (!stack_.empty() && !stack_.back().object) ++stack_.back().index;
        break;
    }
    return true;
  }
  const std::string& duplicate() const { return duplicate_; }

 private:
  struct Frame {
    bool object;
    std::set<std::string> keys;
    std::string key;
    size_t index;
  };
  std::string path() const {
    std::string p;
    for (const Frame& f : stack_) p = join_path(p, f.object ? f.key : std::to_string(f.index));
    return p;
  }
  std::vector<Frame> stack_;
  std::string duplicate_;
};

// Keys that exclude each other under one parent ("vertices" or "edge_length"). When --set
// gives one of them, the file's others are dropped: the command line wins over the file.
void drop_alternatives(json& doc, const std::string& set_path,
                       const std::vector<std::string>& overridden) {
  static const std::vector<std::vector<std::string>> kGroups = {
      {"file", "generate"},      {"vertices", "edge_length"},      {"young", "young_by_speed"},
      {"density", "mass", "vertex_mass"}, {"frames", "frame_interval"}, {"dt", "target_dt"}};
  const size_t dot = set_path.rfind('.');
  if (dot == std::string::npos) return;
  const std::string parent_path = set_path.substr(0, dot);
  const std::string key = set_path.substr(dot + 1);
  json* parent = &doc;
  for (size_t start = 0; start <= parent_path.size();) {
    const size_t next = std::min(parent_path.find('.', start), parent_path.size());
    const std::string segment = parent_path.substr(start, next - start);
    if (!parent->is_object() || parent->find(segment) == parent->end()) return;
    parent = &(*parent)[segment];
    start = next + 1;
  }
  if (!parent->is_object()) return;
  for (const std::vector<std::string>& group : kGroups) {
    if (std::find(group.begin(), group.end(), key) == group.end()) continue;
    // dt "auto" and target_dt live together; only an explicit dt excludes target_dt.
    if (key == "dt" && parent->value("dt", json()) == json("auto")) continue;
    // A graded mesh takes both vertices and edge_length (scaled to the count).
    if (group[0] == "vertices" && parent->contains("refine_edge_length")) continue;
    for (const std::string& other : group) {
      const std::string other_path = parent_path + "." + other;
      if (other == key ||
          std::find(overridden.begin(), overridden.end(), other_path) != overridden.end()) {
        continue;
      }
      parent->erase(other);
      if (key == "generate" && other == "file") parent->erase("unit");
    }
  }
}

}  // namespace

Status apply_override(json& doc, const std::string& assignment) {
  const size_t eq = assignment.find('=');
  if (eq == std::string::npos) {
    return make_error("--set %s: expected key.path=value", assignment.c_str());
  }
  const std::string key = trim(std::string_view(assignment).substr(0, eq));
  const std::string text = trim(std::string_view(assignment).substr(eq + 1));
  std::vector<std::string> segments;
  for (size_t start = 0;;) {
    const size_t dot = key.find('.', start);
    segments.push_back(key.substr(start, dot == std::string::npos ? std::string::npos : dot - start));
    if (dot == std::string::npos) break;
    start = dot + 1;
  }
  for (const std::string& s : segments) {
    if (s.empty()) return make_error("--set %s: empty key in '%s'", assignment.c_str(), key.c_str());
  }
  // JSON when it parses as JSON (2000, true, [1, 0, 0], "quoted"), else the text itself
  // ("20kPa", "0.6 mm/s", "auto").
  if (Status depth = check_json_depth(text); !depth)
    return make_error("--set %s: the value is %s", key.c_str(), depth.error().message.c_str());
  json value = json::parse(text, nullptr, /*allow_exceptions=*/false);
  if (value.is_discarded()) value = text;
  if (!doc.is_object()) return make_error("--set %s: the scene is not a JSON object", assignment.c_str());
  json* node = &doc;
  std::string walked;
  for (size_t i = 0; i < segments.size(); ++i) {
    const std::string& s = segments[i];
    const bool last = i + 1 == segments.size();
    if (node->is_object()) {
      if (last) {
        // null removes the key: the way to fall back to a default from the command line.
        if (value.is_null()) {
          node->erase(s);
        } else {
          (*node)[s] = std::move(value);
        }
        return Status::ok_status();
      }
      if (node->find(s) == node->end()) (*node)[s] = json::object();
      node = &(*node)[s];
    } else if (node->is_array()) {
      size_t index = 0;
      if (!parse_index(s, &index) || index >= node->size()) {
        return make_error("--set %s: '%s' is an array of %zu; '%s' is not an index into it",
                          assignment.c_str(), walked.c_str(), node->size(), s.c_str());
      }
      if (last) {
        (*node)[index] = std::move(value);
        return Status::ok_status();
      }
      node = &(*node)[index];
    } else {
      return make_error("--set %s: '%s' is a %s, not an object", assignment.c_str(),
                        walked.c_str(), node->type_name());
    }
    walked = join_path(walked, s);
  }
  return Status::ok_status();  // not reached: the loop returns at the last segment
}

Result<Scene> parse_scene(const json& input, const std::string& source_name,
                          const std::vector<std::string>& overrides) {
  Context ctx;
  ctx.source = source_name.empty() ? std::string("scene") : source_name;
  ctx.base_dir = fs::path(source_name).parent_path();
  if (ctx.base_dir.empty()) ctx.base_dir = ".";
  json doc = input;
  for (const std::string& o : overrides) {
    Status st = apply_override(doc, o);
    if (!st) return Error{ctx.source + ": " + st.error().message};
    ctx.overridden.push_back(trim(std::string_view(o).substr(0, o.find('='))));
  }
  for (const std::string& path : ctx.overridden) drop_alternatives(doc, path, ctx.overridden);

  Scene scene;
  scene.source = source_name;
  scene.name = fs::path(source_name).stem().string();
  Reader root(ctx, &doc, "",
              {"version", "name", "description", "mesh", "model", "volumetric",
               "volumetric_stabilisation", "materials",
               "integrator",
               "boundary", "needle", "puncture", "holding_pipette", "contact", "haptics",
               "output", "particles", "experiment", "quasi_static", "solver"});
  int64_t version = 1;
  root.integer("version", &version, 1, 1);
  root.string("name", &scene.name);
  root.string("description", &scene.description);
  read_mesh(root, scene);
  root.choice("model", kModels, &scene.model);
  root.choice("volumetric",
              {Choice<bool>{"element", false}, Choice<bool>{"nodal", true}},
              &scene.nodal_pressure);
  if (scene.nodal_pressure && scene.model != ModelKind::kStableNeoHookean)
    root.fail("volumetric", "\"nodal\" is implemented for \"model\": \"neohookean\" only "
                            "(with another model, set \"volumetric\": \"element\")");
  if (root.number("volumetric_stabilisation", &scene.volumetric_stabilisation,
                  Range{0.0, 1.0, false, true, "the fraction of lambda kept per element"}) &&
      !scene.nodal_pressure && scene.volumetric_stabilisation > 0)
    root.fail("volumetric_stabilisation", "needs \"volumetric\": \"nodal\"");
  read_needle(root, scene);
  read_materials(root, scene);
  read_integrator(root, scene);
  read_solver(root, scene);
  read_particles(root, scene);
  read_boundary(root, scene);
  read_puncture(root, scene);
  read_holding_pipette(root, scene);
  read_contact(root, scene);
  read_haptics(root, scene);
  read_output(root, scene);
  read_experiment(root, scene);
  check_scene(ctx, scene);
  if (ctx.failed()) return *ctx.error;
  return scene;
}

Status check_json_depth(std::string_view text, int max_depth) {
  int depth = 0;
  bool in_string = false, escaped = false;
  size_t line = 1, line_start = 0;
  for (size_t i = 0; i < text.size(); ++i) {
    const char c = text[i];
    if (in_string) {
      // Brackets in strings are text; a backslash hides the next character (\" among them).
      if (escaped) {
        escaped = false;
      } else if (c == '\\') {
        escaped = true;
      } else if (c == '"') {
        in_string = false;
      }
      continue;
    }
    switch (c) {
      case '"':
        in_string = true;
        break;
      case '[':
      case '{':
        if (++depth > max_depth)
          return make_error("nested deeper than %d levels (line %zu, column %zu)", max_depth, line,
                            i - line_start + 1);
        break;
      case ']':
      case '}':
        // Unbalanced text is the parser's to report; only the depth is checked here.
        depth = std::max(depth - 1, 0);
        break;
      case '\n':
        ++line;
        line_start = i + 1;
        break;
      default:
        break;
    }
  }
  return Status::ok_status();
}

Status read_scene_json(const std::string& path, json* out) {
  // What the path is, before opening it: a FIFO would block the open, a device (/dev/zero) or a
  // huge file would be read whole into memory.
  const std::string kind = file_kind(path);
  if (kind.empty()) return make_error("%s: cannot open (no such file)", path.c_str());
  if (kind == "directory") return make_error("%s: is a directory, not a scene file", path.c_str());
  if (kind != "regular file")
    return make_error("%s: is not a regular file (%s)", path.c_str(), kind.c_str());
  std::error_code ec;
  const std::uintmax_t size = fs::file_size(path, ec);
  if (!ec && size > kMaxSceneFileBytes)
    return make_error("%s: %ju bytes, more than the %ju a scene file may have", path.c_str(), size,
                      kMaxSceneFileBytes);
  std::ifstream in(path, std::ios::binary);
  if (!in) return make_error("%s: cannot open (%s)", path.c_str(), std::strerror(errno));
  // By chunks, stopping past the bound in case the file grew since it was measured.
  std::string text;
  if (!ec) text.reserve(static_cast<size_t>(size));
  char chunk[1 << 16];
  while (text.size() <= kMaxSceneFileBytes && in.read(chunk, sizeof chunk).gcount() > 0)
    text.append(chunk, static_cast<size_t>(in.gcount()));
  if (in.bad()) return make_error("%s: read error", path.c_str());
  if (text.size() > kMaxSceneFileBytes)
    return make_error("%s: more than the %ju bytes a scene file may have", path.c_str(),
                      kMaxSceneFileBytes);
  if (Status depth = check_json_depth(text); !depth)
    return make_error("%s: %s", path.c_str(), depth.error().message.c_str());
  DuplicateKeyFinder duplicates;
  try {
    // Keeps the callback by reference semantics: nlohmann copies the functor, so it is wrapped.
    *out = json::parse(text, [&duplicates](int depth, json::parse_event_t event, json& parsed) {
      return duplicates(depth, event, parsed);
    });
  } catch (const json::parse_error& e) {
    // "[json.exception.parse_error.101] parse error at line 3, column 5: ..." -> "line 3, ..."
    std::string what = e.what();
    const size_t at = what.find("parse error at ");
    if (at != std::string::npos) what = what.substr(at + std::strlen("parse error at "));
    return make_error("%s: %s", path.c_str(), what.c_str());
  } catch (const json::exception& e) {
    return make_error("%s: %s", path.c_str(), e.what());
  }
  if (!duplicates.duplicate().empty()) {
    return make_error("%s: %s: duplicate key", path.c_str(), duplicates.duplicate().c_str());
  }
  return Status::ok_status();
}

Result<Scene> load_scene(const std::string& path, const std::vector<std::string>& overrides) {
  json doc;
  if (Status st = read_scene_json(path, &doc); !st) return st.error();
  return parse_scene(doc, path, overrides);
}

const MaterialDef* find_material(const Scene& scene, const std::string& region) {
  const MaterialDef* fallback = nullptr;
  for (const RegionMaterialDef& m : scene.materials) {
    if (m.region == region) return &m.material;
    if (m.region == "default") fallback = &m.material;
  }
  return fallback;
}

const char* model_name(ModelKind model) {
  for (const Choice<ModelKind>& c : kModels) {
    if (c.value == model) return c.name;
  }
  return "?";
}

}  // namespace zona
