// Internals of the cell mesh generator shared by mesh_generate.cpp, mesh_lattice.cpp and
// mesh_stuffing.cpp: the layer surfaces, a flat hash map, the working mesh and the passes.
// Not part of the public API (tests may use it to check the passes one by one).
#pragma once

#include <cstdint>
#include <vector>

#include "engine/core/base.h"
#include "engine/mesh/mesh.h"
#include "engine/core/vec.h"

namespace zona::mesh_gen {

/// An axis-aligned ellipsoid centred at the origin: the cell surface and its layer interfaces.
struct Ellipsoid {
  Vec3d semi_axes{1, 1, 1};  ///< [m]

  /// (x/a)^2 + (y/b)^2 + (z/c)^2 - 1: negative inside, zero on the surface, positive outside.
  double value(Vec3d p) const {
    const double x = p.x / semi_axes.x, y = p.y / semi_axes.y, z = p.z / semi_axes.z;
    return x * x + y * y + z * z - 1.0;
  }
  /// Where segment inside -> outside crosses the surface, as the fraction t in [0, 1] from
  /// `inside` (value(inside) < 0 < value(outside)). Exact up to rounding: the surface is a
  /// quadric, so the crossing is a root of a quadratic in t.
  double crossing(Vec3d inside, Vec3d outside) const;
  /// Smallest semi-axis [m].
  double min_semi_axis() const;
};

/// Open-addressing hash map from 64-bit keys to int32 values (lattice coordinates or edges to
/// vertex indices). Only used for look-up, never iterated, so it cannot make output order
/// depend on hashing.
class IndexMap {
 public:
  explicit IndexMap(size_t expected_size = 16);
  /// The value stored for `key`, or -1.
  int32_t find(uint64_t key) const;
  /// The value stored for `key`; stores `value` first when the key is new (`*inserted` = true).
  int32_t find_or_insert(uint64_t key, int32_t value, bool* inserted);
  size_t size() const { return size_; }

 private:
  void grow();
  std::vector<uint64_t> keys_;
  std::vector<int32_t> values_;
  size_t mask_ = 0;
  size_t size_ = 0;
};

/// Key of the undirected edge (a, b).
inline uint64_t edge_key(int32_t a, int32_t b) {
  const uint32_t lo = static_cast<uint32_t>(a < b ? a : b);
  const uint32_t hi = static_cast<uint32_t>(a < b ? b : a);
  return (static_cast<uint64_t>(lo) << 32) | hi;
}

/// How the background lattice is graded.
struct LatticeSpec {
  Vec3d semi_axes{1, 1, 1};    ///< ellipsoid to cover; cells far outside it get no tetrahedra [m]
  double coarse_size = 0;      ///< root cell size (the BCC black edge length) [m]
  int max_level = 0;           ///< octree depth: the finest cells are coarse_size / 2^max_level
  double fine_size = 0;        ///< wanted cell size within refine_radius of refine_center [m]
  Vec3d refine_center{0, 0, 0};  ///< [m]
  double refine_radius = 0;    ///< [m]
  double grading = 0.5;        ///< growth of the wanted size per unit distance beyond the radius
  double z_offset = 0;         ///< lattice shift along z, fraction of a root cell in [0, 1)
};

/// Background tetrahedra: body-centred cubic tetrahedra of a 2:1-balanced octree, positively
/// oriented, covering at least the ellipsoid.
struct Lattice {
  std::vector<Vec3d> positions;  ///< [m], (vertex_count)
  std::vector<Tet> tets;         ///< (tet_count)
  int64_t leaf_count = 0;
};

/// Builds the background lattice. Errors when the octree would not fit its integer keys.
Result<Lattice> build_lattice(const LatticeSpec& spec);

/// The mesh between passes.
struct WorkMesh {
  std::vector<Vec3d> positions;  ///< [m], (vertex_count)
  std::vector<Tet> tets;         ///< positively oriented, (tet_count)
  std::vector<int32_t> region;   ///< region tag, (tet_count)
  std::vector<uint8_t> pristine; ///< 1: an untouched lattice tetrahedron, (tet_count)
};

/// Counters of one cutting pass.
struct CutStats {
  int64_t warped_vertices = 0;  ///< vertices snapped onto the surface
  int64_t cut_vertices = 0;     ///< new vertices on lattice edges
  int64_t steiner_vertices = 0; ///< new vertices inside cut tetrahedra (rare)
  int64_t cut_tets = 0;         ///< tetrahedra decomposed along the surface
  int64_t centroid_tets = 0;    ///< tetrahedra crossing the surface that were tagged by centroid
};

/// Isosurface stuffing: keeps the part of the lattice inside `surface`. Lattice vertices close
/// to the surface are snapped onto it, the remaining crossings become cut vertices, and each
/// crossing tetrahedron is split along the surface. All kept tetrahedra get `region`.
/// Fails only on an internal inconsistency (a polytope that cannot be tetrahedralized).
Result<WorkMesh> stuff_inside(Lattice lattice, const Ellipsoid& surface, int32_t region,
                              CutStats* stats = nullptr);

/// Cuts the mesh along an internal interface where it is resolved: tetrahedra that are still
/// lattice tetrahedra with edges no longer than `max_edge` are split so that the interface is
/// made of mesh faces; elsewhere tetrahedra are tagged by their centroid. Tetrahedra inside get
/// `inside_region`, outside `outside_region` (-1: keep the tag they have).
Result<CutStats> cut_interface(WorkMesh& mesh, const Ellipsoid& surface, double max_edge,
                               int32_t inside_region, int32_t outside_region);

/// Moves vertices that lie on none of `surfaces` to raise the smallest dihedral sine of the
/// elements below `target_sine` (pattern search, never lowering the worst element around a
/// vertex). Returns the number of vertices moved.
int64_t smooth_worst_tets(WorkMesh& mesh, const std::vector<Ellipsoid>& surfaces,
                          double target_sine, int sweeps);

/// Drops vertices no tetrahedron uses, keeping the order of the others.
void remove_unreferenced(WorkMesh& mesh);

/// Smallest sine of the six dihedral angles; <= 0 for flat or inverted tetrahedra. A cheap
/// shape measure (no acos) that penalises both small and nearly flat (near 180 deg) angles.
double tet_min_sine(Vec3d a, Vec3d b, Vec3d c, Vec3d d);

}  // namespace zona::mesh_gen
