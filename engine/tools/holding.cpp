// The holding pipette: tube-wall distance, the aspirated patch and its suction forces.
#include "engine/tools/holding.h"

#include <algorithm>
#include <cmath>

#include "engine/tools/contact.h"
#include "engine/tools/tool_sdf.h"

namespace zona {

ToolDistance holding_distance(const HoldingGeometry& h, Vec3d x) {
  // One distance function for every path: engine/tools/tool_sdf.h, host and device.
  const ToolSdf sdf =
      holding_sdf(h.mouth, h.axis, h.inner_radius, h.outer_radius, x, h.edge_radius);
  return ToolDistance{sdf.distance, sdf.normal};
}

Result<HoldingSetup> make_holding(const HoldingPipetteDef& def, const ContactSurface& surface,
                                  const std::vector<Vec3d>& rest, Vec3d centre,
                                  Vec3d needle_direction) {
  HoldingSetup setup;
  setup.mode = def.mode;
  setup.friction = def.friction;
  setup.stick_length = def.stick_length;
  Vec3d axis = def.side ? *def.side : needle_direction;
  const double axis_norm = norm(axis);
  if (!(axis_norm > 0)) return make_error("holding_pipette: the side direction is zero");
  axis = axis / axis_norm;
  const double a = def.inner_radius;
  if (!(a > 0)) return make_error("holding_pipette: inner_radius must be > 0 m, got %g", a);
  HoldingGeometry& g = setup.geometry;
  g.axis = axis;
  g.inner_radius = a;
  g.outer_radius = def.outer_radius > a ? def.outer_radius : 1.25 * a;
  if (!(def.edge_radius >= 0) || !(def.edge_radius < 0.5 * (g.outer_radius - a)))
    return make_error("holding_pipette: edge_radius %g m must be >= 0 and below half the rim's "
                      "width (%g m)",
                      def.edge_radius, 0.5 * (g.outer_radius - a));
  g.edge_radius = def.edge_radius;

  // The mouth: given, or where the circle of radius a meets the rest surface. The cell's extent
  // along the axis comes from a ray cast from the centre (works for file meshes too).
  const std::vector<Vec3d> zero(rest.size(), Vec3d{0, 0, 0});
  if (def.position) {
    g.mouth = *def.position;
  } else {
    // From outside, looking back at the cell: the first hit faces the ray.
    double extent = 0;
    for (const Vec3d& p : rest) extent = std::max(extent, norm(p - centre));
    const RayHit far = cast_ray(surface, rest, zero, centre + 2.0 * extent * axis, -1.0 * axis, -1);
    if (far.triangle < 0) return make_error("holding_pipette: the axis from the cell centre misses the surface");
    const double radius = dot(far.point - centre, axis);
    if (!(a < radius))
      return make_error("holding_pipette: inner_radius %g m is not smaller than the cell radius %g m",
                        a, radius);
    g.mouth = centre + std::sqrt(radius * radius - a * a) * axis;
  }

  // The aspirated patch: the surface triangles whose centroid lies over the opening (within a
  // of the axis, on the pipette side of the centre) and their corners.
  std::vector<size_t> patch_triangles;
  for (size_t t = 0; t < surface.triangles.size(); ++t) {
    const Triangle& tri = surface.triangles[t];
    const Vec3d centroid = (rest[tri[0]] + rest[tri[1]] + rest[tri[2]]) / 3.0;
    const Vec3d w = centroid - g.mouth;
    const double s = dot(w, axis);
    if (norm(w - s * axis) > a || dot(centroid - centre, axis) <= 0) continue;
    patch_triangles.push_back(t);
    for (int32_t v : tri) setup.patch_vertices.push_back(v);
  }
  std::sort(setup.patch_vertices.begin(), setup.patch_vertices.end());
  setup.patch_vertices.erase(std::unique(setup.patch_vertices.begin(), setup.patch_vertices.end()),
                             setup.patch_vertices.end());
  if (setup.patch_vertices.empty())
    return make_error(
        "holding_pipette: no surface triangle lies within inner_radius %g m of the pipette axis "
        "(refine the mesh there or widen the pipette)",
        a);

  // Suction: the pressure difference pulls the membrane over the opening into the pipette, along
  // its outward normal: each patch triangle gives p A n / 3 to each corner, so the total is p
  // times the patch's vector area (p pi a^2 along the axis for a spherical cap). Dead load on the
  // rest geometry (the aspirated tongue stays small).
  for (size_t t : patch_triangles) {
    const Triangle& tri = surface.triangles[t];
    const Vec3d p0 = rest[tri[0]], p1 = rest[tri[1]], p2 = rest[tri[2]];
    setup.aspirated_area += 0.5 * dot(cross(p1 - p0, p2 - p0), axis);
  }
  if (def.mode == HoldingMode::kSuction) {
    setup.suction_force.assign(setup.patch_vertices.size(), Vec3d{0, 0, 0});
    for (size_t t : patch_triangles) {
      const Triangle& tri = surface.triangles[t];
      const Vec3d p0 = rest[tri[0]], p1 = rest[tri[1]], p2 = rest[tri[2]];
      const Vec3d area_normal = 0.5 * cross(p1 - p0, p2 - p0);  // outward, |.| = area
      for (int32_t v : tri) {
        const auto it = std::lower_bound(setup.patch_vertices.begin(), setup.patch_vertices.end(), v);
        setup.suction_force[static_cast<size_t>(it - setup.patch_vertices.begin())] +=
            (def.suction / 3.0) * area_normal;
      }
    }
    for (const Vec3d& f : setup.suction_force) setup.suction_total += f;
  }
  return setup;
}

}  // namespace zona
