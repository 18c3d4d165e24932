// The boundary surface the tools touch (built once, with its adjacency), and Ladjal et al.'s
// ray-triangle intersection with a local search from the last hit triangle: where the needle's
// axis enters the cell (the deformation measure's entry point). The tools' contact itself is the
// penalty law on their distance fields (engine/tools/penalty.h, engine/sim/job.h).
#pragma once

#include <array>
#include <cstdint>
#include <span>
#include <vector>

#include "engine/tools/holding.h"
#include "engine/mesh/mesh.h"
#include "engine/fem/model.h"
#include "engine/tools/needle.h"
#include "engine/core/vec.h"

namespace zona {

/// The boundary surface with what contact queries need, built once from the rest mesh.
struct ContactSurface {
  std::vector<Triangle> triangles;        ///< outward counter-clockwise, (triangle_count)
  /// Triangle across edge e (corners e, e+1 mod 3) of each triangle, -1 on an open edge.
  std::vector<std::array<int32_t, 3>> triangle_neighbors;
  std::vector<int32_t> vertices;          ///< mesh indices of surface vertices, sorted
  std::vector<int32_t> surface_index;     ///< mesh vertex -> index in `vertices`, -1 if inside
  std::vector<int32_t> neighbor_offsets;  ///< surface vertex graph (CSR), (surface count + 1)
  std::vector<int32_t> neighbors;         ///< surface indices of edge neighbours
  std::vector<double> vertex_area;        ///< rest tributary area, a third of each incident
                                          ///< triangle [m^2], (surface count)
  double max_edge = 0;                    ///< longest surface edge at rest [m]
  double area = 0;                        ///< total rest surface area [m^2]
};

/// Builds the contact surface of a mesh (extract_boundary plus adjacency and areas).
/// Errors: an empty boundary, or an edge shared by more than two triangles.
Result<ContactSurface> build_contact_surface(const Mesh& mesh);

/// Ray-triangle intersection (Moller-Trumbore): the ray origin + t dir meets the triangle
/// (a, b, c) at t with barycentric weights (1 - b1 - b2, b1, b2). Returns false when the ray is
/// parallel to the triangle's plane. The weights are written even when they lie outside [0, 1]
/// (the local search uses them to choose where to walk).
bool ray_triangle(Vec3d origin, Vec3d dir, Vec3d a, Vec3d b, Vec3d c, double* t, double* b1,
                  double* b2);

/// A ray's first hit on the surface.
struct RayHit {
  int32_t triangle = -1;   ///< hit triangle, -1: no hit
  double t = 0;            ///< ray parameter [m] (dir is unit)
  Vec3d point{0, 0, 0};    ///< hit point [m]
  int walk_steps = 0;      ///< triangles visited by the local search
  bool global_scan = false;  ///< the local search failed and every triangle was tested
};

/// Casts the ray origin + t dir (dir unit, t > 0) against the deformed surface (positions
/// rest + u) and returns its first hit on a triangle facing the ray. Ladjal et al.'s method: walk
/// from `start_triangle` (the last hit) across the edge with the most negative barycentric
/// weight until the containing triangle is found (at most `max_walk` steps); if that fails (no
/// start, a silhouette, a fold), test every triangle and keep the nearest hit. Never allocates.
RayHit cast_ray(const ContactSurface& surface, std::span<const Vec3d> rest,
                std::span<const Vec3d> u, Vec3d origin, Vec3d dir, int32_t start_triangle,
                int max_walk = 256);

}  // namespace zona
