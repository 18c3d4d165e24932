// Scene -> mesh: file reading or generation, and the needle's entry point on the cell surface.
#include "engine/scene/scene_mesh.h"

#include <cstdio>

#include <cmath>

#include "engine/mesh/mesh_io.h"

namespace zona {

Vec3d needle_entry_point(const Scene& scene) {
  const MeshGenerateDef& g = scene.mesh.generate;
  const double r = 0.5 * g.diameter;
  const Vec3d axes{r * g.radii_scale.x, r * g.radii_scale.y, r * g.radii_scale.z};
  const Vec3d d = scene.needle.direction / norm(scene.needle.direction);
  // Work in coordinates where the ellipsoid is the unit sphere: x' = x / axes.
  auto to_unit = [&](Vec3d v) { return Vec3d{v.x / axes.x, v.y / axes.y, v.z / axes.z}; };
  const Vec3d p = scene.needle.start ? *scene.needle.start : -2.0 * norm(axes) * d;
  const Vec3d pu = to_unit(p), du = to_unit(d);
  // Ray pu + s du against |x'| = 1: a s^2 + 2 b s + c = 0, first root.
  const double a = dot(du, du), b = dot(pu, du), c = dot(pu, pu) - 1.0;
  const double disc = b * b - a * c;
  if (disc < 0) {
    // The needle misses the cell: the surface point facing it along -d.
    const Vec3d q = to_unit(-1.0 * d);
    return -1.0 * d / norm(q);
  }
  const double s = (-b - std::sqrt(disc)) / a;
  return p + s * d;
}

CellMeshSpec cell_mesh_spec(const Scene& scene) {
  const MeshGenerateDef& g = scene.mesh.generate;
  CellMeshSpec spec;
  spec.diameter = g.diameter;
  spec.radii_scale = g.radii_scale;
  spec.zona_thickness = g.zona_thickness;
  spec.nucleus_diameter = g.nucleus_diameter;
  spec.target_vertices = g.target_vertices;
  spec.edge_length = g.edge_length;
  spec.refine_edge_length = g.refine_edge_length;
  spec.refine_radius = g.refine_radius;
  // The loader has already resolved "refine_at": "needle" (ellipsoid-aware) into refine_at.
  if (g.refine_edge_length > 0) spec.refine_at = g.refine_at;
  return spec;
}

Result<Mesh> build_scene_mesh(const Scene& scene, std::vector<std::string>* warnings) {
  if (scene.mesh.source == MeshSource::kFile) {
    ReadMeshOptions options;
    options.scale = scene.mesh.file_unit;
    Result<Mesh> mesh = read_mesh(scene.mesh.file, options, warnings);
    if (!mesh.ok()) return mesh;
    // A wrong unit makes a 56 m cell that fails later with an unrelated tool error: say it here.
    if (const std::string hint = mesh_unit_hint(*mesh); !hint.empty()) {
      char unit[64];
      std::snprintf(unit, sizeof unit, "%.6g m", scene.mesh.file_unit);
      return Error{(scene.source.empty() ? scene.name : scene.source) + ": mesh.unit: " +
                   scene.mesh.file + " read with one file unit = " + unit + ": " + hint};
    }
    return mesh;
  }
  Result<Mesh> mesh = generate_cell_mesh(cell_mesh_spec(scene));
  if (!mesh.ok())
    return Error{(scene.source.empty() ? scene.name : scene.source) + ": mesh.generate: " +
                 mesh.error().message};
  return mesh;
}

}  // namespace zona
