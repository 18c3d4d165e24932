// Contact surface, ray casting with local search, and the kinematic contact set with friction.
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

ToolDistance tool_distance(const ContactTool& tool, Vec3d origin, Vec3d x) {
  if (tool.kind == ContactTool::Kind::kNeedle) return needle_distance(tool.needle, origin, x);
  return holding_distance(tool.holding, x - origin);
}

ContactSet::ContactSet(const ContactTool& tool, const ContactSurface& surface,
                       size_t vertex_count, size_t capacity)
    : tool_(tool),
      surface_(&surface),
      contacts_(capacity),
      in_set_(vertex_count, 0),
      released_at_(vertex_count, -1),
      visit_stamp_(vertex_count, 0),
      queue_(vertex_count, 0) {}

void ContactSet::measure_reactions(const Model& model, std::span<const Vec3d> u,
                                   std::span<const Vec3d> u_prev, std::span<const Vec3d> force,
                                   std::span<const Vec3d> external) {
  // The constraint force that held each vertex on its path: what its centred-difference
  // equation leaves over, M a + gamma v - f_el - f_ext (as the integrator computes it).
  const double inv_dt2 = 1.0 / (model.dt * model.dt);
  const double half_inv_dt = 0.5 / model.dt;
  for (size_t i = 0; i < count_; ++i) {
    Contact& c = contacts_[i];
    const size_t v = static_cast<size_t>(c.vertex);
    const Vec3d acc = inv_dt2 * (u[v] - 2.0 * u_prev[v] + c.u_before);
    const Vec3d vel = half_inv_dt * (u[v] - c.u_before);
    c.static_reaction = -1.0 * (force[v] + external[v]);
    c.reaction = model.vertex_mass[v] * acc + model.vertex_damping[v] * vel + c.static_reaction;
    if (c.measurements < 2) ++c.measurements;
  }
}

void ContactSet::set_linear_history(std::span<const Vec3d> u, std::span<const Vec3d> u_prev) {
  for (size_t i = 0; i < count_; ++i) {
    const size_t v = static_cast<size_t>(contacts_[i].vertex);
    contacts_[i].u_before = 2.0 * u_prev[v] - u[v];
  }
}

void ContactSet::add(int32_t vertex, Vec3d anchor, Vec3d normal, Vec3d u_now) {
  Contact& c = contacts_[count_++];
  c.vertex = vertex;
  c.anchor = anchor;
  c.normal = normal;
  c.u_before = u_now;
  c.reaction = Vec3d{0, 0, 0};
  c.static_reaction = Vec3d{0, 0, 0};
  c.slipping = false;
  c.face = false;
  c.measurements = 0;
  in_set_[static_cast<size_t>(vertex)] = 1;
}

bool ContactSet::hold(int32_t vertex, Vec3d anchor, Vec3d normal, Vec3d u_now) {
  if (in_set_[static_cast<size_t>(vertex)] || count_ == contacts_.size()) return false;
  add(vertex, anchor, normal, u_now);
  contacts_[count_ - 1].face = true;
  return true;
}

ContactUpdate ContactSet::update(const Model& model, std::span<const Vec3d> u, Vec3d origin,
                                 std::span<const int32_t> seeds, std::span<const uint8_t> taken,
                                 bool full_scan, double search_margin, double relax) {
  ContactUpdate result;
  const std::span<const Vec3d> rest(model.rest_positions);
  const double mu = tool_.friction;
  ++update_count_;

  // 1. Release contacts that pull; slide the ones whose friction cone is exceeded. Only
  // contacts measured on the tool are judged, against a tolerance relative to the set's mean
  // quasi-static reaction (contact.h: the release rule, robust to rounding).
  double reaction_sum = 0;
  int32_t measured = 0;
  for (size_t i = 0; i < count_; ++i) {
    const double r = norm(contacts_[i].static_reaction);
    if (contacts_[i].measurements >= 2 && std::isfinite(r)) {  // a NaN releases only its own
      reaction_sum += r;
      ++measured;
    }
  }
  const double tolerance =
      measured > 0 ? kContactReleaseTolerance * reaction_sum / static_cast<double>(measured) : 0.0;
  for (size_t i = 0; i < count_;) {
    Contact& c = contacts_[i];
    if (c.measurements < 2) {
      // Its reaction so far is the free vertex's before the take: keep it where it was put.
      c.slipping = false;
      ++i;
      continue;
    }
    const double rn = dot(c.static_reaction, c.normal);
    if (!(rn >= -tolerance)) {  // NaN releases too
      in_set_[static_cast<size_t>(c.vertex)] = 0;
      // A released vertex sits on the tool surface, within rounding of inside it: it must not
      // be taken back in the same update, only if it moves into the tool again.
      released_at_[static_cast<size_t>(c.vertex)] = update_count_;
      contacts_[i] = contacts_[--count_];
      ++result.released;
      continue;
    }
    const Vec3d rt = c.static_reaction - rn * c.normal;
    const double rt_norm = norm(rt);
    // A kept contact within the tolerance (rn <= 0) has a cone of zero radius.
    const double cone = mu * std::max(rn, 0.0);
    c.slipping = !c.face && rt_norm > cone;
    if (c.slipping) {
      // Return mapping: the reaction answers a target shift by shift / c (c = dt^2 / (M +
      // gamma dt / 2)) at first, so moving the anchor by -c (|r_t| - mu r_n) t_hat brings the
      // tangential reaction back to the cone; `relax` < 1 damps the one-step lag.
      const double compliance = model.vertex_coefficients[static_cast<size_t>(c.vertex)].c;
      const Vec3d shift = (-relax * compliance * (rt_norm - cone) / rt_norm) * rt;
      const Vec3d x = origin + c.anchor + shift;
      const ToolDistance d = tool_distance(tool_, origin, x);
      c.anchor = project_to_surface(x, d) - origin;
      c.normal = d.normal;
      ++result.slipping;
    }
    ++i;
  }

  // 2. Find free vertices inside the tool. Interior vertices count too: where the surface layer
  // under the tip is crushed, the tool must still push the material behind it.
  auto visit = [&](int32_t v, bool expand_always) -> bool {
    const Vec3d x = position(rest, u, v);
    const ToolDistance d = tool_distance(tool_, origin, x);
    if (d.distance < 0 && !in_set_[static_cast<size_t>(v)] && !taken[static_cast<size_t>(v)] &&
        released_at_[static_cast<size_t>(v)] != update_count_) {
      if (count_ == contacts_.size()) {
        result.overflow = true;
      } else {
        add(v, project_to_surface(x, d) - origin, d.normal, u[static_cast<size_t>(v)]);
        ++result.added;
      }
    }
    return expand_always || d.distance < search_margin;
  };
  const int32_t nv = static_cast<int32_t>(in_set_.size());
  if (full_scan) {
    for (int32_t v = 0; v < nv; ++v) visit(v, false);
    return result;
  }
  // Breadth-first search over the mesh graph (vertices sharing a tetrahedron) from the seeds and
  // the current contacts, expanding through vertices within search_margin of the tool.
  ++stamp_;
  size_t head = 0, tail = 0;
  auto push = [&](int32_t v) {
    if (v < 0 || v >= nv || visit_stamp_[static_cast<size_t>(v)] == stamp_) return;
    visit_stamp_[static_cast<size_t>(v)] = stamp_;
    queue_[tail++] = v;
  };
  for (int32_t v : seeds) push(v);
  for (size_t i = 0; i < count_; ++i) push(contacts_[i].vertex);
  const size_t roots = tail;
  const VertexTetAdjacency& adj = model.adjacency;
  while (head < tail) {
    const bool root = head < roots;
    const int32_t v = queue_[head++];
    if (!visit(v, root)) continue;
    for (int32_t k = adj.offsets[static_cast<size_t>(v)]; k < adj.offsets[static_cast<size_t>(v) + 1]; ++k)
      for (int32_t w : model.tets[static_cast<size_t>(adj.tets[static_cast<size_t>(k)])]) push(w);
  }
  return result;
}

void ContactSet::targets(const Model& model, std::span<const Vec3d> u_prev_step, Vec3d next_origin,
                         std::span<Vec3d> out) {
  ZONA_ASSERT(out.size() >= count_);
  for (size_t i = 0; i < count_; ++i) {
    Contact& c = contacts_[i];
    const size_t v = static_cast<size_t>(c.vertex);
    c.u_before = u_prev_step[v];
    out[i] = next_origin + c.anchor - model.rest_positions[v];
  }
}

Vec3d ContactSet::total_reaction() const {
  Vec3d sum{0, 0, 0};
  for (size_t i = 0; i < count_; ++i) sum += contacts_[i].reaction;
  return sum;
}

Vec3d ContactSet::total_static_reaction() const {
  Vec3d sum{0, 0, 0};
  for (size_t i = 0; i < count_; ++i) sum += contacts_[i].static_reaction;
  return sum;
}

}  // namespace zona
