// build_model: validation, materials, lumped masses, damping, stable time step, precompute.
#include "engine/fem/model.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <limits>
#include <type_traits>

#include "engine/core/parallel.h"
#include "engine/fem/forces_cpu.h"
#include "engine/fem/mass_scaling.h"

namespace zona {
namespace {

bool finite_nonneg(double x) { return std::isfinite(x) && x >= 0; }

Status validate_desc(const Mesh& mesh, const ModelDesc& d) {
  if (mesh.tet_count() == 0) return make_error("model: the mesh has no tetrahedra");
  // The CPU passes address doubles with int32 offsets: cpu_tet_corner_offsets 3 v, and
  // AssemblyPlan::corner_code up to 4 (vertices + 4 tetrahedra) (every corner late).
  if (4.0 * (static_cast<double>(mesh.vertex_count()) +
             4.0 * static_cast<double>(mesh.tet_count())) > static_cast<double>(INT32_MAX))
    return make_error("model: %zu tetrahedra and %zu vertices, more than the CPU element pass's "
                      "int32 offsets address (4 (vertices + 4 tetrahedra) <= %d)",
                      mesh.tet_count(), mesh.vertex_count(), INT32_MAX);
  if (!mesh.tet_region.empty() && mesh.tet_region.size() != mesh.tet_count())
    return make_error("model: tet_region has %zu entries for %zu tetrahedra",
                      mesh.tet_region.size(), mesh.tet_count());
  if (Status s = validate_material(d.material, "material"); !s) return s;
  for (size_t i = 0; i < d.region_materials.size(); ++i) {
    const RegionMaterial& r = d.region_materials[i];
    const std::string what = "material of region " + std::to_string(r.region);
    if (Status s = validate_material(r.material, what); !s) return s;
    for (size_t j = 0; j < i; ++j)
      if (d.region_materials[j].region == r.region)
        return make_error("model: region %d has two materials", r.region);
  }
  if (!finite_nonneg(d.vertex_mass))
    return make_error("model: vertex_mass must be >= 0 kg (0: from density), got %g",
                      d.vertex_mass);
  if (!(std::isfinite(d.mass_scaling) && d.mass_scaling > 0))
    return make_error("model: mass_scaling must be > 0, got %g", d.mass_scaling);
  if (!finite_nonneg(d.target_dt))
    return make_error("model: target_dt must be >= 0 s, got %g", d.target_dt);
  if (!finite_nonneg(d.dt))
    return make_error("model: dt must be >= 0 s (0: automatic), got %g", d.dt);
  if (!(std::isfinite(d.dt_safety) && d.dt_safety > 0 && d.dt_safety <= 1))
    return make_error("model: dt_safety must be in (0, 1], got %g", d.dt_safety);
  if (!(std::isfinite(d.energy_blowup_factor) && d.energy_blowup_factor > 1))
    return make_error("model: energy_blowup_factor must be > 1, got %g", d.energy_blowup_factor);
  if (!(std::isfinite(d.clamp_stretch) && d.clamp_stretch > 0 && d.clamp_stretch < 1))
    return make_error("model: clamp_stretch must be in (0, 1), got %g", d.clamp_stretch);
  if (d.constitutive != ConstitutiveModel::kSvk && d.constitutive != ConstitutiveModel::kLinear &&
      d.constitutive != ConstitutiveModel::kStableNeoHookean)
    return make_error("model: constitutive model %d is none of svk (0), linear (1), neohookean (2)",
                      static_cast<int>(d.constitutive));
  if (d.constitutive == ConstitutiveModel::kStableNeoHookean &&
      d.formulation != Formulation::kGradient)
    return make_error(
        "model: the neohookean model has no mass-tensor form: use the gradient "
        "formulation");
  if (d.nodal_pressure && d.constitutive != ConstitutiveModel::kStableNeoHookean)
    return make_error("model: nodal pressure is implemented for the neohookean model only");
  if (!(d.nodal_stabilisation >= 0 && d.nodal_stabilisation < 1))
    return make_error("model: nodal_stabilisation %g outside [0, 1)", d.nodal_stabilisation);
  if (d.inversion == InversionHandling::kClampStretch &&
      (d.constitutive != ConstitutiveModel::kSvk || d.formulation != Formulation::kGradient))
    return make_error(
        "model: inversion-safe SVK (clamped stretches) needs the svk model in the gradient "
        "formulation");
  if (d.element_precision != ElementPrecision::kFloat64 &&
      d.element_precision != ElementPrecision::kFloat32)
    return make_error("model: element_precision %d is neither float64 (0) nor float32 (1)",
                      static_cast<int>(d.element_precision));
  if (d.element_precision == ElementPrecision::kFloat32 &&
      (d.formulation != Formulation::kGradient || d.inversion != InversionHandling::kReport))
    return make_error(
        "model: float32 element math is implemented for the gradient formulation without the "
        "stretch clamp only");
  if (d.element_precision == ElementPrecision::kFloat32 &&
      d.constitutive == ConstitutiveModel::kStableNeoHookean)
    return make_error(
        "model: float32 element math on the CPU is implemented for svk and linear "
        "only (neohookean runs in float64 on the CPU, float32 on the GPU)");
  for (int32_t v : d.fixed_vertices)
    if (v < 0 || static_cast<size_t>(v) >= mesh.vertex_count())
      return make_error("model: fixed vertex %d out of range [0, %zu)", v, mesh.vertex_count());
  return Status::ok_status();
}

// Largest face area of a tetrahedron [m^2]; the smallest altitude is 3 V / that area.
double max_face_area(const Vec3d p[4]) {
  static constexpr int kFaces[4][3] = {{1, 2, 3}, {0, 2, 3}, {0, 1, 3}, {0, 1, 2}};
  double a = 0;
  for (const auto& f : kFaces)
    a = std::max(a, 0.5 * norm(cross(p[f[1]] - p[f[0]], p[f[2]] - p[f[0]])));
  return a;
}

}  // namespace

Result<Model> build_model(const Mesh& mesh, const ModelDesc& desc) {
  const auto start = std::chrono::steady_clock::now();
  if (Status s = validate_desc(mesh, desc); !s) return s.error();
  const size_t nv = mesh.vertex_count();
  const size_t nt = mesh.tet_count();

  Model model;
  model.rest_positions = mesh.rest_positions;
  model.tets = mesh.tets;
  model.adjacency = build_vertex_tet_adjacency(mesh);
  model.constitutive = desc.constitutive;
  model.formulation = desc.formulation;
  model.inversion = desc.inversion;
  model.element_precision = desc.element_precision;
  model.clamp_stretch = desc.clamp_stretch;
  model.nodal_pressure = desc.nodal_pressure;
  model.nodal_stabilisation = desc.nodal_pressure ? desc.nodal_stabilisation : 0.0;
  model.energy_blowup_factor = desc.energy_blowup_factor;
  model.unsafe_allow_dt_above_critical = desc.unsafe_allow_dt_above_critical;

  // Materials: index 0 is the default, then one per region override.
  model.materials.push_back(desc.material);
  for (const RegionMaterial& r : desc.region_materials) model.materials.push_back(r.material);
  for (const Material& m : model.materials)
    model.material_lame.push_back(lame_from_young_poisson(m.young, m.poisson));
  model.tet_material.assign(nt, 0);
  if (!mesh.tet_region.empty())
    for (size_t t = 0; t < nt; ++t)
      for (size_t i = 0; i < desc.region_materials.size(); ++i)
        if (desc.region_materials[i].region == mesh.tet_region[t])
          model.tet_material[t] = static_cast<int32_t>(i + 1);

  // Rest geometry.
  const int threads = desc.precompute_threads;
  compute_tet_shapes(mesh, model.tet_shape, threads);
  for (size_t t = 0; t < nt; ++t)
    if (!(model.tet_shape[t].volume > 0) || !std::isfinite(model.tet_shape[t].volume))
      return make_error("model: tetrahedron %zu has rest volume %g m^3 (must be > 0; run "
                        "validate_mesh to repair orientation)",
                        t, model.tet_shape[t].volume);

  // Lumped masses and mass-weighted damping rates: each corner gets a quarter of its
  // tetrahedron. With a uniform vertex mass the damping rate is volume-weighted instead.
  std::vector<double> lumped_volume(nv, 0.0), mass(nv, 0.0), alpha_weight(nv, 0.0);
  double total_volume = 0;
  double min_mu = std::numeric_limits<double>::infinity();
  for (size_t t = 0; t < nt; ++t) {
    const Material& mat = model.materials[static_cast<size_t>(model.tet_material[t])];
    const double quarter = model.tet_shape[t].volume / 4.0;
    total_volume += model.tet_shape[t].volume;
    min_mu = std::min(min_mu, model.tet_lame(t).mu);
    const double corner_mass = desc.vertex_mass > 0 ? quarter : mat.density * quarter;
    for (int32_t v : mesh.tets[t]) {
      lumped_volume[v] += quarter;
      mass[v] += corner_mass;
      alpha_weight[v] += mat.damping * corner_mass;
    }
  }
  if (model.nodal_pressure) {
    model.vertex_inverse_volume.assign(nv, 0.0);
    model.vertex_lambda.assign(nv, 0.0);
    for (size_t t = 0; t < nt; ++t) {
      const double quarter = model.tet_shape[t].volume / 4.0;
      for (int32_t v : mesh.tets[t]) model.vertex_lambda[v] += quarter * model.tet_lame(t).lambda;
    }
    for (size_t v = 0; v < nv; ++v)
      if (lumped_volume[v] > 0) {
        model.vertex_inverse_volume[v] = 1.0 / lumped_volume[v];
        model.vertex_lambda[v] /= lumped_volume[v];
        model.vertex_lambda[v] *= 1.0 - model.nodal_stabilisation;  // exact where it is 0
      }
  }
  std::vector<double> alpha(nv, 0.0);
  for (size_t v = 0; v < nv; ++v) {
    alpha[v] = mass[v] > 0 ? alpha_weight[v] / mass[v] : 0.0;
    if (desc.vertex_mass > 0) mass[v] = lumped_volume[v] > 0 ? desc.vertex_mass : 0.0;
  }

  // Critical step before scaling. Element eigenvalue inequality: with the element's share of
  // each corner's mass, at least rho_e V / 4 where rho_e is the smallest effective density
  // M_v / V_v of its corners (= rho for density masses), omega_max^2 <= max_e omega_e^2, and
  // (Cauchy-Schwarz on tr(eps) = sum g_j.u_j, and |sym(U G^T)| <= |U| sigma_max(G)):
  //   omega_e^2 <= (4 / rho_e) (lambda sum_j |g_j|^2 + 2 mu lambda_max(G G^T)),
  // so dt_e = 2 / omega_e = sqrt(rho_e / (lambda sum|g|^2 + 2 mu lambda_max)). The altitude
  // estimate h / c_d is kept for reports (it is not a bound: docs/physics.md).
  // Stable neo-Hookean takes its own constants (mu_s = mu, lambda_s = lambda + mu): at rest its
  // tangent equals the linear one with (lambda, mu), so the larger lambda_s only shortens the
  // step (by ~1 % at nu = 0.49): a small margin for deformed elements, whose tangent is no
  // longer the rest one (dt_safety covers the rest, as for SVK's stiffening).
  const bool snh = desc.constitutive == ConstitutiveModel::kStableNeoHookean;
  // Per range of tetrahedra (parallel_ranges), combined in range order: min and max do not
  // depend on the split.
  struct StepBounds {
    double dt_bound = std::numeric_limits<double>::infinity();
    double dt_altitude = std::numeric_limits<double>::infinity();
    double min_altitude = std::numeric_limits<double>::infinity();
    double max_wave_speed = 0;
  };
  std::vector<StepBounds> bounds(parallel_range_count(nt, threads, 4096));
  parallel_ranges(nt, threads, 4096, [&](size_t range, size_t begin, size_t end) {
    StepBounds b;
    for (size_t t = begin; t < end; ++t) {
      const Tet& e = mesh.tets[t];
      const TetShape<double>& shape = model.tet_shape[t];
      const Lame& material_lame = model.tet_lame(t);
      const Lame lame =
          snh ? Lame{snh_lambda(material_lame.lambda, material_lame.mu), material_lame.mu}
              : material_lame;
      Vec3d p[4];
      double rho = std::numeric_limits<double>::infinity();
      for (int c = 0; c < 4; ++c) {
        p[c] = mesh.rest_positions[e[c]];
        rho = std::min(rho, mass[e[c]] / lumped_volume[e[c]]);
      }
      b.dt_bound =
          std::min(b.dt_bound, std::sqrt(rho / element_stiffness_measure(shape, lame)));
      const double h = 3.0 * shape.volume / max_face_area(p);
      const double cd = dilatational_wave_speed(lame, rho);
      b.min_altitude = std::min(b.min_altitude, h);
      b.max_wave_speed = std::max(b.max_wave_speed, cd);
      b.dt_altitude = std::min(b.dt_altitude, h / cd);
    }
    bounds[range] = b;
  });
  double dt_bound0 = std::numeric_limits<double>::infinity();
  double dt_altitude0 = std::numeric_limits<double>::infinity();
  model.min_altitude = std::numeric_limits<double>::infinity();
  model.max_wave_speed = 0;
  for (const StepBounds& b : bounds) {
    dt_bound0 = std::min(dt_bound0, b.dt_bound);
    dt_altitude0 = std::min(dt_altitude0, b.dt_altitude);
    model.min_altitude = std::min(model.min_altitude, b.min_altitude);
    model.max_wave_speed = std::max(model.max_wave_speed, b.max_wave_speed);
  }

  // Mass scaling: the requested factor, raised if a target step asks for more. A power-iteration
  // limit is not known yet here; the bound decides the factor (conservative).
  double scaling = desc.mass_scaling;
  if (desc.target_dt > 0) {
    const double needed = desc.target_dt / (desc.dt_safety * dt_bound0);
    scaling = std::max(scaling, needed * needed);
  }
  model.mass_scaling = scaling;
  model.dt_element_bound = dt_bound0 * std::sqrt(scaling);
  model.dt_altitude_estimate = dt_altitude0 * std::sqrt(scaling);
  model.max_wave_speed /= std::sqrt(scaling);

  // Masses, damping, fixed vertices; then the step and the centred-difference coefficients.
  model.vertex_mass.resize(nv);
  model.vertex_damping.resize(nv);
  model.vertex_coefficients.resize(nv);
  model.vertex_fixed.assign(nv, 0);
  for (int32_t v : desc.fixed_vertices) model.vertex_fixed[v] = 1;
  for (size_t v = 0; v < nv; ++v)
    if (model.vertex_fixed[v]) model.fixed_vertices.push_back(static_cast<int32_t>(v));
  for (size_t v = 0; v < nv; ++v) {
    model.vertex_mass[v] = mass[v] * scaling;
    model.vertex_damping[v] = alpha[v] * model.vertex_mass[v];
  }

  // The step: the bound, or 2 / omega_max from power iteration on the finished masses.
  model.dt_critical = model.dt_element_bound;
  if (desc.critical_step == CriticalStep::kPowerIteration) {
    model.omega_max = estimate_max_frequency(model, 300);
    if (model.omega_max > 0) model.dt_critical = 2.0 / model.omega_max;
  }
  model.dt = desc.dt > 0 ? desc.dt : desc.dt_safety * model.dt_critical;
  if (model.dt > model.dt_critical && !desc.unsafe_allow_dt_above_critical)
    return make_error(
        "model: dt %.4g s is above the critical step %.4g s (%s; h_min %.4g m, c_d %.4g m/s, "
        "mass scaling %g); use dt = 0 (automatic), a smaller dt, or mass scaling",
        model.dt, model.dt_critical,
        desc.critical_step == CriticalStep::kPowerIteration ? "2/omega_max" : "element bound",
        model.min_altitude, model.max_wave_speed, scaling);
  for (size_t v = 0; v < nv; ++v)
    model.vertex_coefficients[v] =
        vertex_coefficients(model.vertex_mass[v], model.vertex_damping[v], model.dt);

  model.energy_floor = min_mu * total_volume * 1e-16;

  // Lane-major batches of eight for the CPU's vectorised element passes: shape gradients of
  // corners 1-3 (the passes form H from edges and f_0 = -(f_1 + f_2 + f_3): grad[0] is never
  // read), volume and Lame coefficients, in float64 and (for the float32 pass) rounded to float; the
  // last batch repeats the last tetrahedron.
  const size_t batches = (nt + 7) / 8;
  auto fill_batches = [&](auto* data, size_t stride) {
    using T = std::remove_pointer_t<decltype(data)>;
    parallel_ranges(batches, threads, 512, [&](size_t, size_t begin, size_t end) {
      for (size_t b = begin; b < end; ++b)
        for (size_t l = 0; l < 8; ++l) {
          const size_t t = std::min(8 * b + l, nt - 1);
          T* out = data + b * stride + l;
          const TetShape<double>& shape = model.tet_shape[t];
          for (int j = 1; j < 4; ++j)
            for (int i = 0; i < 3; ++i)
              out[8 * (3 * (j - 1) + i)] = static_cast<T>(shape.grad[j][i]);
          out[8 * 9] = static_cast<T>(shape.volume);
          out[8 * 10] = static_cast<T>(model.tet_lame(t).lambda);
          out[8 * 11] = static_cast<T>(model.tet_lame(t).mu);
        }
    });
  };
  model.cpu_tet_batches.assign(batches * kCpuTetBatchStride, 0.0);
  fill_batches(model.cpu_tet_batches.data(), size_t{kCpuTetBatchStride});
  if (desc.element_precision == ElementPrecision::kFloat32) {
    model.cpu_tet_batches_f32.assign(batches * kCpuTetBatchStrideF32, 0.0f);
    fill_batches(model.cpu_tet_batches_f32.data(), size_t{kCpuTetBatchStrideF32});
  }
  model.cpu_tet_corner_offsets.assign(batches * kCpuTetOffsetStride, 0);
  for (size_t b = 0; b < batches; ++b)
    for (size_t l = 0; l < 8; ++l) {
      const size_t t = std::min(8 * b + l, nt - 1);
      for (int c = 0; c < 4; ++c)
        model.cpu_tet_corner_offsets[b * kCpuTetOffsetStride + 8 * c + l] = 3 * model.tets[t][c];
    }

  if (desc.formulation == Formulation::kTensorStored) {
    const auto tensor_start = std::chrono::steady_clock::now();
    compute_mass_tensors(model.tet_shape, model.tet_material, model.material_lame,
                         model.constitutive, model.tensors, threads);
    model.tensor_precompute_seconds =
        std::chrono::duration<double>(std::chrono::steady_clock::now() - tensor_start).count();
  }
  model.precompute_seconds =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  return model;
}

std::string describe_model(const Model& model, bool explicit_step) {
  const char* cm = model.constitutive == ConstitutiveModel::kSvk      ? "svk"
                   : model.constitutive == ConstitutiveModel::kLinear ? "linear"
                                                                      : "neohookean";
  const char* fm = model.formulation == Formulation::kGradient        ? "gradient"
                   : model.formulation == Formulation::kTensorStored ? "tensor_stored"
                                                                     : "tensor_rebuilt";
  char line[512];
  if (!explicit_step) {
    std::snprintf(line, sizeof line, "%zu vertices, %zu tets, %s%s, precompute %.3f ms",
                  model.vertex_count(), model.tet_count(), cm,
                  model.nodal_pressure ? " with nodal pressure" : "", model.precompute_seconds * 1e3);
    return line;
  }
  std::snprintf(line, sizeof line,
                "%zu vertices, %zu tets, %s%s (%s%s%s), dt %.4g s (critical %.4g s by %s; h_min %.4g m, "
                "c_d %.4g m/s), mass scaling %g, precompute %.3f ms",
                model.vertex_count(), model.tet_count(), cm,
                model.nodal_pressure ? " with nodal pressure" : "", fm,
                model.inversion == InversionHandling::kClampStretch ? ", clamped" : "",
                model.element_precision == ElementPrecision::kFloat32 ? ", float32 elements" : "",
                model.dt,
                model.dt_critical, model.omega_max > 0 ? "2/omega_max" : "element bound",
                model.min_altitude, model.max_wave_speed, model.mass_scaling,
                model.precompute_seconds * 1e3);
  return line;
}

}  // namespace zona
