// Cell mesh generator: checks the spec, picks the lattice, runs the cutting passes, and finds
// the lattice scale that gives a target vertex count; also the structured box mesh.
#include "engine/mesh/mesh_generate.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <numbers>

#include "engine/mesh/mesh_generate_internal.h"

namespace zona {
namespace {

using mesh_gen::Ellipsoid;

// An interface is conforming where lattice edges are at most this fraction of the layer gap:
// then no lattice tetrahedron reaches across the layer, so each is cut by one interface only.
constexpr double kResolvedFraction = 0.75;
// Elements whose smallest (or 180 minus largest) dihedral angle is below this get repaired.
constexpr double kRepairBelowDeg = 15.0;
// Refuse specs whose estimated size would not fit in memory (or in int32 indices).
constexpr double kMaxVertices = static_cast<double>(kMaxCellMeshVertices);

bool finite_positive(double x) { return std::isfinite(x) && x > 0; }

Status check_spec(const CellMeshSpec& s) {
  if (!finite_positive(s.diameter))
    return make_error("cell mesh: diameter must be positive and finite (got %g m)", s.diameter);
  for (int a = 0; a < 3; ++a)
    if (!finite_positive(s.radii_scale[a]))
      return make_error("cell mesh: radii_scale must be positive and finite (axis %d is %g)", a,
                        s.radii_scale[a]);
  const double min_semi =
      0.5 * s.diameter * std::min(s.radii_scale.x, std::min(s.radii_scale.y, s.radii_scale.z));
  if (!(std::isfinite(s.zona_thickness) && s.zona_thickness >= 0 &&
        s.zona_thickness < min_semi))
    return make_error("cell mesh: zona_thickness must be in [0, %g m), the smallest semi-axis "
                      "(got %g m)",
                      min_semi, s.zona_thickness);
  const double inner = min_semi - s.zona_thickness;
  if (!(std::isfinite(s.nucleus_diameter) && s.nucleus_diameter >= 0 &&
        0.5 * s.nucleus_diameter < inner))
    return make_error("cell mesh: nucleus_diameter must be in [0, %g m) to fit inside the "
                      "cytoplasm (got %g m)",
                      2 * inner, s.nucleus_diameter);
  if (s.target_vertices < 0)
    return make_error("cell mesh: target_vertices must be >= 0 (got %lld)",
                      static_cast<long long>(s.target_vertices));
  if (!(std::isfinite(s.edge_length) && s.edge_length >= 0))
    return make_error("cell mesh: edge_length must be >= 0 and finite (got %g m)", s.edge_length);
  if (s.target_vertices == 0 && s.edge_length == 0)
    return make_error("cell mesh: set target_vertices or edge_length");
  if (s.target_vertices > 0 && s.target_vertices < kMinCellMeshVertices)
    return make_error("cell mesh: target_vertices must be at least %lld (got %lld)",
                      static_cast<long long>(kMinCellMeshVertices),
                      static_cast<long long>(s.target_vertices));
  if (s.target_vertices > static_cast<int64_t>(kMaxVertices))
    return make_error("cell mesh: target_vertices %lld exceeds the limit %.0f",
                      static_cast<long long>(s.target_vertices), kMaxVertices);
  if (!(std::isfinite(s.refine_edge_length) && s.refine_edge_length >= 0))
    return make_error("cell mesh: refine_edge_length must be >= 0 and finite (got %g m)",
                      s.refine_edge_length);
  const bool graded = s.refine_edge_length > 0;
  if (graded != s.refine_at.has_value())
    return make_error("cell mesh: refine_edge_length and refine_at go together (refine_at %s, "
                      "refine_edge_length %g m)",
                      s.refine_at ? "set" : "missing", s.refine_edge_length);
  if (graded) {
    if (s.edge_length == 0)
      return make_error("cell mesh: a graded mesh needs edge_length (the coarse size) too");
    if (s.refine_edge_length > s.edge_length)
      return make_error("cell mesh: refine_edge_length (%g m) must not exceed edge_length (%g m)",
                        s.refine_edge_length, s.edge_length);
    for (int a = 0; a < 3; ++a)
      if (!std::isfinite((*s.refine_at)[a]))
        return make_error("cell mesh: refine_at must be finite");
    if (!(std::isfinite(s.refine_radius) && s.refine_radius >= 0))
      return make_error("cell mesh: refine_radius must be >= 0 and finite (got %g m)",
                        s.refine_radius);
    if (!(std::isfinite(s.grading) && s.grading >= 0.05 && s.grading <= 10))
      return make_error("cell mesh: grading must be in [0.05, 10] (got %g)", s.grading);
  }
  if (!(s.lattice_shift >= 0 && s.lattice_shift < 1))
    return make_error("cell mesh: lattice_shift must be in [0, 1) (got %g)", s.lattice_shift);
  return {};
}

Vec3d semi_axes(const CellMeshSpec& s) { return 0.5 * s.diameter * s.radii_scale; }

double ellipsoid_volume(Vec3d r) { return 4.0 / 3.0 * std::numbers::pi * r.x * r.y * r.z; }

// Surface area of an ellipsoid (Knud Thomsen's formula, within about 1 %).
double ellipsoid_area(Vec3d r) {
  const double p = 1.6075;
  const double ap = std::pow(r.x, p), bp = std::pow(r.y, p), cp = std::pow(r.z, p);
  return 4.0 * std::numbers::pi * std::pow((ap * bp + ap * cp + bp * cp) / 3.0, 1.0 / p);
}

// Vertex count of a uniform mesh of lattice edge h: 2 lattice vertices per h^3 inside plus the
// surface vertices (calibrated on generated balls; good to a few % above ~1000 vertices).
double uniform_vertex_estimate(Vec3d r, double h) {
  return 2.0 * ellipsoid_volume(r) / (h * h * h) + 1.1 * ellipsoid_area(r) / (h * h);
}

double uniform_edge_for(Vec3d r, double vertices) {
  // The estimate falls monotonically with h: bisect on log h.
  double lo = 1e-6 * r.x, hi = 10 * r.x;
  for (int i = 0; i < 100; ++i) {
    const double mid = std::sqrt(lo * hi);
    (uniform_vertex_estimate(r, mid) > vertices ? lo : hi) = mid;
  }
  return std::sqrt(lo * hi);
}

// Rough vertex count of a graded mesh (for refusing absurd specs before allocating): the
// lattice density 2 / h^3 integrated over the ball, with h growing radially from refine_at.
double graded_vertex_estimate(Vec3d r, double coarse, double fine, double radius,
                              double grading) {
  double n = uniform_vertex_estimate(r, coarse);
  if (fine <= 0) return n;
  const double reach = radius + (coarse - fine) / grading;
  const int steps = 200;
  for (int i = 0; i < steps; ++i) {
    const double d = (i + 0.5) / steps * reach;
    const double h = std::min(coarse, fine + grading * std::max(0.0, d - radius));
    n += (2.0 / (h * h * h) - 2.0 / (coarse * coarse * coarse)) * 4.0 * std::numbers::pi * d *
         d * (reach / steps);
  }
  return n;
}

struct Lengths {
  double coarse = 0;
  double fine = 0;  // 0: uniform
  int levels = 0;
  double radius = 0;
  double shift = 0;
};

Lengths resolve_lengths(double edge, double refine_edge, double radius) {
  Lengths l;
  if (refine_edge <= 0) {
    l.coarse = edge;
    return l;
  }
  l.levels = std::max(0, static_cast<int>(std::lround(std::log2(edge / refine_edge))));
  l.fine = refine_edge;
  l.coarse = refine_edge * static_cast<double>(int64_t{1} << l.levels);
  l.radius = radius;
  return l;
}

Result<Mesh> generate_once(const CellMeshSpec& s, const Lengths& len, CellMeshReport* report) {
  const Vec3d r = semi_axes(s);
  const double estimate =
      graded_vertex_estimate(r, len.coarse, len.fine, len.radius, s.grading);
  if (!(estimate <= kMaxVertices))
    return make_error("cell mesh: about %.3g vertices exceed the limit %.0f; use a larger "
                      "edge_length or refine_edge_length",
                      estimate, kMaxVertices);
  if (len.levels > 18)
    return make_error("cell mesh: edge_length / refine_edge_length = 2^%d is too large (at most "
                      "2^18)",
                      len.levels);

  mesh_gen::LatticeSpec lattice_spec;
  lattice_spec.semi_axes = r;
  lattice_spec.coarse_size = len.coarse;
  lattice_spec.max_level = len.levels;
  lattice_spec.fine_size = len.fine;
  lattice_spec.refine_center = s.refine_at.value_or(Vec3d{0, 0, 0});
  lattice_spec.refine_radius = len.radius;
  lattice_spec.grading = s.grading;
  lattice_spec.z_offset = len.shift;
  Result<mesh_gen::Lattice> lattice = mesh_gen::build_lattice(lattice_spec);
  if (!lattice) return lattice.error();
  CellMeshReport rep;
  rep.edge_length = len.coarse;
  rep.refine_edge_length = len.fine;
  rep.octree_levels = len.levels;
  rep.lattice_shift = len.shift;
  rep.lattice_vertices = static_cast<int64_t>(lattice->positions.size());
  rep.lattice_tets = static_cast<int64_t>(lattice->tets.size());

  // Pass 1: the cell surface.
  const Ellipsoid outer{r};
  mesh_gen::CutStats stats;
  Result<mesh_gen::WorkMesh> work =
      mesh_gen::stuff_inside(std::move(*lattice), outer, kRegionCytoplasm, &stats);
  if (!work) return work.error();

  // Passes 2 and 3: the layer interfaces, each conforming where the lattice resolves its gap.
  const double t = s.zona_thickness;
  const double nucleus_radius = 0.5 * s.nucleus_diameter;
  const Ellipsoid inner{r - Vec3d{t, t, t}};
  const Ellipsoid nucleus{{nucleus_radius, nucleus_radius, nucleus_radius}};
  auto add = [&](const mesh_gen::CutStats& c) {
    stats.warped_vertices += c.warped_vertices;
    stats.cut_vertices += c.cut_vertices;
    stats.steiner_vertices += c.steiner_vertices;
    stats.centroid_tets += c.centroid_tets;
  };
  if (t > 0) {
    double gap = t;
    if (nucleus_radius > 0) gap = std::min(gap, inner.min_semi_axis() - nucleus_radius);
    Result<mesh_gen::CutStats> c = mesh_gen::cut_interface(
        *work, inner, kResolvedFraction * gap, -1, kRegionZona);
    if (!c) return c.error();
    add(*c);
  }
  if (nucleus_radius > 0) {
    const double gap = (t > 0 ? inner : outer).min_semi_axis() - nucleus_radius;
    Result<mesh_gen::CutStats> c = mesh_gen::cut_interface(
        *work, nucleus, kResolvedFraction * gap, kRegionNucleus, -1);
    if (!c) return c.error();
    add(*c);
  }
  // Repair: lift the few elements near the stuffing bound (interface caps, octree
  // transitions) clear of it by moving vertices that lie on no surface.
  std::vector<Ellipsoid> surfaces{outer};
  if (t > 0) surfaces.push_back(inner);
  if (nucleus_radius > 0) surfaces.push_back(nucleus);
  const int64_t smoothed = mesh_gen::smooth_worst_tets(
      *work, surfaces, std::sin(kRepairBelowDeg * std::numbers::pi / 180.0), 3);
  mesh_gen::remove_unreferenced(*work);

  Mesh mesh;
  mesh.rest_positions = std::move(work->positions);
  mesh.tets = std::move(work->tets);
  mesh.tet_region = std::move(work->region);
  mesh.regions.push_back({kRegionCytoplasm, "cytoplasm"});
  if (t > 0) mesh.regions.push_back({kRegionZona, "zona"});
  if (nucleus_radius > 0) mesh.regions.push_back({kRegionNucleus, "nucleus"});
  if (mesh.tets.empty())
    return make_error("cell mesh: edge_length %g m is too coarse for a %g m cell: no elements",
                      len.coarse, s.diameter);
  // Cheap self-check: a flat or inverted element here is a generator bug, never a valid mesh.
  for (size_t i = 0; i < mesh.tets.size(); ++i)
    if (!(tet_rest_volume(mesh, i) > 0))
      return make_error("cell mesh: element %zu is not positively oriented (internal error)", i);

  rep.warped_vertices = stats.warped_vertices;
  rep.cut_vertices = stats.cut_vertices;
  rep.steiner_vertices = stats.steiner_vertices;
  rep.centroid_tagged_tets = stats.centroid_tets;
  rep.smoothed_vertices = smoothed;
  if (report) *report = rep;
  return mesh;
}

// Scales the spec's lengths as a whole until the vertex count is within 2 % of the target (or
// the closest found in a bounded number of attempts). The count is a step function of the
// scale; when a secant search on the scale stalls on a step, the lattice shift is changed,
// which moves the steps.
Result<Mesh> generate_for_count(const CellMeshSpec& s, CellMeshReport* report) {
  const Vec3d r = semi_axes(s);
  const double target = static_cast<double>(s.target_vertices);
  const double tolerance = std::max(0.02, 2.5 / target);
  const bool graded = s.refine_edge_length > 0;
  // Lengths at scale 1 and the first scale: a graded mesh starts from the uniform estimate at
  // its coarse size, and the search corrects for the refinement's extra vertices.
  const double base = graded ? s.edge_length : 1.0;
  auto lengths_at = [&](double k, double shift) {
    Lengths l = graded ? resolve_lengths(k * s.edge_length, k * s.refine_edge_length,
                                         k * s.refine_radius)
                       : resolve_lengths(k, 0, 0);
    l.shift = shift;
    return l;
  };

  std::optional<Mesh> best;
  CellMeshReport best_report;
  double best_error = std::numeric_limits<double>::infinity();
  double best_scale = uniform_edge_for(r, target) / base;
  int attempts = 0;
  constexpr double kShifts[] = {0.0, 0.5, 0.25, 0.75, 0.125, 0.375, 0.625, 0.875};
  constexpr int kStepsPerShift = 8;
  // Large counts are smooth in the scale and land in one or two attempts; the cap only bounds
  // the time if that ever fails (an attempt at 1e7 vertices takes about 20 s).
  const int max_attempts = target > 2e5 ? 6 : 64;
  for (double shift : kShifts) {
    if (best_error <= tolerance || attempts >= max_attempts) break;
    double scale = best_scale;
    double prev_scale = 0, prev_count = 0;
    for (int step = 0; step < kStepsPerShift && attempts < max_attempts; ++step) {
      CellMeshReport rep;
      Result<Mesh> mesh = generate_once(s, lengths_at(scale, shift), &rep);
      ++attempts;
      if (!mesh) return mesh.error();
      const double count = static_cast<double>(mesh->vertex_count());
      const double error = std::abs(count - target) / target;
      if (error < best_error) {
        best_error = error;
        best_scale = scale;
        best = std::move(*mesh);
        best_report = rep;
      }
      if (best_error <= tolerance) break;
      // Secant step on log(count) versus log(scale), slope clamped to sane values (a uniform
      // mesh has slope -3); a plain -3 step when there is no usable previous point.
      double slope = -3.0;
      if (prev_scale > 0 && prev_count != count && prev_scale != scale)
        slope = std::clamp(std::log(count / prev_count) / std::log(scale / prev_scale), -6.0,
                           -1.0);
      prev_scale = scale;
      prev_count = count;
      double next = scale * std::pow(target / count, 1.0 / slope);
      // On a flat step of the count the secant would stop: nudge it across.
      if (std::abs(next / scale - 1) < 1e-3) next = scale * (count > target ? 1.01 : 0.99);
      scale = next;
    }
  }
  best_report.attempts = attempts;
  if (report) *report = best_report;
  return std::move(*best);
}

}  // namespace

Result<Mesh> generate_cell_mesh(const CellMeshSpec& spec, CellMeshReport* report) {
  if (Status st = check_spec(spec); !st) return st.error();
  if (spec.target_vertices > 0) return generate_for_count(spec, report);
  Lengths lengths =
      resolve_lengths(spec.edge_length, spec.refine_edge_length, spec.refine_radius);
  lengths.shift = spec.lattice_shift;
  return generate_once(spec, lengths, report);
}

CellMeshSpec table2_spec(int64_t vertices) {
  CellMeshSpec s;
  s.diameter = 56e-6;
  s.target_vertices = vertices;
  // Shape of the grading (lengths are scaled together by the vertex search): fine elements a
  // quarter of the coarse ones within half a coarse edge of the pole.
  s.edge_length = 1.0;
  s.refine_edge_length = 0.25;
  s.refine_radius = 0.5;
  s.refine_at = Vec3d{0, 0, 0.5 * s.diameter};
  return s;
}

Mesh generate_box_mesh(Vec3d lo, Vec3d hi, int nx, int ny, int nz) {
  ZONA_ASSERT(nx >= 1 && ny >= 1 && nz >= 1);
  ZONA_ASSERT(lo.x < hi.x && lo.y < hi.y && lo.z < hi.z);
  Mesh mesh;
  nx = std::max(nx, 0);
  ny = std::max(ny, 0);
  nz = std::max(nz, 0);
  const int64_t sx = nx + 1, sy = ny + 1;
  auto index = [&](int64_t i, int64_t j, int64_t k) {
    return static_cast<int32_t>(i + sx * (j + sy * k));
  };
  mesh.rest_positions.reserve(static_cast<size_t>(sx * sy * (nz + 1)));
  for (int k = 0; k <= nz; ++k)
    for (int j = 0; j <= ny; ++j)
      for (int i = 0; i <= nx; ++i)
        mesh.rest_positions.push_back(
            {lo.x + (hi.x - lo.x) * i / nx, lo.y + (hi.y - lo.y) * j / ny,
             lo.z + (hi.z - lo.z) * k / nz});
  // Kuhn split: one tetrahedron per axis order, each a monotone path from corner (0,0,0) to
  // (1,1,1). Every cube splits its faces along the diagonals through its (0,0,0)-(1,1,1)
  // corners' projections, so neighbouring cubes agree.
  constexpr int kOrders[6][3] = {{0, 1, 2}, {0, 2, 1}, {1, 0, 2}, {1, 2, 0}, {2, 0, 1}, {2, 1, 0}};
  mesh.tets.reserve(static_cast<size_t>(6) * nx * ny * nz);
  for (int k = 0; k < nz; ++k)
    for (int j = 0; j < ny; ++j)
      for (int i = 0; i < nx; ++i)
        for (const auto& order : kOrders) {
          int64_t c[3] = {i, j, k};
          Tet t;
          t[0] = index(c[0], c[1], c[2]);
          for (int step = 0; step < 3; ++step) {
            ++c[order[step]];
            t[step + 1] = index(c[0], c[1], c[2]);
          }
          const auto& p = mesh.rest_positions;
          if (tet_signed_volume(p[t[0]], p[t[1]], p[t[2]], p[t[3]]) < 0) std::swap(t[2], t[3]);
          mesh.tets.push_back(t);
        }
  mesh.tet_region.assign(mesh.tets.size(), kRegionCytoplasm);
  mesh.regions.push_back({kRegionCytoplasm, "cytoplasm"});
  return mesh;
}

}  // namespace zona
