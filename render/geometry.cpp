// Render space, camera matrices, the cell surface with smooth normals, pipette meshes
// (geometry.h).
#include "render/geometry.h"

#include <algorithm>
#include <cmath>
#include <glm/gtc/matrix_transform.hpp>
#include <limits>

namespace zona {

namespace {
constexpr double kDegree = 3.14159265358979323846 / 180.0;
}  // namespace

Vec3d camera_eye(const OrbitCamera& c) {
  const double yaw = c.yaw_deg * kDegree, pitch = c.pitch_deg * kDegree;
  const Vec3d dir{std::cos(pitch) * std::sin(yaw), std::sin(pitch),
                  std::cos(pitch) * std::cos(yaw)};
  return c.target + c.distance * dir;
}

OrbitCamera fit_camera(Vec3d centre, double radius, double fill, double yaw_deg, double pitch_deg,
                       double fov_y_deg) {
  OrbitCamera c;
  c.target = centre;
  c.yaw_deg = yaw_deg;
  c.pitch_deg = pitch_deg;
  c.fov_y_deg = fov_y_deg;
  // The sphere's silhouette spans 2 asin(r / d) of the view; ask for `fill` of fov_y.
  const double half = 0.5 * std::clamp(fill, 0.05, 0.99) * fov_y_deg * kDegree;
  c.distance = radius / std::sin(half);
  return c;
}

void orbit_camera(OrbitCamera* camera, double yaw_deg, double pitch_deg) {
  camera->yaw_deg = std::fmod(camera->yaw_deg + yaw_deg, 360.0);
  camera->pitch_deg = std::clamp(camera->pitch_deg + pitch_deg, -89.0, 89.0);
}

namespace render {

gpu::vec3 RenderSpace::to_render(Vec3d x) const {
  const Vec3d r = (x - origin) * scale;
  return {static_cast<float>(r.x), static_cast<float>(r.y), static_cast<float>(r.z)};
}

CameraMatrices camera_matrices(const OrbitCamera& camera, double aspect) {
  CameraMatrices m;
  m.space.origin = camera.target;
  m.space.scale = camera.distance > 0 ? 1.0 / camera.distance : 1.0;
  const Vec3d eye = (camera_eye(camera) - camera.target) * m.space.scale;  // unit length
  m.eye = {static_cast<float>(eye.x), static_cast<float>(eye.y), static_cast<float>(eye.z)};
  const gpu::mat4 view = glm::lookAt(m.eye, gpu::vec3(0.0f), gpu::vec3(0.0f, 1.0f, 0.0f));
  // Render space puts the target at distance 1: near / far bracket everything within 0.99 of it
  // in front and 20 behind, ample for a cell and tools that leave the view.
  gpu::mat4 proj = glm::perspective(static_cast<float>(camera.fov_y_deg * kDegree),
                                    static_cast<float>(aspect), 0.01f, 20.0f);
  proj[1][1] *= -1.0f;  // Vulkan's clip space has y pointing down
  m.view_proj = proj * view;
  return m;
}

Status update_surface(const RenderFrame& frame, const RenderSpace& space, SurfaceGeometry* s) {
  const size_t nv = frame.rest.size();
  if (!frame.displacement.empty() && frame.displacement.size() != nv)
    return make_error("render frame: displacement has %zu entries, rest positions %zu",
                      frame.displacement.size(), nv);
  if (!frame.scalar.empty() && frame.scalar.size() != nv)
    return make_error("render frame: scalar has %zu entries, rest positions %zu",
                      frame.scalar.size(), nv);
  // Compaction: rebuilt when the triangle array changes (new mesh), reused otherwise.
  if (s->cached_triangles != frame.triangles.data() || s->cached_count != frame.triangles.size() ||
      s->cached_vertex_count != nv) {
    std::vector<int32_t> compact(nv, -1);
    s->mesh_vertex.clear();
    s->mesh.indices.clear();
    s->mesh.indices.reserve(3 * frame.triangles.size());
    for (size_t t = 0; t < frame.triangles.size(); ++t) {
      for (int32_t v : frame.triangles[t]) {
        if (v < 0 || static_cast<size_t>(v) >= nv)
          return make_error("render frame: triangle %zu has vertex %d, vertex count %zu", t, v, nv);
        if (compact[v] < 0) {
          compact[v] = static_cast<int32_t>(s->mesh_vertex.size());
          s->mesh_vertex.push_back(v);
        }
        s->mesh.indices.push_back(static_cast<uint32_t>(compact[v]));
      }
    }
    s->cached_triangles = frame.triangles.data();
    s->cached_count = frame.triangles.size();
    s->cached_vertex_count = nv;
  }

  const size_t n = s->mesh_vertex.size();
  s->mesh.positions.resize(n);
  s->mesh.normals.assign(n, gpu::vec4(0.0f));
  double lo = std::numeric_limits<double>::infinity(), hi = -lo;
  for (size_t i = 0; i < n; ++i) {
    const size_t v = static_cast<size_t>(s->mesh_vertex[i]);
    const Vec3d x =
        frame.displacement.empty() ? frame.rest[v] : frame.rest[v] + frame.displacement[v];
    const float value = frame.scalar.empty() ? 0.0f : frame.scalar[v];
    s->mesh.positions[i] = gpu::vec4(space.to_render(x), value);
    if (!frame.scalar.empty() && std::isfinite(value)) {
      lo = std::min(lo, static_cast<double>(value));
      hi = std::max(hi, static_cast<double>(value));
    }
  }
  s->scalar_min = std::isfinite(lo) ? lo : 0.0;
  s->scalar_max = std::isfinite(hi) ? hi : 0.0;
  s->scalar_p98 = s->scalar_max;
  if (!frame.scalar.empty() && n > 0) {
    s->scratch.clear();
    for (const gpu::vec4& p : s->mesh.positions)
      if (std::isfinite(p.w)) s->scratch.push_back(p.w);
    if (!s->scratch.empty()) {
      const size_t k = std::min(s->scratch.size() - 1, (s->scratch.size() * 98) / 100);
      std::nth_element(s->scratch.begin(), s->scratch.begin() + static_cast<std::ptrdiff_t>(k),
                       s->scratch.end());
      s->scalar_p98 = s->scratch[k];
    }
  }
  // Smooth normals: the sum of the unnormalised face normals (area-weighted) around a vertex,
  // from the deformed positions so that indentation is shaded.
  const std::vector<uint32_t>& idx = s->mesh.indices;
  for (size_t t = 0; t + 2 < idx.size(); t += 3) {
    const gpu::vec3 a(s->mesh.positions[idx[t]]), b(s->mesh.positions[idx[t + 1]]),
        c(s->mesh.positions[idx[t + 2]]);
    const gpu::vec3 face = glm::cross(b - a, c - a);
    for (int k = 0; k < 3; ++k) s->mesh.normals[idx[t + k]] += gpu::vec4(face, 0.0f);
  }
  for (gpu::vec4& nrm : s->mesh.normals) {
    const float len = glm::length(gpu::vec3(nrm));
    nrm = len > 0 ? gpu::vec4(gpu::vec3(nrm) / len, 0.0f) : gpu::vec4(0.0f, 0.0f, 1.0f, 0.0f);
  }
  return {};
}

void append_revolution(const std::vector<ProfilePoint>& profile, Vec3d origin, Vec3d axis,
                       int segments, const RenderSpace& space, MeshData* mesh) {
  if (profile.size() < 2 || segments < 3) return;
  const double len = norm(axis);
  if (!(len > 0)) return;
  const Vec3d a = axis / len;
  // Two unit vectors across the axis.
  const Vec3d helper = std::abs(a.x) < 0.9 ? Vec3d{1, 0, 0} : Vec3d{0, 1, 0};
  Vec3d e1 = cross(a, helper);
  e1 = e1 / norm(e1);
  const Vec3d e2 = cross(a, e1);
  const uint32_t base = static_cast<uint32_t>(mesh->positions.size());
  const uint32_t ring = static_cast<uint32_t>(segments + 1);  // seam vertex duplicated
  for (const ProfilePoint& p : profile) {
    for (int k = 0; k <= segments; ++k) {
      const double phi = 2.0 * 3.14159265358979323846 * k / segments;
      const Vec3d radial = std::cos(phi) * e1 + std::sin(phi) * e2;
      const Vec3d x = origin + p.axial * a + p.radius * radial;
      const Vec3d n = p.normal_axial * a + p.normal_radial * radial;
      mesh->positions.push_back(gpu::vec4(space.to_render(x), 0.0f));
      mesh->normals.push_back(gpu::vec4(static_cast<float>(n.x), static_cast<float>(n.y),
                                        static_cast<float>(n.z), 0.0f));
    }
  }
  for (uint32_t r = 0; r + 1 < profile.size(); ++r) {
    for (uint32_t k = 0; k < static_cast<uint32_t>(segments); ++k) {
      const uint32_t i0 = base + r * ring + k, i1 = i0 + 1, j0 = i0 + ring, j1 = j0 + 1;
      mesh->indices.insert(mesh->indices.end(), {i0, j0, i1, i1, j0, j1});
    }
  }
}

void append_needle(const NeedlePose& needle, double default_length, const RenderSpace& space,
                   MeshData* mesh) {
  if (!needle.visible) return;
  const double r = needle.tip_radius;
  const double length = needle.length > 0 ? needle.length : default_length;
  // Axial coordinate runs from the tip back along the shaft (axis = -direction).
  const Vec3d back = -1.0 * needle.direction;
  std::vector<ProfilePoint> profile;
  if (needle.flat_tip) {
    // A disc facing forward, then the shaft with its own (hard-edged) normals.
    append_revolution({{0, 0, -1, 0}, {0, r, -1, 0}}, needle.tip, back, 24, space, mesh);
    profile = {{0, r, 0, 1}, {length, r, 0, 1}};
  } else {
    constexpr int kArc = 8;
    for (int i = 0; i <= kArc; ++i) {
      const double theta = 0.5 * 3.14159265358979323846 * i / kArc;  // 0 at the apex
      profile.push_back(
          {r - r * std::cos(theta), r * std::sin(theta), -std::cos(theta), std::sin(theta)});
    }
    profile.push_back({length, r, 0, 1});
  }
  append_revolution(profile, needle.tip, back, 24, space, mesh);
}

void append_holding(const HoldingPose& holding, double default_length, const RenderSpace& space,
                    MeshData* mesh) {
  if (!holding.visible) return;
  const double length = holding.length > 0 ? holding.length : default_length;
  const double ri = holding.inner_radius;
  const double ro = std::max(holding.outer_radius, 1.05 * ri);
  constexpr int kSegments = 48;
  // Rim facing the cell, outer wall, bore: three bands with their own (hard-edged) normals.
  append_revolution({{0, ri, -1, 0}, {0, ro, -1, 0}}, holding.mouth, holding.axis, kSegments, space,
                    mesh);
  append_revolution({{0, ro, 0, 1}, {length, ro, 0, 1}}, holding.mouth, holding.axis, kSegments,
                    space, mesh);
  append_revolution({{0, ri, 0, -1}, {length, ri, 0, -1}}, holding.mouth, holding.axis, kSegments,
                    space, mesh);
}

}  // namespace render
}  // namespace zona
