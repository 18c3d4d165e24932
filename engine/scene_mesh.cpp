// Scene -> mesh: file reading or generation, and the needle's entry point on the cell surface.
#include "engine/scene_mesh.h"

#include <cmath>

#include "engine/mesh_io.h"

namespace zona {

Vec3d needle_entry_point(const Scene& scene) {
  const MeshGenerateDef& g = scene.mesh.generate;
  const double r = 0.5 * g.diameter;
  const Vec3d d = scene.needle.direction / norm(scene.needle.direction);
  if (!scene.needle.start) return -r * d;
  // Ray p + s d against the sphere |x| = r: s^2 + 2 (p.d) s + |p|^2 - r^2 = 0, first root.
  const Vec3d p = *scene.needle.start;
  const double b = dot(p, d);
  const double c = dot(p, p) - r * r;
  const double disc = b * b - c;
  if (disc < 0) return -r * d;  // the needle misses the cell: refine where it points
  const double s = -b - std::sqrt(disc);
  return p + s * d;
}

CellMeshSpec cell_mesh_spec(const Scene& scene) {
  const MeshGenerateDef& g = scene.mesh.generate;
  CellMeshSpec spec;
  spec.diameter = g.diameter;
  spec.zona_thickness = g.zona_thickness;
  spec.nucleus_diameter = g.nucleus_diameter;
  spec.target_vertices = g.target_vertices;
  spec.edge_length = g.edge_length;
  spec.refine_edge_length = g.refine_edge_length;
  spec.refine_radius = g.refine_radius;
  if (g.refine_edge_length > 0)
    spec.refine_at = g.refine_at_needle ? needle_entry_point(scene) : g.refine_at;
  return spec;
}

Result<Mesh> build_scene_mesh(const Scene& scene, std::vector<std::string>* warnings) {
  if (scene.mesh.source == MeshSource::kFile) {
    ReadMeshOptions options;
    options.scale = scene.mesh.file_unit;
    return read_mesh(scene.mesh.file, options, warnings);
  }
  Result<Mesh> mesh = generate_cell_mesh(cell_mesh_spec(scene));
  if (!mesh.ok())
    return Error{(scene.source.empty() ? scene.name : scene.source) + ": mesh.generate: " +
                 mesh.error().message};
  return mesh;
}

}  // namespace zona
