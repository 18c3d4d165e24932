// The particle cell model (Asgari et al.): layouts, build, stable step, body mesh/model, CPU step.
#include "engine/particles/particle_model.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <initializer_list>
#include <map>

#include "engine/particles/particle_element.h"

namespace zona {
namespace {

constexpr double kPi = 3.14159265358979323846;

// Unit-sphere points, an outward triangulation and the springs of one layout.
struct Layout {
  std::vector<Vec3d> points;
  std::vector<Triangle> triangles;
  std::vector<std::array<int32_t, 2>> springs;  // i < j, sorted
  double kappa = 3.0;  // spring constant factor (ParticleModelDesc::membrane_modulus)
};

void sort_unique(std::vector<std::array<int32_t, 2>>& edges) {
  for (auto& e : edges)
    if (e[0] > e[1]) std::swap(e[0], e[1]);
  std::sort(edges.begin(), edges.end());
  edges.erase(std::unique(edges.begin(), edges.end()), edges.end());
}

// Every triangle turned outward (the layouts are star-shaped about the origin).
void orient_outward(const std::vector<Vec3d>& x, std::vector<Triangle>& triangles) {
  for (Triangle& t : triangles) {
    const Vec3d a = x[static_cast<size_t>(t[0])], b = x[static_cast<size_t>(t[1])],
                c = x[static_cast<size_t>(t[2])];
    if (dot(triangle_area_vector(a, b, c), a + b + c) < 0) std::swap(t[1], t[2]);
  }
}

// Geodesic icosphere of frequency n: each icosahedron face split into n^2 triangles, points
// projected on the sphere. A point is named by its integer barycentric weights over the face's
// corners (corner ids sorted), so that points on shared edges are made once.
Layout icosphere(int n) {
  const double phi = (1.0 + std::sqrt(5.0)) / 2.0;
  std::vector<Vec3d> ico;
  for (double s1 : {-1.0, 1.0})
    for (double s2 : {-1.0, 1.0}) {
      ico.push_back(Vec3d{0, s1, s2 * phi});
      ico.push_back(Vec3d{s1, s2 * phi, 0});
      ico.push_back(Vec3d{s2 * phi, 0, s1});
    }
  // Faces: triples of corners at the edge length (2) from each other.
  std::vector<std::array<int, 3>> faces;
  auto adjacent = [&](int a, int b) { return std::fabs(norm(ico[size_t(a)] - ico[size_t(b)]) - 2.0) < 1e-9; };
  for (int a = 0; a < 12; ++a)
    for (int b = a + 1; b < 12; ++b)
      for (int c = b + 1; c < 12; ++c)
        if (adjacent(a, b) && adjacent(b, c) && adjacent(a, c)) faces.push_back({a, b, c});

  Layout out;
  std::map<std::array<int64_t, 6>, int32_t> index;
  auto point = [&](const std::array<int, 3>& f, int wa, int wb, int wc) {
    std::array<std::pair<int, int>, 3> w = {{{f[0], wa}, {f[1], wb}, {f[2], wc}}};
    std::sort(w.begin(), w.end());
    std::array<int64_t, 6> key{-1, 0, -1, 0, -1, 0};
    int k = 0;
    Vec3d p{0, 0, 0};
    for (const auto& [corner, weight] : w) {
      if (weight == 0) continue;
      key[size_t(2 * k)] = corner;
      key[size_t(2 * k + 1)] = weight;
      ++k;
      p += static_cast<double>(weight) * ico[size_t(corner)];
    }
    auto [it, inserted] = index.emplace(key, static_cast<int32_t>(out.points.size()));
    if (inserted) out.points.push_back(p / norm(p));
    return it->second;
  };
  for (const auto& f : faces)
    for (int i = 0; i < n; ++i)
      for (int j = 0; i + j < n; ++j) {
        const int32_t p00 = point(f, n - i - j, i, j), p10 = point(f, n - i - 1 - j, i + 1, j),
                      p01 = point(f, n - i - j - 1, i, j + 1);
        out.triangles.push_back({p00, p10, p01});
        if (i + j + 2 <= n) {
          const int32_t p11 = point(f, n - i - j - 2, i + 1, j + 1);
          out.triangles.push_back({p10, p11, p01});
        }
      }
  orient_outward(out.points, out.triangles);
  for (const Triangle& t : out.triangles)
    for (int c = 0; c < 3; ++c) out.springs.push_back({t[size_t(c)], t[size_t((c + 1) % 3)]});
  sort_unique(out.springs);
  out.kappa = 3.0;
  return out;
}

// Asgari et al.'s latitude-longitude grid about `axis`: n_lat rings of n_lon particles between two
// poles; springs to the four grid neighbours (each pole to its whole ring); the quads split into
// two triangles for the volume and the contact surface (the diagonals carry no spring).
Layout lat_long(int n_lat, int n_lon, Vec3d axis) {
  const Vec3d e3 = axis / norm(axis);
  const Vec3d trial = std::fabs(e3.x) < 0.9 ? Vec3d{1, 0, 0} : Vec3d{0, 1, 0};
  const Vec3d e1p = trial - dot(trial, e3) * e3;
  const Vec3d e1 = e1p / norm(e1p);
  const Vec3d e2 = cross(e3, e1);
  Layout out;
  out.points.push_back(e3);
  for (int k = 1; k <= n_lat; ++k) {
    const double theta = kPi * k / (n_lat + 1);
    for (int m = 0; m < n_lon; ++m) {
      const double ph = 2.0 * kPi * m / n_lon;
      out.points.push_back(std::sin(theta) * (std::cos(ph) * e1 + std::sin(ph) * e2) +
                           std::cos(theta) * e3);
    }
  }
  out.points.push_back(-1.0 * e3);
  const int32_t south = static_cast<int32_t>(out.points.size() - 1);
  auto id = [n_lon](int k, int m) { return static_cast<int32_t>(1 + (k - 1) * n_lon + (m % n_lon)); };
  for (int m = 0; m < n_lon; ++m) {
    out.springs.push_back({0, id(1, m)});
    out.springs.push_back({id(n_lat, m), south});
    out.triangles.push_back({0, id(1, m), id(1, m + 1)});
    out.triangles.push_back({id(n_lat, m), south, id(n_lat, m + 1)});
    for (int k = 1; k <= n_lat; ++k) {
      out.springs.push_back({id(k, m), id(k, m + 1)});
      if (k < n_lat) {
        out.springs.push_back({id(k, m), id(k + 1, m)});
        out.triangles.push_back({id(k, m), id(k + 1, m), id(k + 1, m + 1)});
        out.triangles.push_back({id(k, m), id(k + 1, m + 1), id(k, m + 1)});
      }
    }
  }
  orient_outward(out.points, out.triangles);
  sort_unique(out.springs);
  out.kappa = 2.0;
  return out;
}

// CSR of (particle -> values) from pairs, each list ascending.
void build_csr(size_t count, std::vector<std::pair<int32_t, int32_t>> pairs,
               std::vector<int32_t>& offsets, std::vector<int32_t>& values) {
  std::sort(pairs.begin(), pairs.end());
  offsets.assign(count + 1, 0);
  for (const auto& p : pairs) ++offsets[size_t(p.first) + 1];
  for (size_t i = 0; i < count; ++i) offsets[i + 1] += offsets[i];
  values.resize(pairs.size());
  for (size_t e = 0; e < pairs.size(); ++e) values[e] = pairs[e].second;
}

Status check_positive(const char* key, double value) {
  if (!(value > 0) || !std::isfinite(value))
    return make_error("particles.%s must be > 0 and finite, got %g", key, value);
  return {};
}

Status check_non_negative(const char* key, double value) {
  if (!(value >= 0) || !std::isfinite(value))
    return make_error("particles.%s must be >= 0 and finite, got %g", key, value);
  return {};
}

}  // namespace

// ---------------------------------------------------------------------------------------------
// Build.

ParticleStepBound particle_critical_step(const ParticleModel& pm, std::span<const double> mass) {
  ParticleStepBound b;
  const size_t n = static_cast<size_t>(pm.membrane_count);
  const double mc = mass[n];
  double centre_k = 0, centre_c = 0;
  std::vector<Vec3d> gradient(n, Vec3d{0, 0, 0});
  for (const Triangle& t : pm.triangles) {
    const Vec3d g = triangle_area_vector(pm.rest_positions[size_t(t[0])], pm.rest_positions[size_t(t[1])],
                                         pm.rest_positions[size_t(t[2])]) / 3.0;
    for (int32_t p : t) gradient[size_t(p)] += g;
  }
  double hydraulic = 0;
  for (size_t i = 0; i < n; ++i) {
    // Gershgorin row of M^-1/2 K M^-1/2 (and of the dashpot matrix): the diagonal block's norm
    // is at most sum k / m_i, each off-diagonal block's k / sqrt(m_i m_j).
    double k_row = 0, c_row = 0;
    const double mi = mass[i];
    for (int32_t e = pm.neighbor_offsets[i]; e < pm.neighbor_offsets[i + 1]; ++e) {
      const double mj = mass[size_t(pm.neighbor_index[size_t(e)])];
      const double w = 1.0 / mi + 1.0 / std::sqrt(mi * mj);
      k_row += pm.neighbor_stiffness[size_t(e)] * w;
      c_row += pm.neighbor_damping[size_t(e)] * w;
    }
    const double wc = 1.0 / mi + 1.0 / std::sqrt(mi * mc);
    k_row += pm.centre_stiffness[i] * wc;
    c_row += pm.centre_damping[i] * wc;
    b.spring_omega_sq = std::max(b.spring_omega_sq, k_row);
    b.dashpot_rate = std::max(b.dashpot_rate, c_row);
    const double w_centre = 1.0 / mc + 1.0 / std::sqrt(mi * mc);
    centre_k += pm.centre_stiffness[i] * w_centre;
    centre_c += pm.centre_damping[i] * w_centre;
    hydraulic += dot(gradient[i], gradient[i]) / mi;
  }
  b.spring_omega_sq = std::max(b.spring_omega_sq, centre_k);
  b.dashpot_rate = std::max(b.dashpot_rate, centre_c);
  // The same matrices written over edges, sum_e w_e b_e b_e^T with b_e = e_i/sqrt(m_i) -
  // e_j/sqrt(m_j): Gershgorin on the edge-space matrix gives max_e sqrt(w_e) (S_i/m_i + S_j/m_j),
  // S_p the sum of sqrt(w) over p's edges. Both bounds hold; the smaller is kept. The edge form
  // is far tighter at the centre, whose N springs make its vertex row sqrt(N) times too large.
  std::vector<double> sk(n + 1, 0.0), sc(n + 1, 0.0);
  for (size_t i = 0; i < n; ++i) {
    for (int32_t e = pm.neighbor_offsets[i]; e < pm.neighbor_offsets[i + 1]; ++e) {
      sk[i] += std::sqrt(pm.neighbor_stiffness[size_t(e)]);
      sc[i] += std::sqrt(pm.neighbor_damping[size_t(e)]);
    }
    sk[i] += std::sqrt(pm.centre_stiffness[i]);
    sc[i] += std::sqrt(pm.centre_damping[i]);
    sk[n] += std::sqrt(pm.centre_stiffness[i]);
    sc[n] += std::sqrt(pm.centre_damping[i]);
  }
  double edge_k = 0, edge_c = 0;
  for (size_t i = 0; i < n; ++i) {
    for (int32_t e = pm.neighbor_offsets[i]; e < pm.neighbor_offsets[i + 1]; ++e) {
      const size_t j = size_t(pm.neighbor_index[size_t(e)]);
      edge_k = std::max(edge_k, std::sqrt(pm.neighbor_stiffness[size_t(e)]) * (sk[i] / mass[i] + sk[j] / mass[j]));
      edge_c = std::max(edge_c, std::sqrt(pm.neighbor_damping[size_t(e)]) * (sc[i] / mass[i] + sc[j] / mass[j]));
    }
    edge_k = std::max(edge_k, std::sqrt(pm.centre_stiffness[i]) * (sk[i] / mass[i] + sk[n] / mc));
    edge_c = std::max(edge_c, std::sqrt(pm.centre_damping[i]) * (sc[i] / mass[i] + sc[n] / mc));
  }
  b.spring_omega_sq = std::min(b.spring_omega_sq, edge_k);
  b.dashpot_rate = std::min(b.dashpot_rate, edge_c);
  // The hydraulic stiffness (1/(beta V0)) g g^T is rank one: its eigenvalue is exact, and the
  // largest eigenvalue of a sum of PSD matrices is at most the sum of theirs.
  b.hydraulic_omega_sq = hydraulic / (pm.compressibility * pm.rest_volume);
  const double g = b.spring_omega_sq + b.hydraulic_omega_sq, c = b.dashpot_rate;
  b.dt_critical = g > 0 ? (-c + std::sqrt(c * c + 4.0 * g)) / g : 2.0 / std::max(c, 1e-300);
  return b;
}

Result<ParticleModel> build_particle_model(const ParticleModelDesc& d) {
  if (Status s = check_positive("radius", d.radius); !s) return s.error();
  if (Status s = check_positive("membrane_modulus", d.membrane_modulus); !s) return s.error();
  if (Status s = check_positive("compressibility", d.compressibility); !s) return s.error();
  if (Status s = check_positive("areal_density", d.areal_density); !s) return s.error();
  if (Status s = check_non_negative("membrane_relaxation_time", d.membrane_relaxation_time); !s) return s.error();
  if (Status s = check_non_negative("radial_stiffness", d.radial_stiffness); !s) return s.error();
  if (Status s = check_non_negative("radial_damping", d.radial_damping); !s) return s.error();
  if (Status s = check_non_negative("centre_mass", d.centre_mass); !s) return s.error();
  for (int a = 0; a < 3; ++a)
    if (Status s = check_non_negative("damping", d.damping[a]); !s) return s.error();
  if (d.target_particles < 12 || d.target_particles > 4'000'000)
    return make_error("particles.particles must be in [12, 4000000], got %lld",
                      static_cast<long long>(d.target_particles));
  if (!(norm(d.pole_axis) > 0)) return make_error("particles.pole_axis must not be zero");
  if (!(d.dt_safety > 0 && d.dt_safety <= 1))
    return make_error("integrator.dt_safety must be in (0, 1], got %g", d.dt_safety);
  if (!(d.mass_scaling >= 1)) return make_error("integrator.mass_scaling must be >= 1, got %g", d.mass_scaling);
  if (!(d.dt >= 0) || !(d.target_dt >= 0)) return make_error("integrator: dt and target_dt must be >= 0");

  // Layout on the unit sphere, scaled to the radius.
  Layout layout;
  const double target = static_cast<double>(d.target_particles);
  if (d.layout == ParticleLayout::kIcosphere) {
    layout = icosphere(std::max(1, static_cast<int>(std::lround(std::sqrt((target - 2) / 10)))));
  } else {
    // n_lat rings of n_lon = 2 (n_lat + 1) (square cells at the equator): 2 n (n + 1) + 2.
    const int n_lat = std::max(2, static_cast<int>(std::lround((-1 + std::sqrt(1 + 2 * (target - 2))) / 2)));
    layout = lat_long(n_lat, 2 * (n_lat + 1), d.pole_axis);
  }
  ParticleModel pm;
  pm.layout = d.layout;
  pm.membrane_count = static_cast<int32_t>(layout.points.size());
  pm.centre = pm.membrane_count;
  const size_t n = layout.points.size();
  pm.rest_positions.resize(n + 1);
  for (size_t i = 0; i < n; ++i) pm.rest_positions[i] = d.radius * layout.points[i];
  pm.rest_positions[n] = Vec3d{0, 0, 0};
  pm.triangles = std::move(layout.triangles);
  pm.springs = std::move(layout.springs);
  pm.compressibility = d.compressibility;
  pm.radius = d.radius;
  pm.membrane_modulus = d.membrane_modulus;

  // Areas and volume at rest.
  pm.area.assign(n, 0.0);
  std::vector<int32_t> degree(n, 0);
  std::vector<std::pair<int32_t, int32_t>> around;  // (particle, triangle)
  for (size_t t = 0; t < pm.triangles.size(); ++t) {
    const Triangle& tri = pm.triangles[t];
    const Vec3d a = pm.rest_positions[size_t(tri[0])], b = pm.rest_positions[size_t(tri[1])],
                c = pm.rest_positions[size_t(tri[2])];
    const double area = norm(triangle_area_vector(a, b, c));
    pm.rest_area += area;
    pm.rest_volume += triangle_volume_term(a, b, c);
    for (int32_t p : tri) {
      pm.area[size_t(p)] += area / 3.0;
      around.emplace_back(p, static_cast<int32_t>(t));
    }
  }
  build_csr(n, std::move(around), pm.triangle_offsets, pm.particle_triangles);

  // Membrane springs, both directions, from the 2D modulus.
  std::vector<std::pair<int32_t, int32_t>> pairs;
  for (const auto& s : pm.springs) {
    ++degree[size_t(s[0])];
    ++degree[size_t(s[1])];
    pairs.emplace_back(s[0], s[1]);
    pairs.emplace_back(s[1], s[0]);
  }
  build_csr(n, pairs, pm.neighbor_offsets, pm.neighbor_index);
  const size_t entries = pm.neighbor_index.size();
  pm.neighbor_rest_length.resize(entries);
  pm.neighbor_stiffness.resize(entries);
  pm.neighbor_damping.resize(entries);
  pm.min_spring_length = 1e300;
  pm.max_spring_length = 0;
  for (size_t i = 0; i < n; ++i)
    for (int32_t e = pm.neighbor_offsets[i]; e < pm.neighbor_offsets[i + 1]; ++e) {
      const size_t j = size_t(pm.neighbor_index[size_t(e)]);
      const double length = norm(pm.rest_positions[j] - pm.rest_positions[i]);
      const double k = layout.kappa * d.membrane_modulus *
                       (pm.area[i] / degree[i] + pm.area[j] / degree[j]) / (length * length);
      pm.neighbor_rest_length[size_t(e)] = length;
      pm.neighbor_stiffness[size_t(e)] = k;
      pm.neighbor_damping[size_t(e)] = d.membrane_relaxation_time * k;
      pm.min_spring_length = std::min(pm.min_spring_length, length);
      pm.max_spring_length = std::max(pm.max_spring_length, length);
    }
  pm.centre_rest_length.resize(n);
  pm.centre_stiffness.resize(n);
  pm.centre_damping.resize(n);
  for (size_t i = 0; i < n; ++i) {
    pm.centre_rest_length[i] = norm(pm.rest_positions[i]);
    pm.centre_stiffness[i] = d.radial_stiffness * pm.area[i];
    pm.centre_damping[i] = d.radial_damping * pm.area[i];
  }

  // Masses and eq. 5's damping.
  pm.mass.resize(n + 1);
  pm.damping.assign(n + 1, Vec3d{0, 0, 0});
  double membrane_mass = 0;
  for (size_t i = 0; i < n; ++i) {
    pm.mass[i] = d.areal_density * pm.area[i];
    membrane_mass += pm.mass[i];
    pm.damping[i] = Vec3d{d.damping.x * pm.area[i], d.damping.y * pm.area[i], d.damping.z * pm.area[i]};
  }
  pm.mass[n] = d.centre_mass > 0 ? d.centre_mass : membrane_mass;

  // Stable step and mass scaling: with every mass times s, G_k and G_c fall by s, so the step
  // reaching t solves (G_k t^2 + 2 G_c t) / s = 4.
  const ParticleStepBound unit = particle_critical_step(pm, pm.mass);
  double scaling = d.mass_scaling;
  if (d.target_dt > 0) {
    const double t = d.target_dt / d.dt_safety;
    const double g = unit.spring_omega_sq + unit.hydraulic_omega_sq;
    scaling = std::max(scaling, (g * t * t + 2.0 * unit.dashpot_rate * t) / 4.0 * (1.0 + 1e-12));
  }
  if (scaling != 1.0)
    for (double& m : pm.mass) m *= scaling;
  pm.mass_scaling = scaling;
  pm.dt_critical = particle_critical_step(pm, pm.mass).dt_critical;
  if (d.dt > 0) {
    if (d.dt > pm.dt_critical)
      return make_error("integrator.dt %g s is above the particle model's critical step %g s",
                        d.dt, pm.dt_critical);
    pm.dt = d.dt;
  } else {
    pm.dt = d.dt_safety * pm.dt_critical;
  }
  return pm;
}

Result<ParticleModelDesc> particle_desc_from_scene(const Scene& scene) {
  if (scene.mesh.source != MeshSource::kGenerate)
    return make_error("%s: model 'particles' builds its own sphere: give mesh.generate.diameter, "
                      "not a mesh file", scene.name.c_str());
  const Vec3d k = scene.mesh.generate.radii_scale;
  if (k.x != 1.0 || k.y != 1.0 || k.z != 1.0)
    return make_error("%s: model 'particles' is a sphere: mesh.generate.radii_scale must be 1",
                      scene.name.c_str());
  const ParticlesDef& p = scene.particles;
  ParticleModelDesc d;
  d.radius = scene.mesh.generate.diameter / 2;
  d.layout = p.layout;
  d.target_particles = p.particles;
  d.pole_axis = p.pole_axis;
  d.membrane_modulus = p.membrane_modulus;
  d.membrane_relaxation_time = p.membrane_relaxation_time;
  d.radial_stiffness = p.radial_stiffness;
  d.radial_damping = p.radial_damping;
  d.damping = p.damping;
  d.compressibility = p.compressibility;
  d.areal_density = p.areal_density;
  d.centre_mass = p.centre_mass;
  const IntegratorDef& in = scene.integrator;
  d.dt = in.dt ? *in.dt : 0.0;
  d.dt_safety = in.dt_safety;
  d.mass_scaling = in.mass_scaling;
  d.target_dt = in.target_dt ? *in.target_dt : 0.0;
  return d;
}

// ---------------------------------------------------------------------------------------------
// The body: mesh and shared Model.

Mesh particle_body_mesh(const ParticleModel& pm) {
  Mesh mesh;
  mesh.rest_positions = pm.rest_positions;
  mesh.tets.reserve(pm.triangles.size());
  for (const Triangle& t : pm.triangles) mesh.tets.push_back({pm.centre, t[0], t[1], t[2]});
  mesh.tet_region.assign(mesh.tets.size(), 0);
  mesh.regions.push_back(Region{0, "membrane"});
  return mesh;
}

Result<Model> particle_body_model(const ParticleModel& pm, const Mesh& mesh,
                                  std::span<const int32_t> fixed) {
  ModelDesc desc;
  desc.constitutive = ConstitutiveModel::kLinear;
  // Placeholder material: build_model needs one; its FEM forces are never evaluated.
  desc.material.young = 1.0;
  desc.material.poisson = 0.3;
  desc.material.density = 1.0;
  desc.fixed_vertices.assign(fixed.begin(), fixed.end());
  Result<Model> built = build_model(mesh, desc);
  if (!built.ok()) return built.error();
  Model model = std::move(*built);
  // The particle masses, step and damping replace the placeholder's.
  const size_t nv = model.vertex_count();
  model.vertex_mass = pm.mass;
  model.mass_scaling = pm.mass_scaling;
  model.dt = pm.dt;
  model.dt_critical = pm.dt_critical;
  model.dt_element_bound = pm.dt_critical;
  model.dt_altitude_estimate = 0;
  model.omega_max = 0;
  model.min_altitude = pm.min_spring_length;
  model.max_wave_speed = 0;
  model.energy_floor = pm.membrane_modulus * pm.rest_area * 1e-16;
  for (size_t v = 0; v < nv; ++v) {
    const Vec3d b = pm.damping[v];
    model.vertex_damping[v] = (b.x + b.y + b.z) / 3.0;
    const double m = model.vertex_mass[v], h = 0.5 * model.vertex_damping[v] * model.dt;
    model.vertex_coefficients[v] = VertexCoefficients{2.0 * m / (m + h), (m - h) / (m + h),
                                                      model.dt * model.dt / (m + h)};
  }
  return model;
}

// ---------------------------------------------------------------------------------------------
// Forces and the step.

double particle_volume(const ParticleModel& pm, std::span<const Vec3d> u) {
  double volume = 0;
  for (const Triangle& t : pm.triangles) {
    const size_t a = size_t(t[0]), b = size_t(t[1]), c = size_t(t[2]);
    volume += triangle_volume_term(pm.rest_positions[a] + u[a], pm.rest_positions[b] + u[b],
                                   pm.rest_positions[c] + u[c]);
  }
  return volume;
}

ParticleStepInfo particle_forces(const ParticleModel& pm, std::span<const Vec3d> u,
                                 std::span<const Vec3d> u_prev, double inv_dt,
                                 std::span<Vec3d> force) {
  ParticleStepInfo info;
  const std::vector<Vec3d>& x0 = pm.rest_positions;
  info.volume = particle_volume(pm, u);
  info.pressure = hydraulic_pressure(info.volume, pm.rest_volume, pm.compressibility);
  double energy = hydraulic_energy(info.volume, pm.rest_volume, pm.compressibility);
  const size_t n = size_t(pm.membrane_count), centre = size_t(pm.centre);
  auto velocity = [&](size_t p) { return inv_dt * (u[p] - u_prev[p]); };
  const Vec3d xc = x0[centre] + u[centre], vc = velocity(centre);
  const double third_pressure = info.pressure / 3.0;
  Vec3d centre_force{0, 0, 0};
  for (size_t i = 0; i < n; ++i) {
    const Vec3d xi = x0[i] + u[i], vi = velocity(i);
    Vec3d f{0, 0, 0};
    // Neighbour spring-dashpots (eqs. 2-4), in CSR order (the GPU sums in the same order).
    for (int32_t e = pm.neighbor_offsets[i]; e < pm.neighbor_offsets[i + 1]; ++e) {
      const size_t j = size_t(pm.neighbor_index[size_t(e)]);
      const Vec3d xj = x0[j] + u[j];
      f += particle_spring_force(xi, xj, vi, velocity(j), pm.neighbor_rest_length[size_t(e)],
                                 pm.neighbor_stiffness[size_t(e)], pm.neighbor_damping[size_t(e)]);
      if (j > i) energy += particle_spring_energy(xi, xj, pm.neighbor_rest_length[size_t(e)],
                                                  pm.neighbor_stiffness[size_t(e)]);
    }
    // The centre spring-dashpot; its reaction goes to the centre particle.
    const Vec3d fc = particle_spring_force(xi, xc, vi, vc, pm.centre_rest_length[i],
                                           pm.centre_stiffness[i], pm.centre_damping[i]);
    f += fc;
    centre_force -= fc;
    energy += particle_spring_energy(xi, xc, pm.centre_rest_length[i], pm.centre_stiffness[i]);
    // Hydraulic force (eq. 6): P dV/dx_i, with dV/dx_i a third of the adjacent area vectors.
    Vec3d g{0, 0, 0};
    for (int32_t e = pm.triangle_offsets[i]; e < pm.triangle_offsets[i + 1]; ++e) {
      const Triangle& t = pm.triangles[size_t(pm.particle_triangles[size_t(e)])];
      const size_t a = size_t(t[0]), b = size_t(t[1]), c = size_t(t[2]);
      g += triangle_area_vector(x0[a] + u[a], x0[b] + u[b], x0[c] + u[c]);
    }
    force[i] = f + third_pressure * g;
  }
  force[centre] = centre_force;
  info.elastic_energy = energy;
  return info;
}

namespace {
inline bool finite3(Vec3d a) { return std::isfinite(a.x) && std::isfinite(a.y) && std::isfinite(a.z); }
}  // namespace

StepStatus particle_step(const ParticleModel& pm, const Model& body, State& s, ParticleStepInfo* out) {
  if (body.dt > body.dt_critical && !body.unsafe_allow_dt_above_critical) return kStepDtAboveCritical;
  const double dt = body.dt, inv_dt = 1.0 / dt, half_inv_dt = 0.5 / dt;
  StepDiagnostics& d = s.diag;

  // 1. Forces at u_n (dashpots on the last step's velocity), volume and pressure.
  const ParticleStepInfo info = particle_forces(pm, s.u, s.u_prev, inv_dt, s.force);
  if (out) *out = info;
  d.elastic_energy = info.elastic_energy;
  d.element_health = 0;
  d.inverted_count = d.collapsing_count = d.clamped_count = 0;
  d.first_inverted = d.first_collapsing = -1;

  // 2. Centred difference of free particles with eq. 5's damping centred-implicit per axis.
  double kinetic = 0, work = 0, residual_sq = 0, reference_sq = 0;
  int64_t first_nonfinite = -1;
  const size_t nv = body.vertex_count();
  for (size_t v = 0; v < nv; ++v) {
    const Vec3d f = s.force[v], ext = s.external_force[v];
    Vec3d next = s.u[v];
    if (s.vertex_constraint[v] == kVertexFree) {
      const Vec3d total = f + ext, un = s.u[v], up = s.u_prev[v], b = pm.damping[v];
      const double m = pm.mass[v];
      next = Vec3d{particle_update(un.x, up.x, total.x, m, b.x, dt),
                   particle_update(un.y, up.y, total.y, m, b.y, dt),
                   particle_update(un.z, up.z, total.z, m, b.z, dt)};
      const Vec3d du = next - up, vel = half_inv_dt * du;
      kinetic += 0.5 * m * dot(vel, vel);
      work += 0.5 * dot(ext, du);
      residual_sq += dot(total, total);
    } else {
      if (s.vertex_constraint[v] == kVertexFixed) next = Vec3d{0, 0, 0};
      reference_sq += dot(f, f);
    }
    reference_sq += dot(ext, ext);
    if (!finite3(next) && first_nonfinite < 0) first_nonfinite = static_cast<int64_t>(v);
    s.u_next[v] = next;
  }

  // 3. Prescribed particles at their targets; the constraint force is what their equation of
  //    motion leaves over, M a + B v - f - f_ext.
  Vec3d reaction{0, 0, 0};
  const double inv_dt2 = inv_dt * inv_dt;
  for (size_t k = 0; k < s.prescribed_vertices.size(); ++k) {
    const size_t v = size_t(s.prescribed_vertices[k]);
    const Vec3d next = s.prescribed_displacement[k], un = s.u[v], up = s.u_prev[v];
    s.u_next[v] = next;
    const Vec3d du = next - up, vel = half_inv_dt * du, acc = inv_dt2 * (next - 2.0 * un + up);
    const Vec3d b = pm.damping[v];
    const double m = pm.mass[v];
    const Vec3d r = m * acc + Vec3d{b.x * vel.x, b.y * vel.y, b.z * vel.z} - s.force[v] -
                    s.external_force[v];
    reaction += r;
    kinetic += 0.5 * m * dot(vel, vel);
    work += 0.5 * dot(r + s.external_force[v], du);
    if (!finite3(next) && (first_nonfinite < 0 || static_cast<int64_t>(v) < first_nonfinite))
      first_nonfinite = static_cast<int64_t>(v);
  }

  // 4. Diagnostics and flags (zona::step's rules).
  d.constraint_force = reaction;
  d.kinetic_energy = kinetic;
  d.step_input_work = work;
  d.first_nonfinite = first_nonfinite;
  d.residual_norm = std::sqrt(residual_sq);
  d.reference_force_norm = std::sqrt(reference_sq + dot(reaction, reaction));
  StepStatus status = kStepOk;
  const double energy = d.kinetic_energy + d.elastic_energy;
  if (first_nonfinite >= 0 || !std::isfinite(energy)) {
    status |= kStepNonFinite;
  } else {
    if (!s.energy_budget_valid) {
      d.energy_budget = energy;
      s.energy_budget_valid = true;
    }
    d.energy_budget += d.step_input_work;
    if (energy > body.energy_blowup_factor * std::max(d.energy_budget, body.energy_floor))
      status |= kStepEnergyBlowUp;
  }
  if (body.dt > body.dt_critical) status |= kStepDtAboveCritical;

  // 5. Accept u_{n+1}.
  if (!(status & kStepNotAdvanced)) {
    std::swap(s.u_prev, s.u);
    std::swap(s.u, s.u_next);
    s.time += dt;
    ++s.step_count;
  }
  return status;
}

std::string describe_particle_model(const ParticleModel& pm) {
  char line[400];
  std::snprintf(line, sizeof line,
                "particles (%s): %d membrane particles + centre, %zu springs, spacing %.3g-%.3g um, "
                "dt %.4g s (critical %.4g s), mass scaling %.4g",
                pm.layout == ParticleLayout::kIcosphere ? "icosphere" : "lat-long", pm.membrane_count,
                pm.spring_count(), pm.min_spring_length * 1e6, pm.max_spring_length * 1e6, pm.dt,
                pm.dt_critical, pm.mass_scaling);
  return line;
}

}  // namespace zona
