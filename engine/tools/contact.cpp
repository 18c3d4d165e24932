// The boundary surface the tools touch and ray casting on it with a local search.
#include "engine/tools/contact.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <map>
#include <utility>

namespace zona {

Result<ContactSurface> build_contact_surface(const Mesh& mesh) {
  ContactSurface s;
  BoundarySurface boundary = extract_boundary(mesh);
  if (boundary.triangles.empty()) return make_error("contact surface: the mesh has no boundary");
  s.triangles = std::move(boundary.triangles);
  s.vertices = std::move(boundary.vertices);
  const size_t nt = s.triangles.size();
  s.surface_index.assign(mesh.vertex_count(), -1);
  for (size_t i = 0; i < s.vertices.size(); ++i)
    s.surface_index[static_cast<size_t>(s.vertices[i])] = static_cast<int32_t>(i);

  // Triangle neighbours across each edge: key (min, max) vertex pair -> first (triangle, edge).
  s.triangle_neighbors.assign(nt, {-1, -1, -1});
  std::map<std::pair<int32_t, int32_t>, std::pair<int32_t, int32_t>> open;
  std::vector<std::pair<int32_t, int32_t>> edges;  // unique surface edges (surface indices)
  for (size_t t = 0; t < nt; ++t)
    for (int e = 0; e < 3; ++e) {
      const int32_t a = s.triangles[t][e], b = s.triangles[t][(e + 1) % 3];
      const auto key = std::minmax(a, b);
      auto it = open.find(key);
      if (it == open.end()) {
        open.emplace(key, std::make_pair(static_cast<int32_t>(t), e));
        edges.emplace_back(s.surface_index[a], s.surface_index[b]);
        continue;
      }
      if (it->second.first < 0)
        return make_error("contact surface: edge (%d, %d) is shared by more than two triangles",
                          a, b);
      const auto [other, other_edge] = it->second;
      s.triangle_neighbors[t][e] = other;
      s.triangle_neighbors[static_cast<size_t>(other)][other_edge] = static_cast<int32_t>(t);
      it->second.first = -1;  // closed
    }

  // Vertex graph (CSR) from the unique edges.
  const size_t ns = s.vertices.size();
  s.neighbor_offsets.assign(ns + 1, 0);
  for (const auto& [a, b] : edges) {
    ++s.neighbor_offsets[static_cast<size_t>(a) + 1];
    ++s.neighbor_offsets[static_cast<size_t>(b) + 1];
  }
  for (size_t i = 0; i < ns; ++i) s.neighbor_offsets[i + 1] += s.neighbor_offsets[i];
  s.neighbors.assign(static_cast<size_t>(s.neighbor_offsets[ns]), -1);
  std::vector<int32_t> fill(s.neighbor_offsets.begin(), s.neighbor_offsets.end() - 1);
  for (const auto& [a, b] : edges) {
    s.neighbors[static_cast<size_t>(fill[static_cast<size_t>(a)]++)] = b;
    s.neighbors[static_cast<size_t>(fill[static_cast<size_t>(b)]++)] = a;
  }
  for (size_t i = 0; i < ns; ++i)
    std::sort(s.neighbors.begin() + s.neighbor_offsets[i],
              s.neighbors.begin() + s.neighbor_offsets[i + 1]);

  // Areas and the longest edge.
  s.vertex_area.assign(ns, 0.0);
  for (const Triangle& tri : s.triangles) {
    const Vec3d a = mesh.rest_positions[tri[0]], b = mesh.rest_positions[tri[1]],
                c = mesh.rest_positions[tri[2]];
    const double area = 0.5 * norm(cross(b - a, c - a));
    s.area += area;
    for (int32_t v : tri) s.vertex_area[static_cast<size_t>(s.surface_index[v])] += area / 3.0;
    s.max_edge = std::max({s.max_edge, norm(b - a), norm(c - b), norm(a - c)});
  }
  return s;
}

bool ray_triangle(Vec3d origin, Vec3d dir, Vec3d a, Vec3d b, Vec3d c, double* t, double* b1,
                  double* b2) {
  const Vec3d e1 = b - a, e2 = c - a;
  const Vec3d p = cross(dir, e2);
  const double det = dot(e1, p);
  // Relative test: det is |e1||e2| sin(angle) times the ray's cosine with the plane.
  const double scale = norm(e1) * norm(e2);
  if (!(std::fabs(det) > 1e-12 * scale)) return false;
  const double inv = 1.0 / det;
  const Vec3d s = origin - a;
  *b1 = dot(s, p) * inv;
  const Vec3d q = cross(s, e1);
  *b2 = dot(dir, q) * inv;
  *t = dot(e2, q) * inv;
  return true;
}

namespace {

inline Vec3d position(std::span<const Vec3d> rest, std::span<const Vec3d> u, int32_t v) {
  return rest[static_cast<size_t>(v)] + u[static_cast<size_t>(v)];
}

// Weights slightly outside the triangle still count as inside: a ray through a shared edge or
// vertex must hit one of the triangles around it.
constexpr double kInsideTolerance = 1e-10;

}  // namespace

RayHit cast_ray(const ContactSurface& surface, std::span<const Vec3d> rest,
                std::span<const Vec3d> u, Vec3d origin, Vec3d dir, int32_t start_triangle,
                int max_walk) {
  RayHit hit;
  const int32_t nt = static_cast<int32_t>(surface.triangles.size());
  // Local search (Ladjal et al.): walk towards the triangle whose projection along the ray contains
  // the ray, leaving each triangle across the edge opposite its most negative weight.
  int32_t tri = (start_triangle >= 0 && start_triangle < nt) ? start_triangle : -1;
  int32_t previous = -1;
  for (int step = 0; tri >= 0 && step < max_walk; ++step) {
    ++hit.walk_steps;
    const Triangle& f = surface.triangles[static_cast<size_t>(tri)];
    const Vec3d a = position(rest, u, f[0]), b = position(rest, u, f[1]), c = position(rest, u, f[2]);
    double t = 0, b1 = 0, b2 = 0;
    if (!ray_triangle(origin, dir, a, b, c, &t, &b1, &b2)) break;  // edge-on: search globally
    const double w[3] = {1.0 - b1 - b2, b1, b2};
    const int worst = w[0] <= w[1] ? (w[0] <= w[2] ? 0 : 2) : (w[1] <= w[2] ? 1 : 2);
    if (w[worst] >= -kInsideTolerance) {
      const bool facing = dot(cross(b - a, c - a), dir) < 0;
      if (facing && t > 0) {
        hit.triangle = tri;
        hit.t = t;
        hit.point = origin + t * dir;
        return hit;
      }
      break;  // inside a back face or behind the origin: not the first hit we want
    }
    // Corner `worst` is opposite edge (worst + 1) mod 3.
    const int32_t next = surface.triangle_neighbors[static_cast<size_t>(tri)][(worst + 1) % 3];
    if (next == previous) break;  // oscillating across a fold
    previous = tri;
    tri = next;
  }
  // Global scan: the nearest facing hit in front of the origin.
  hit.global_scan = true;
  double best = std::numeric_limits<double>::infinity();
  for (int32_t i = 0; i < nt; ++i) {
    const Triangle& f = surface.triangles[static_cast<size_t>(i)];
    const Vec3d a = position(rest, u, f[0]), b = position(rest, u, f[1]), c = position(rest, u, f[2]);
    double t = 0, b1 = 0, b2 = 0;
    if (!ray_triangle(origin, dir, a, b, c, &t, &b1, &b2)) continue;
    if (t <= 0 || t >= best) continue;
    if (b1 < -kInsideTolerance || b2 < -kInsideTolerance || b1 + b2 > 1 + kInsideTolerance)
      continue;
    if (dot(cross(b - a, c - a), dir) >= 0) continue;
    best = t;
    hit.triangle = i;
  }
  if (hit.triangle >= 0) {
    hit.t = best;
    hit.point = origin + best * dir;
  }
  return hit;
}

}  // namespace zona
