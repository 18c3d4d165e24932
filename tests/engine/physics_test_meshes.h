// Small meshes for the physics tests: one tetrahedron, and a box of cubes each split into six
// tetrahedra (Kuhn split along the main diagonal, conforming across cells).
#pragma once

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <vector>

#include "engine/mesh/mesh.h"
#include "engine/core/vec.h"

namespace zona::testing {

/// One positively oriented, deliberately irregular tetrahedron of size ~`scale` [m].
inline Mesh single_tet_mesh(double scale = 1e-6) {
  Mesh mesh;
  mesh.rest_positions = {Vec3d{0.1, -0.05, 0.02} * scale, Vec3d{1.05, 0.1, -0.03} * scale,
                         Vec3d{0.2, 0.9, 0.1} * scale, Vec3d{0.15, 0.2, 1.1} * scale};
  mesh.tets = {Tet{0, 1, 2, 3}};
  mesh.tet_region = {0};
  return mesh;
}

/// A box [lo, hi] of nx x ny x nz cubes, six tetrahedra each, all positively oriented.
/// Vertex (i, j, k) has index i + (nx + 1) (j + (ny + 1) k).
inline Mesh box_mesh(Vec3d lo, Vec3d hi, int nx, int ny, int nz) {
  Mesh mesh;
  auto index = [&](int i, int j, int k) { return i + (nx + 1) * (j + (ny + 1) * k); };
  for (int k = 0; k <= nz; ++k)
    for (int j = 0; j <= ny; ++j)
      for (int i = 0; i <= nx; ++i)
        mesh.rest_positions.push_back(Vec3d{lo.x + (hi.x - lo.x) * i / nx,
                                            lo.y + (hi.y - lo.y) * j / ny,
                                            lo.z + (hi.z - lo.z) * k / nz});
  std::array<int, 3> perm = {0, 1, 2};
  std::vector<std::array<int, 3>> perms;
  do perms.push_back(perm);
  while (std::next_permutation(perm.begin(), perm.end()));
  for (int k = 0; k < nz; ++k)
    for (int j = 0; j < ny; ++j)
      for (int i = 0; i < nx; ++i)
        for (const auto& p : perms) {
          int c[3] = {i, j, k};
          Tet t;
          t[0] = index(c[0], c[1], c[2]);
          for (int s = 0; s < 3; ++s) {
            ++c[p[s]];
            t[s + 1] = index(c[0], c[1], c[2]);
          }
          const auto& x = mesh.rest_positions;
          if (tet_signed_volume(x[t[0]], x[t[1]], x[t[2]], x[t[3]]) < 0) std::swap(t[2], t[3]);
          mesh.tets.push_back(t);
        }
  mesh.tet_region.assign(mesh.tets.size(), 0);
  return mesh;
}

/// Vertices of a box mesh with coordinate `axis` equal to `value` (to 1e-9 of the box size).
inline std::vector<int32_t> vertices_where(const Mesh& mesh, int axis, double value,
                                           double tolerance) {
  std::vector<int32_t> out;
  for (size_t v = 0; v < mesh.vertex_count(); ++v)
    if (std::abs(mesh.rest_positions[v][axis] - value) <= tolerance)
      out.push_back(static_cast<int32_t>(v));
  return out;
}

}  // namespace zona::testing
