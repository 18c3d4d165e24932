// Selective (per-vertex) mass scaling to a target explicit step.
#include "engine/fem/mass_scaling.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <vector>

#include "engine/core/parallel.h"
#include "engine/fem/fem_element.h"

namespace zona {

double element_stiffness_measure(const TetShape<double>& shape, const Lame& lame) {
  Mat3d ggt = Mat3d::zero();
  for (int j = 0; j < 4; ++j) ggt = ggt + outer(shape.grad[j], shape.grad[j]);
  double eig[3];
  Mat3d vectors;
  symmetric_eigen3(ggt, eig, &vectors);
  return lame.lambda * trace(ggt) + 2.0 * lame.mu * std::max({eig[0], eig[1], eig[2]});
}

namespace {

// element_stiffness_measure of every tetrahedron, in ranges side by side (parallel.h).
std::vector<double> element_stiffness_measures(const Model& model, int threads) {
  std::vector<double> stiffness(model.tet_count(), 0.0);
  parallel_ranges(stiffness.size(), threads, 4096, [&](size_t, size_t begin, size_t end) {
    for (size_t t = begin; t < end; ++t)
      stiffness[t] = element_stiffness_measure(model.tet_shape[t], model.tet_lame(t));
  });
  return stiffness;
}

}  // namespace

Result<SelectiveScalingReport> apply_selective_mass_scaling(Model& model, double target_dt,
                                                            double dt_safety, int threads) {
  if (!(std::isfinite(target_dt) && target_dt > 0))
    return make_error("selective mass scaling: target_dt must be > 0 s, got %g", target_dt);
  if (!(std::isfinite(dt_safety) && dt_safety > 0 && dt_safety <= 1))
    return make_error("selective mass scaling: dt_safety must be in (0, 1], got %g", dt_safety);
  const size_t nv = model.vertex_count();
  const size_t nt = model.tet_count();
  SelectiveScalingReport report;

  // Lumped volume per vertex and each element's stiffness measure.
  const std::vector<double> lumped = vertex_lumped_volumes(model);
  const std::vector<double> stiffness = element_stiffness_measures(model, threads);

  // Each vertex needs mass per lumped volume of at least (dt_crit_target)^2 S_e for every element
  // around it, so that rho_e = min over corners >= dt_crit_target^2 S_e.
  const double crit = target_dt / dt_safety;
  std::vector<double> rate(nv, 0.0);  // damping rate gamma / M, kept
  int64_t raised = 0;
  for (size_t v = 0; v < nv; ++v) {
    const double m = model.vertex_mass[v];
    rate[v] = m > 0 ? model.vertex_damping[v] / m : 0.0;
    report.mass_before += m;
    double need = 0;
    for (int32_t k = model.adjacency.offsets[v]; k < model.adjacency.offsets[v + 1]; ++k)
      need = std::max(need, crit * crit * stiffness[static_cast<size_t>(model.adjacency.tets[static_cast<size_t>(k)])]);
    const double m_new = std::max(m, need * lumped[v]);
    if (m_new > m && lumped[v] > 0) {
      ++raised;
      if (m > 0) report.max_vertex_factor = std::max(report.max_vertex_factor, m_new / m);
      model.vertex_mass[v] = m_new;
    }
    model.vertex_damping[v] = rate[v] * model.vertex_mass[v];
    report.mass_after += model.vertex_mass[v];
  }
  report.scaled_fraction = nv > 0 ? static_cast<double>(raised) / static_cast<double>(nv) : 0.0;

  // The critical step of the new masses (element bound), the step and the coefficients.
  double dt_crit = std::numeric_limits<double>::infinity();
  for (size_t t = 0; t < nt; ++t) {
    double rho = std::numeric_limits<double>::infinity();
    for (int32_t v : model.tets[t])
      if (lumped[static_cast<size_t>(v)] > 0)
        rho = std::min(rho, model.vertex_mass[static_cast<size_t>(v)] / lumped[static_cast<size_t>(v)]);
    dt_crit = std::min(dt_crit, std::sqrt(rho / stiffness[t]));
  }
  model.dt_critical = dt_crit;
  model.dt_element_bound = dt_crit;
  model.omega_max = 0;
  model.dt = dt_safety * dt_crit;
  model.mass_scaling = report.mass_before > 0 ? report.mass_after / report.mass_before : 1.0;
  for (size_t v = 0; v < nv; ++v)
    model.vertex_coefficients[v] =
        vertex_coefficients(model.vertex_mass[v], model.vertex_damping[v], model.dt);
  return report;
}

double selective_scaling_total_mass(const Model& model, double target_dt, double dt_safety,
                                    std::vector<double>* need, int threads) {
  const size_t nv = model.vertex_count();
  if (need->size() != nv) {
    const std::vector<double> lumped = vertex_lumped_volumes(model);
    // Each element's measure once (an eigenvalue problem; per vertex and element, four times
    // over, it was 2.7 s of a 1M-vertex cell's setup).
    const std::vector<double> stiffness = element_stiffness_measures(model, threads);
    need->assign(nv, 0.0);
    for (size_t v = 0; v < nv; ++v) {
      double s = 0;
      for (int32_t k = model.adjacency.offsets[v]; k < model.adjacency.offsets[v + 1]; ++k)
        s = std::max(s, stiffness[static_cast<size_t>(model.adjacency.tets[static_cast<size_t>(k)])]);
      (*need)[v] = s * lumped[v];
    }
  }
  const double crit = target_dt / dt_safety;
  double total = 0;
  for (size_t v = 0; v < nv; ++v) total += std::max(model.vertex_mass[v], crit * crit * (*need)[v]);
  return total;
}

std::vector<double> vertex_lumped_volumes(const Model& model) {
  std::vector<double> lumped(model.vertex_count(), 0.0);
  for (size_t t = 0; t < model.tet_count(); ++t) {
    const double quarter = model.tet_shape[t].volume / 4.0;
    for (int32_t v : model.tets[t]) lumped[static_cast<size_t>(v)] += quarter;
  }
  return lumped;
}

VertexCoefficients vertex_coefficients(double mass, double gamma, double dt) {
  if (!(mass > 0)) return {1.0, 0.0, 0.0};
  const double denom = mass + 0.5 * gamma * dt;
  return {2.0 * mass / denom, (mass - 0.5 * gamma * dt) / denom, dt * dt / denom};
}

void set_vertex_mass(Model& model, size_t v, double mass) {
  const double m = model.vertex_mass[v];
  const double rate = m > 0 ? model.vertex_damping[v] / m : 0.0;
  model.vertex_mass[v] = mass;
  model.vertex_damping[v] = rate * mass;
  model.vertex_coefficients[v] = vertex_coefficients(mass, model.vertex_damping[v], model.dt);
}

}  // namespace zona
