// Tetrahedral mesh: rest geometry, connectivity, regions, boundary surface, adjacency, quality.
#pragma once

#include <array>
#include <cstdint>
#include <string>
#include <vector>

#include "engine/core/base.h"
#include "engine/core/vec.h"

namespace zona {

/// Region tags used by the cell generator and the scenes. Meshes from files keep their own
/// physical tags; names for them come from the file (Gmsh $PhysicalNames) when present.
enum RegionTag : int32_t {
  kRegionNone = 0,
  kRegionCytoplasm = 1,
  kRegionZona = 2,  ///< zona pellucida / chorion / membrane shell
  kRegionNucleus = 3,
};

/// A named region: the tag stored per tetrahedron and its human name ("zona", "cytoplasm").
struct Region {
  int32_t tag = 0;
  std::string name;
};

/// Four vertex indices. Positive orientation: dot(p1-p0, cross(p2-p0, p3-p0)) > 0.
using Tet = std::array<int32_t, 4>;
/// Three vertex indices, counter-clockwise seen from outside (normal points out of the mesh).
using Triangle = std::array<int32_t, 3>;

/// A tetrahedral mesh. Plain data: readers and the generator fill it, validate_mesh() checks it.
struct Mesh {
  std::vector<Vec3d> rest_positions;  ///< rest positions [m], (vertex_count)
  std::vector<Tet> tets;              ///< vertex indices, (tet_count)
  std::vector<int32_t> tet_region;    ///< region tag per tetrahedron, (tet_count)
  std::vector<Region> regions;        ///< names of the tags that have one

  size_t vertex_count() const { return rest_positions.size(); }
  size_t tet_count() const { return tets.size(); }
  /// Name of a region tag: the file's or generator's name, else the tag as text.
  std::string region_name(int32_t tag) const;
};

/// Signed volume of tetrahedron (a, b, c, d) [m^3]: positive for positive orientation.
ZONA_HOST_DEVICE ZONA_INLINE double tet_signed_volume(Vec3d a, Vec3d b, Vec3d c, Vec3d d) {
  return dot(b - a, cross(c - a, d - a)) / 6.0;
}

/// Signed rest volume of tetrahedron t [m^3].
double tet_rest_volume(const Mesh& mesh, size_t t);

/// What validate_mesh does with inverted (negative-volume) tetrahedra.
enum class InvertedPolicy {
  kRepair,  ///< swap two vertices and add a warning (default: many exporters mix orientations)
  kReject,  ///< report the first inverted element as an error
};

/// Options for validate_mesh.
struct ValidateOptions {
  InvertedPolicy inverted = InvertedPolicy::kRepair;
  /// Elements with |volume| <= relative_min_volume * (mean |volume|) are degenerate.
  double relative_min_volume = 1e-12;
  /// Unreferenced vertices: an error when true, otherwise a warning.
  bool reject_unreferenced = false;
};

/// Checks a mesh and repairs what is safe to repair. Errors name `source` and the element or
/// vertex index: non-finite coordinates, out-of-range or repeated indices, zero-volume
/// elements, a region array of the wrong length, an empty mesh. Warnings (repaired inversions,
/// unreferenced vertices) are appended to `warnings` when given.
Status validate_mesh(Mesh& mesh, const std::string& source, const ValidateOptions& options = {},
                     std::vector<std::string>* warnings = nullptr);

/// Boundary surface: the faces that belong to one tetrahedron only, oriented outward.
struct BoundarySurface {
  std::vector<Triangle> triangles;     ///< outward counter-clockwise, (triangle_count)
  std::vector<int32_t> triangle_tet;   ///< the tetrahedron each triangle bounds, (triangle_count)
  std::vector<int32_t> vertices;       ///< boundary vertex indices, sorted, unique
};

/// Extracts the boundary surface. Deterministic: triangles come in order of (tet, local face).
/// The mesh must index its vertices in range (validate_mesh).
BoundarySurface extract_boundary(const Mesh& mesh);

/// Compressed vertex-to-tetrahedron adjacency: the tetrahedra around vertex v are
/// tets[offsets[v] .. offsets[v+1]), with the vertex's local corner (0..3) in `corner`.
struct VertexTetAdjacency {
  std::vector<int32_t> offsets;  ///< (vertex_count + 1)
  std::vector<int32_t> tets;     ///< tetrahedron indices, ascending per vertex, (4 tet_count)
  std::vector<int8_t> corner;    ///< local index of the vertex in that tetrahedron, (4 tet_count)
};

/// Builds the vertex-to-tetrahedron adjacency in O(vertices + tets).
VertexTetAdjacency build_vertex_tet_adjacency(const Mesh& mesh);

/// Quality of one tetrahedron.
struct TetQuality {
  double volume = 0;           ///< signed volume [m^3]
  double min_dihedral_deg = 0; ///< smallest of the six dihedral angles [deg]
  double max_dihedral_deg = 0; ///< largest of the six dihedral angles [deg]
  double aspect_ratio = 0;     ///< longest edge / (2 sqrt(6) inradius); 1 for a regular tet
  double min_edge = 0;         ///< shortest edge [m]
  double max_edge = 0;         ///< longest edge [m]
};

/// Quality of tetrahedron (a, b, c, d).
TetQuality tet_quality(Vec3d a, Vec3d b, Vec3d c, Vec3d d);

/// Whole-mesh quality summary.
struct MeshQuality {
  double volume = 0;            ///< total |volume| [m^3]
  double min_volume = 0;        ///< smallest signed element volume [m^3]
  double min_dihedral_deg = 0;
  double max_dihedral_deg = 0;
  double max_aspect_ratio = 0;
  double mean_aspect_ratio = 0;
  double min_edge = 0;          ///< shortest edge in the mesh [m]
  double max_edge = 0;          ///< longest edge in the mesh [m]
  double min_altitude = 0;      ///< smallest vertex-to-opposite-face height [m] (for stable dt)
  int64_t worst_dihedral_tet = -1;  ///< index of the element with the smallest dihedral angle
};

/// Computes the quality summary over all tetrahedra.
MeshQuality mesh_quality(const Mesh& mesh);

/// Bounding box of the rest positions.
struct Aabb {
  Vec3d lo{0, 0, 0};
  Vec3d hi{0, 0, 0};
};
Aabb mesh_bounds(const Mesh& mesh);

/// Cells are between about 1 um (a bacterium) and 1 cm (the largest eggs) across; a mesh whose
/// largest extent lies outside [kCellExtentMin, kCellExtentMax] was almost certainly read in
/// the wrong length unit (micrometre coordinates read as metres give a 56 m cell).
inline constexpr double kCellExtentMin = 1e-7;  ///< 0.1 um [m]
inline constexpr double kCellExtentMax = 1e-2;  ///< 1 cm [m]

/// One sentence naming the likely unit mistake when the mesh's largest extent lies outside the
/// range above ("the mesh is 56 m across: ... read as metres"); "" when the size is plausible.
std::string mesh_unit_hint(const Mesh& mesh);

}  // namespace zona
