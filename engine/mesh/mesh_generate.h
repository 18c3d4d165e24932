// Cell mesh generator: tetrahedral meshes of a ball or ellipsoid with optional concentric layers
// (zona pellucida / chorion shell, nucleus), uniform at a target vertex count or graded around
// a puncture point; plus a structured box mesh for tests.
//
// Method (details and measurements in docs/mesh_generation.md): a body-centred cubic lattice on
// a 2:1-balanced octree (graded towards the puncture point) is cut to the cell surface by
// isosurface stuffing (Labelle and Shewchuk 2007: vertices near the surface are snapped onto it,
// the rest of the crossing tetrahedra are split along it), then the internal layer interfaces
// are cut the same way wherever the lattice resolves them, and the few worst elements are
// repaired by moving vertices. Chosen over TetGen on measurement: on the same 56 um ball TetGen
// 1.5 (-pq1.4/10) took 18 s for 195k vertices and still left 2 degree slivers; this takes
// 1.6 s for 1 million vertices with every dihedral angle above 14 degrees, is deterministic,
// and adds no library that the GPU machine's copied build folder would have to carry.
#pragma once

#include <cstdint>
#include <optional>

#include "engine/core/base.h"
#include "engine/mesh/mesh.h"
#include "engine/core/vec.h"

namespace zona {

/// Fewest vertices the generator may be asked for (CellMeshSpec::target_vertices).
inline constexpr int64_t kMinCellMeshVertices = 8;
/// Most vertices the generator will build.
inline constexpr int64_t kMaxCellMeshVertices = 400'000'000;

/// What to mesh and how finely. Defaults: a 56 um mouse-oocyte-like ball (set a resolution).
///
/// Resolution, one of:
///  - `target_vertices` > 0 alone: a uniform mesh with about that many vertices (+-10 %; a
///    uniform edge_length given with it is ignored);
///  - `edge_length` > 0 alone: a uniform mesh with that lattice edge length;
///  - `edge_length`, `refine_edge_length` and `refine_at`: graded, fine at the puncture point;
///  - all of the above with `target_vertices` > 0: the graded mesh scaled as a whole (the three
///    lengths keep their ratios) to reach the vertex count.
/// The coarse edge length of a graded mesh is rounded to refine_edge_length times a power of
/// two (the octree's levels), so refine_edge_length holds exactly at the puncture point.
///
/// Layers: the zona shell is the region between the cell surface and the same ellipsoid shrunk
/// by `zona_thickness` on each semi-axis; the nucleus is a concentric ball. An interface is made
/// of mesh faces (conforming) where the lattice edges are at most 0.75 times the layer gap (the
/// shell thickness, or the distance to the next interface), i.e. near the puncture point of a
/// graded mesh or everywhere in a fine uniform one; elsewhere elements are tagged by their
/// centroid, so a shell thinner than the local elements is represented only on average.
struct CellMeshSpec {
  double diameter = 56e-6;          ///< cell diameter [m]
  Vec3d radii_scale{1, 1, 1};       ///< ellipsoid: semi-axes = diameter / 2 * radii_scale
  double zona_thickness = 0;        ///< > 0: outer shell region kRegionZona [m]
  double nucleus_diameter = 0;      ///< > 0: concentric region kRegionNucleus [m]
  int64_t target_vertices = 0;      ///< > 0: about this many vertices (+-10 %)
  double edge_length = 0;           ///< coarse lattice edge length, far from refine_at [m]
  double refine_edge_length = 0;    ///< fine lattice edge length at refine_at [m] (0: uniform)
  std::optional<Vec3d> refine_at;   ///< puncture point, usually on the surface [m]
  double refine_radius = 0;         ///< the fine size holds within this distance of refine_at [m]
  double grading = 0.5;             ///< growth of the edge length per unit distance beyond it
  /// Shift of the lattice along z as a fraction of a coarse cell, in [0, 1). The z axis stays a
  /// lattice line (so the poles are always mesh vertices); the vertex-count search varies it to
  /// break the lattice's symmetry, whose groups of up to 48 vertices make small counts jump.
  double lattice_shift = 0;
};

/// What the generator did (for reports and the CLI).
struct CellMeshReport {
  double edge_length = 0;           ///< coarse lattice edge length used [m]
  double refine_edge_length = 0;    ///< fine lattice edge length used [m] (0: uniform)
  int octree_levels = 0;            ///< refinement levels below the coarse cells
  int64_t lattice_vertices = 0;     ///< background lattice size before cutting
  int64_t lattice_tets = 0;
  int64_t warped_vertices = 0;      ///< lattice vertices snapped onto a surface (all passes)
  int64_t cut_vertices = 0;         ///< vertices created on lattice edges (all passes)
  int64_t steiner_vertices = 0;     ///< vertices created inside tetrahedra (rare)
  int64_t centroid_tagged_tets = 0; ///< elements crossing an unresolved interface
  int64_t smoothed_vertices = 0;    ///< free vertices moved by the final quality repair
  double lattice_shift = 0;         ///< lattice shift used (see CellMeshSpec)
  int attempts = 1;                 ///< meshes generated to reach target_vertices
};

/// Generates a cell mesh. Deterministic: the same spec gives the same bits on every run.
/// Tetrahedra are positively oriented, tagged kRegionCytoplasm / kRegionZona / kRegionNucleus
/// (names in Mesh::regions), and every vertex is used. Errors name the offending field.
Result<Mesh> generate_cell_mesh(const CellMeshSpec& spec, CellMeshReport* report = nullptr);

/// Ladjal et al.'s Table II meshes (115 to 1093 vertices): a 56 um ball refined at its
/// north pole (0, 0, r) where the needle enters, with about `vertices` vertices (+-10 % for 100
/// to 1e7 vertices). The spec uses target_vertices, so generate_cell_mesh does the search.
CellMeshSpec table2_spec(int64_t vertices);

/// A structured box [lo, hi] of nx x ny x nz cubes, each split into 6 tetrahedra around its
/// main diagonal (the same split in every cube, so faces match). Vertex (i, j, k) has index
/// i + (nx + 1) (j + (ny + 1) k). All tetrahedra kRegionCytoplasm. For patch and stretch tests.
/// Precondition (asserted): nx, ny, nz >= 1 and lo < hi on every axis.
Mesh generate_box_mesh(Vec3d lo, Vec3d hi, int nx, int ny, int nz);

}  // namespace zona
