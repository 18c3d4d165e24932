// Local quality repair for the cell mesh generator: moves the free vertices of the worst
// elements to raise their smallest dihedral angle.
//
// Stuffing bounds the angles (about 10.7 degrees on the uniform lattice, in theory and here in
// practice); interface cuts and octree transitions add a few elements near that bound. A
// handful of pattern-search moves on the vertices of those elements lifts them clear of it.
// A vertex on the cell surface or on a conforming interface only slides along that ellipsoid
// (moved in its tangent plane, then scaled back onto it), so the boundary stays on the
// ellipsoid and interfaces stay conforming. A move that lowers the worst element around the
// vertex is never accepted, so the repair cannot make the mesh worse.
#include <algorithm>
#include <cmath>
#include <limits>

#include "engine/mesh/mesh_generate_internal.h"

namespace zona::mesh_gen {

namespace {

constexpr double kOnSurface = 1e-9;  // |ellipsoid value| below this: the vertex is on it

// Worst dihedral sine of the tetrahedra in `incident` with vertex v moved to x.
double worst_around(const WorkMesh& m, const int32_t* incident, int count, int32_t v, Vec3d x) {
  double worst = 1.0;
  for (int i = 0; i < count; ++i) {
    const Tet& t = m.tets[incident[i]];
    Vec3d q[4];
    for (int k = 0; k < 4; ++k) q[k] = t[k] == v ? x : m.positions[t[k]];
    worst = std::min(worst, tet_min_sine(q[0], q[1], q[2], q[3]));
  }
  return worst;
}

}  // namespace

int64_t smooth_worst_tets(WorkMesh& m, const std::vector<Ellipsoid>& surfaces,
                          double target_sine, int sweeps) {
  std::vector<Vec3d>& p = m.positions;
  const size_t n = p.size();
  int64_t moved = 0;
  std::vector<int32_t> slot(n, -1);
  // Only elements that were cut, touch a surface or lost a vertex to a move can be below the
  // target (untouched lattice elements have 35 degrees or more): flag their vertices so the
  // scan skips the bulk of the mesh.
  std::vector<uint8_t> touched(n, 0);
  for (size_t v = 0; v < n; ++v)
    for (const Ellipsoid& s : surfaces)
      if (std::abs(s.value(p[v])) <= kOnSurface) touched[v] = 1;
  for (int sweep = 0; sweep < sweeps; ++sweep) {
    // The vertices of the elements below the target, in index order.
    std::vector<int32_t> vertices;
    for (size_t ti = 0; ti < m.tets.size(); ++ti) {
      const Tet& t = m.tets[ti];
      if (m.pristine[ti] && !(touched[t[0]] | touched[t[1]] | touched[t[2]] | touched[t[3]]))
        continue;
      if (tet_min_sine(p[t[0]], p[t[1]], p[t[2]], p[t[3]]) >= target_sine) continue;
      for (int k = 0; k < 4; ++k) {
        if (slot[t[k]] >= 0) continue;
        slot[t[k]] = 0;
        vertices.push_back(t[k]);
      }
    }
    if (vertices.empty()) break;
    std::sort(vertices.begin(), vertices.end());
    for (size_t i = 0; i < vertices.size(); ++i) slot[vertices[i]] = static_cast<int32_t>(i);

    // Their tetrahedra, as compressed lists.
    std::vector<int32_t> offset(vertices.size() + 1, 0);
    for (const Tet& t : m.tets)
      for (int k = 0; k < 4; ++k)
        if (slot[t[k]] >= 0) ++offset[slot[t[k]] + 1];
    for (size_t i = 0; i < vertices.size(); ++i) offset[i + 1] += offset[i];
    std::vector<int32_t> incident(static_cast<size_t>(offset.back()));
    std::vector<int32_t> fill(offset.begin(), offset.end() - 1);
    for (size_t ti = 0; ti < m.tets.size(); ++ti)
      for (int k = 0; k < 4; ++k)
        if (slot[m.tets[ti][k]] >= 0) incident[fill[slot[m.tets[ti][k]]]++] = static_cast<int32_t>(ti);

    // Pattern search per vertex: the six axis directions at a shrinking step.
    for (size_t i = 0; i < vertices.size(); ++i) {
      const int32_t v = vertices[i];
      const int32_t* inc = incident.data() + offset[i];
      const int count = offset[i + 1] - offset[i];
      double shortest = std::numeric_limits<double>::infinity();
      for (int j = 0; j < count; ++j) {
        const Tet& t = m.tets[inc[j]];
        for (int k = 0; k < 4; ++k)
          if (t[k] != v) shortest = std::min(shortest, norm(p[t[k]] - p[v]));
      }
      // Search directions: the three axes for a free vertex, two tangents for a surface one.
      const Ellipsoid* surface = nullptr;
      for (const Ellipsoid& s : surfaces)
        if (std::abs(s.value(p[v])) <= kOnSurface) surface = &s;
      Vec3d dirs[3] = {{1, 0, 0}, {0, 1, 0}, {0, 0, 1}};
      int dir_count = 3;
      if (surface) {
        const Vec3d r = surface->semi_axes;
        const Vec3d normal{p[v].x / (r.x * r.x), p[v].y / (r.y * r.y), p[v].z / (r.z * r.z)};
        const Vec3d nu = normal / norm(normal);
        // Any axis not parallel to the normal gives the first tangent.
        const Vec3d axis = std::abs(nu.x) < 0.6 ? Vec3d{1, 0, 0} : Vec3d{0, 1, 0};
        Vec3d t1 = cross(nu, axis);
        t1 = t1 / norm(t1);
        dirs[0] = t1;
        dirs[1] = cross(nu, t1);
        dir_count = 2;
      }
      auto place = [&](Vec3d y) {
        if (!surface) return y;
        // Scale along the ray from the centre onto the ellipsoid (exact for a quadric).
        return y / std::sqrt(surface->value(y) + 1.0);
      };
      Vec3d x = p[v];
      double best = worst_around(m, inc, count, v, x);
      double step = 0.25 * shortest;
      for (int halving = 0; halving < 6 && best < target_sine; ++halving, step *= 0.5) {
        bool improved = true;
        for (int tries = 0; tries < 8 && improved && best < target_sine; ++tries) {
          improved = false;
          for (int d = 0; d < dir_count; ++d)
            for (int sign = -1; sign <= 1; sign += 2) {
              const Vec3d y = place(x + (sign * step) * dirs[d]);
              const double q = worst_around(m, inc, count, v, y);
              if (q > best) {
                best = q;
                x = y;
                improved = true;
              }
            }
        }
      }
      if (x.x != p[v].x || x.y != p[v].y || x.z != p[v].z) {
        p[v] = x;
        touched[v] = 1;
        ++moved;
      }
    }
    for (int32_t v : vertices) slot[v] = -1;
  }
  return moved;
}

}  // namespace zona::mesh_gen
