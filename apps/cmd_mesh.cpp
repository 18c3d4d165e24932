// `zona mesh info | generate | convert`: inspect, generate and convert tetrahedral meshes.
#include <chrono>
#include <cstdio>
#include <map>
#include <memory>
#include <sstream>

#include <nlohmann/json.hpp>

#include "apps/commands.h"
#include "engine/mesh/mesh_generate.h"
#include "engine/mesh/mesh_io.h"
#include "engine/scene/scene.h"
#include "engine/scene/scene_mesh.h"
#include "engine/core/units.h"

namespace zona::cli {
namespace {

// Length of one file unit [m] from a name such as "m", "um", "mm".
Result<double> unit_scale(const std::string& unit) {
  return parse_quantity("1 " + unit, dim::kLength);
}

// Parses "x,y,z" with an optional unit on each ("0,0,28um") or on the whole ("0,0,28 um").
Result<Vec3d> parse_point(const std::string& text) {
  std::stringstream ss(text);
  std::string part;
  Vec3d p{0, 0, 0};
  int i = 0;
  while (std::getline(ss, part, ',')) {
    if (i >= 3) return make_error("--refine-at: expected x,y,z, got '%s'", text.c_str());
    Result<double> v = parse_quantity(part, dim::kLength);
    if (!v.ok()) return make_error("--refine-at: %s", v.error().message.c_str());
    p[i++] = *v;
  }
  if (i != 3) return make_error("--refine-at: expected x,y,z, got '%s'", text.c_str());
  return p;
}

void print_warnings(const std::vector<std::string>& warnings) {
  for (const std::string& w : warnings) std::fprintf(stderr, "zona: warning: %s\n", w.c_str());
}

nlohmann::json mesh_summary(const Mesh& mesh) {
  const MeshQuality q = mesh_quality(mesh);
  const BoundarySurface surface = extract_boundary(mesh);
  const Aabb box = mesh_bounds(mesh);
  std::map<std::string, int64_t> regions;
  for (int32_t tag : mesh.tet_region) ++regions[mesh.region_name(tag)];
  nlohmann::json j;
  j["vertices"] = mesh.vertex_count();
  j["tets"] = mesh.tet_count();
  j["boundary_triangles"] = surface.triangles.size();
  j["boundary_vertices"] = surface.vertices.size();
  j["volume_m3"] = q.volume;
  j["min_dihedral_deg"] = q.min_dihedral_deg;
  j["max_dihedral_deg"] = q.max_dihedral_deg;
  j["max_aspect_ratio"] = q.max_aspect_ratio;
  j["mean_aspect_ratio"] = q.mean_aspect_ratio;
  j["min_edge_m"] = q.min_edge;
  j["max_edge_m"] = q.max_edge;
  j["bounds_m"] = {{box.lo.x, box.lo.y, box.lo.z}, {box.hi.x, box.hi.y, box.hi.z}};
  j["centre_m"] = {0.5 * (box.lo.x + box.hi.x), 0.5 * (box.lo.y + box.hi.y),
                   0.5 * (box.lo.z + box.hi.z)};
  j["size_m"] = {box.hi.x - box.lo.x, box.hi.y - box.lo.y, box.hi.z - box.lo.z};
  j["regions"] = regions;
  return j;
}

void print_summary_text(const std::string& name, const nlohmann::json& j) {
  std::printf("%s\n", name.c_str());
  std::printf("  vertices            %lld\n", j["vertices"].get<long long>());
  std::printf("  tetrahedra          %lld\n", j["tets"].get<long long>());
  std::printf("  boundary triangles  %lld\n", j["boundary_triangles"].get<long long>());
  std::printf("  volume              %.6g m^3\n", j["volume_m3"].get<double>());
  std::printf("  dihedral angles     %.2f .. %.2f deg\n", j["min_dihedral_deg"].get<double>(),
              j["max_dihedral_deg"].get<double>());
  std::printf("  aspect ratio        mean %.3f, max %.3f\n", j["mean_aspect_ratio"].get<double>(),
              j["max_aspect_ratio"].get<double>());
  std::printf("  edge length         %.4g .. %.4g m\n", j["min_edge_m"].get<double>(),
              j["max_edge_m"].get<double>());
  const nlohmann::json& b = j["bounds_m"];
  std::printf("  bounding box        %.4g .. %.4g, %.4g .. %.4g, %.4g .. %.4g m\n",
              b[0][0].get<double>(), b[1][0].get<double>(), b[0][1].get<double>(),
              b[1][1].get<double>(), b[0][2].get<double>(), b[1][2].get<double>());
  const nlohmann::json& c = j["centre_m"];
  std::printf("  centre              %.4g, %.4g, %.4g m; size %.4g x %.4g x %.4g m\n",
              c[0].get<double>(), c[1].get<double>(), c[2].get<double>(), j["size_m"][0].get<double>(),
              j["size_m"][1].get<double>(), j["size_m"][2].get<double>());
  std::printf("  regions            ");
  for (const auto& [region, count] : j["regions"].items())
    std::printf(" %s: %lld", region.c_str(), count.get<long long>());
  std::printf("\n");
}

void add_info(CLI::App& group) {
  struct Args {
    std::string file;
    std::string unit = "m";
    bool json = false;
  };
  auto args = std::make_shared<Args>();
  auto* cmd = group.add_subcommand("info", "Counts, volume, quality and regions of a mesh file");
  cmd->add_option("FILE", args->file, "Mesh file (.msh, .node, .vtu)")->required();
  cmd->add_option("--unit", args->unit, "Length unit of the file's coordinates (m, um, mm)")
      ->capture_default_str();
  cmd->add_flag("--json", args->json, "Print one JSON object");
  cmd->callback([args] {
    Result<double> scale = unit_scale(args->unit);
    if (!scale.ok()) return fail("--unit: " + scale.error().message);
    ReadMeshOptions options;
    options.scale = *scale;
    std::vector<std::string> warnings;
    Result<Mesh> mesh = read_mesh(args->file, options, &warnings);
    if (!mesh.ok()) return fail(mesh.error().message);
    if (const std::string hint = mesh_unit_hint(*mesh); !hint.empty())
      warnings.push_back(args->file + " read with --unit " + args->unit + ": " + hint);
    print_warnings(warnings);
    const nlohmann::json j = mesh_summary(*mesh);
    if (args->json)
      std::printf("%s\n", j.dump(2).c_str());
    else
      print_summary_text(args->file, j);
  });
}

void add_generate(CLI::App& group) {
  struct Args {
    std::string scene;
    std::vector<std::string> sets;
    std::string diameter;
    int64_t vertices = 0;
    std::string edge_length;
    std::string refine_edge_length;
    std::string refine_radius;
    std::string refine_at;
    std::string zona_thickness;
    std::string nucleus_diameter;
    std::string out;
    bool json = false;
  };
  auto args = std::make_shared<Args>();
  auto* cmd = group.add_subcommand(
      "generate", "Generate a cell mesh from a scene or from a diameter and a resolution");
  auto* scene_opt = cmd->add_option("--scene", args->scene, "Scene file or name (mouse_oocyte)");
  cmd->add_option("--set", args->sets, "Override a scene key: key.path=value")->needs(scene_opt);
  auto* diameter_opt =
      cmd->add_option("--diameter", args->diameter, "Cell diameter with unit, e.g. 56um");
  scene_opt->excludes(diameter_opt);
  cmd->add_option("--vertices", args->vertices, "Target vertex count (uniform, or graded scaled)");
  cmd->add_option("--edge-length", args->edge_length, "Coarse edge length with unit");
  cmd->add_option("--refine-edge-length", args->refine_edge_length,
                  "Fine edge length at --refine-at, with unit");
  cmd->add_option("--refine-radius", args->refine_radius, "Radius of the fine zone, with unit");
  cmd->add_option("--refine-at", args->refine_at, "Puncture point x,y,z with unit (0,0,28um)");
  cmd->add_option("--zona-thickness", args->zona_thickness, "Outer shell thickness, with unit");
  cmd->add_option("--nucleus-diameter", args->nucleus_diameter, "Nucleus diameter, with unit");
  cmd->add_option("--out", args->out, "Output file (.msh or .vtu)")->required();
  cmd->add_flag("--json", args->json, "Print the mesh summary as JSON");
  cmd->callback([args] {
    CellMeshSpec spec;
    if (!args->scene.empty()) {
      Result<std::string> path = find_scene_file(args->scene);
      if (!path.ok()) return fail(path.error().message);
      Result<Scene> scene = load_scene(*path, args->sets);
      if (!scene.ok()) return fail(scene.error().message);
      if (scene->mesh.source != MeshSource::kGenerate)
        return fail(*path + ": mesh: the scene reads a mesh file; use 'zona mesh convert'");
      spec = cell_mesh_spec(*scene);
    } else {
      if (args->diameter.empty()) return fail("mesh generate: give --scene or --diameter");
      struct LengthArg {
        const char* name;
        const std::string& text;
        double* target;
      };
      const LengthArg lengths[] = {{"--diameter", args->diameter, &spec.diameter},
                                   {"--edge-length", args->edge_length, &spec.edge_length},
                                   {"--refine-edge-length", args->refine_edge_length,
                                    &spec.refine_edge_length},
                                   {"--refine-radius", args->refine_radius, &spec.refine_radius},
                                   {"--zona-thickness", args->zona_thickness, &spec.zona_thickness},
                                   {"--nucleus-diameter", args->nucleus_diameter,
                                    &spec.nucleus_diameter}};
      for (const LengthArg& a : lengths) {
        if (a.text.empty()) continue;
        Result<double> v = parse_quantity(a.text, dim::kLength);
        if (!v.ok()) return fail(std::string(a.name) + ": " + v.error().message);
        *a.target = *v;
      }
      if (!args->refine_at.empty()) {
        Result<Vec3d> p = parse_point(args->refine_at);
        if (!p.ok()) return fail(p.error().message);
        spec.refine_at = *p;
        // A point alone asks for refinement: pick the usual seed-like ratios when unset.
        if (spec.refine_edge_length <= 0 && args->vertices > 0) {
          spec.edge_length = spec.diameter / 8.0;
          spec.refine_edge_length = spec.diameter / 40.0;
          spec.refine_radius = spec.diameter / 5.0;
        }
      }
      if (args->vertices <= 0 && spec.edge_length <= 0)
        return fail("mesh generate: give --vertices or --edge-length");
    }
    if (args->vertices > 0) spec.target_vertices = args->vertices;
    const auto t0 = std::chrono::steady_clock::now();
    CellMeshReport report;
    Result<Mesh> mesh = generate_cell_mesh(spec, &report);
    if (!mesh.ok()) return fail(mesh.error().message);
    const double seconds =
        std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    const Status written = write_mesh(args->out, *mesh);
    if (!written.ok()) return fail(written.error().message);
    nlohmann::json j = mesh_summary(*mesh);
    j["generate_s"] = seconds;
    j["out"] = args->out;
    if (args->json)
      std::printf("%s\n", j.dump(2).c_str());
    else {
      print_summary_text(args->out, j);
      std::printf("  generated in        %.3f s\n", seconds);
    }
  });
}

void add_convert(CLI::App& group) {
  struct Args {
    std::string in, out;
    std::string unit = "m";
  };
  auto args = std::make_shared<Args>();
  auto* cmd = group.add_subcommand("convert", "Convert a mesh file (.msh, .node, .vtu -> .msh, .vtu)");
  cmd->add_option("IN", args->in, "Input mesh (.msh, .node, .vtu)")->required();
  cmd->add_option("OUT", args->out, "Output mesh (.msh written as Gmsh 4.1, .vtu)")->required();
  cmd->add_option("--unit", args->unit, "Length unit of the input's coordinates (output is m)")
      ->capture_default_str();
  cmd->callback([args] {
    Result<double> scale = unit_scale(args->unit);
    if (!scale.ok()) return fail("--unit: " + scale.error().message);
    ReadMeshOptions options;
    options.scale = *scale;
    std::vector<std::string> warnings;
    Result<Mesh> mesh = read_mesh(args->in, options, &warnings);
    if (!mesh.ok()) return fail(mesh.error().message);
    print_warnings(warnings);
    const Status written = write_mesh(args->out, *mesh);
    if (!written.ok()) return fail(written.error().message);
    std::printf("%s: %zu vertices, %zu tetrahedra\n", args->out.c_str(), mesh->vertex_count(),
                mesh->tet_count());
  });
}

}  // namespace

void add_mesh_commands(CLI::App& app) {
  auto* mesh = app.add_subcommand("mesh", "Inspect, generate and convert tetrahedral meshes");
  // Its subcommand is required: main() lists them when it is missing.
  mesh->require_subcommand(0, 1);
  add_info(*mesh);
  add_generate(*mesh);
  add_convert(*mesh);
}

}  // namespace zona::cli
