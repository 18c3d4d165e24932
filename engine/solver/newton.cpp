// Projected Newton (newton.h).
#include "engine/solver/newton.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <string>

#include "engine/core/parallel.h"

namespace zona {

static_assert(sizeof(Vec3d) == 3 * sizeof(double), "Vec3d arrays are read as double arrays");

namespace {
// Vertices per range of the elementwise passes on the shared pool.
constexpr size_t kVertexRange = 4096;
}  // namespace

NewtonSolver::NewtonSolver(std::vector<EnergyTerm*> terms, BlockSparseMatrix pattern,
                           std::vector<uint8_t> fixed, std::unique_ptr<LinearSolver> linear,
                           NewtonOptions options)
    : terms_(std::move(terms)),
      h_(std::move(pattern)),
      fixed_(std::move(fixed)),
      linear_(std::move(linear)),
      options_(options) {
  ZONA_ASSERT(fixed_.size() == h_.rows());
  const size_t n = h_.rows();
  g_.resize(n);
  d_.resize(n);
  trial_.resize(n);
  rhs_.resize(n);
}

double NewtonSolver::evaluate(std::span<const Vec3d> u, std::span<Vec3d> g) {
  double e = 0;
  for (EnergyTerm* t : terms_) e += t->energy(u);
  if (!g.empty()) gradient(u, g);
  return e;
}

void NewtonSolver::gradient(std::span<const Vec3d> u, std::span<Vec3d> g) {
  pooled_ranges(g.size(), kVertexRange, [&](size_t, size_t begin, size_t end) {
    std::fill(g.begin() + static_cast<std::ptrdiff_t>(begin),
              g.begin() + static_cast<std::ptrdiff_t>(end), Vec3d{0, 0, 0});
  });
  for (EnergyTerm* t : terms_) t->add_gradient(u, g);
  pooled_ranges(g.size(), kVertexRange, [&](size_t, size_t begin, size_t end) {
    for (size_t i = begin; i < end; ++i)
      if (fixed_[i]) g[i] = Vec3d{0, 0, 0};
  });
}

const BlockSparseMatrix& NewtonSolver::hessian(std::span<const Vec3d> u, bool project) {
  h_.set_zero();
  for (EnergyTerm* t : terms_) t->add_hessian(u, h_, project);
  h_.apply_mask(fixed_);
  return h_;
}

size_t NewtonSolver::largest_imbalance_vertex(std::span<const Vec3d> g) const {
  size_t at = 0;
  double r = -1;
  for (size_t i = 0; i < g.size(); ++i)
    if (const double x = norm(g[i]); x > r) {
      r = x;
      at = i;
    }
  return at;
}

double NewtonSolver::max_imbalance(std::span<const Vec3d> g) const {
  return g.empty() ? 0.0 : norm(g[largest_imbalance_vertex(g)]);
}

NewtonStats NewtonSolver::solve(std::vector<Vec3d>& u, double tolerance) {
  NewtonStats stats;
  const size_t n = u.size();
  ZONA_ASSERT(n == h_.rows());
  double e = evaluate(u, g_);
  if (!std::isfinite(e)) {
    stats.failure = "the starting state has an infinite energy (a collapsed element)";
    return stats;
  }
  double gnorm = 0;
  for (const Vec3d& v : g_) gnorm += dot(v, v);
  gnorm = std::sqrt(gnorm);
  double gnorm_prev = 0, eta = options_.forcing_max;
  bool last_project = false;
  int64_t cg_at_setup = 0, last_cg = 0;
  stats.residual = max_imbalance(g_);
  stats.energy = e;
  auto clock_start = std::chrono::steady_clock::now();
  while (stats.residual > tolerance) {
    if (stats.iterations >= options_.max_iterations) {
      char line[200];
      std::snprintf(line, sizeof line,
                    "Newton did not converge in %d iterations (force imbalance %.3g N, "
                    "tolerance %.3g N)",
                    options_.max_iterations, stats.residual, tolerance);
      stats.failure = line;
      // Most iterations on an indefinite Hessian: the load step is too long or the state the
      // loading came up on is losing its stability (docs/static.md, "Stability").
      if (2 * stats.negative_curvature > stats.iterations)
        stats.failure += "; the Hessian had a direction of negative curvature in " +
                         std::to_string(stats.negative_curvature) +
                         " of them: the equilibrium may be losing its stability";
      if (options_.trace) std::fprintf(options_.trace, "newton end failed (iterations)\n");
      return stats;
    }
    // Forcing term: loose far from the answer, tight near it.
    if (stats.iterations > 0)
      eta = std::clamp(options_.forcing_gamma * std::pow(gnorm / gnorm_prev, options_.forcing_alpha),
                       options_.forcing_min, options_.forcing_max);
    // The exact Hessian first; the projected one where the exact one is not positive definite.
    double slope = 0;
    int64_t cg = 0;
    int project_used = 0;
    bool curvature = false;  // the exact Hessian has a direction of non-positive curvature
    int64_t probe_cg = -1;
    std::string why;
    for (bool project : {false, true}) {
      const BlockSparseMatrix& h = hessian(u, project);
      if (on_hessian) on_hessian(h, u, g_);
      // The preconditioner's whole setup at a solve's first iteration, on a change between the
      // exact and the projected Hessian, and where the last refreshed one let CG take more than
      // twice the iterations of the last whole setup; a refresh otherwise.
      const bool full = stats.iterations == 0 || project != last_project ||
                        last_cg > 2 * cg_at_setup + 4;
      last_project = project;
      if (Status st = full ? linear_->setup(h) : linear_->refresh(h); !st) {
        why = st.error().message;
        continue;
      }
      pooled_ranges(n, kVertexRange, [&](size_t, size_t begin, size_t end) {
        for (size_t i = begin; i < end; ++i) {
          rhs_[i] = -1.0 * g_[i];
          d_[i] = Vec3d{0, 0, 0};
        }
      });
      Result<LinearSolveStats> ls = linear_->solve(rhs_, d_, eta);
      if (!ls.ok()) {
        why = ls.error().message;
        continue;
      }
      cg += ls->iterations;
      last_cg = ls->iterations;
      if (!project && ls->truncated) curvature = true;
      if (options_.trace && options_.krylov_probe > 0) {
        probe_.assign(n, Vec3d{0, 0, 0});
        Result<LinearSolveStats> pr = linear_->solve(rhs_, probe_, options_.krylov_probe);
        probe_cg = pr.ok() ? pr->iterations : -1;
      }
      if (full) cg_at_setup = ls->iterations;
      slope = 0;
      for (size_t i = 0; i < n; ++i) slope += dot(g_[i], d_[i]);
      if (slope < 0) {
        stats.projected += project ? 1 : 0;
        project_used = project ? 1 : 0;
        break;
      }
      why = "the Newton direction does not descend";
    }
    stats.krylov += cg;
    if (curvature || project_used) ++stats.negative_curvature;
    if (!(slope < 0)) {
      stats.failure = "no Newton direction on the projected Hessian: " + why;
      return stats;
    }
    // Backtracking: halve until the energy falls enough, from the capped step.
    double alpha = 1, e_trial = 0;
    double longest = 0;  // the direction's longest vertex move [m], and its vertex
    size_t longest_at = 0;
    for (size_t i = 0; i < n; ++i)
      if (const double l = norm(d_[i]); l > longest) {
        longest = l;
        longest_at = i;
      }
    if (options_.max_displacement > 0 && longest > options_.max_displacement)
      alpha = options_.max_displacement / longest;
    const double alpha_start = alpha;
    for (;;) {
      pooled_ranges(n, kVertexRange, [&](size_t, size_t begin, size_t end) {
        for (size_t i = begin; i < end; ++i) trial_[i] = u[i] + alpha * d_[i];
      });
      e_trial = evaluate(trial_, {});
      if (std::isfinite(e_trial) && e_trial <= e + options_.armijo * alpha * slope) break;
      // At round-off the energy cannot tell; a full step that does not raise it is taken.
      if (alpha == alpha_start && std::isfinite(e_trial) &&
          std::fabs(e_trial - e) <= 1e-13 * std::fabs(e) + 1e-300)
        break;
      alpha *= 0.5;
      if (alpha < options_.min_step * alpha_start) {
        char line[200];
        std::snprintf(line, sizeof line,
                      "the line search found no lower energy along the Newton direction "
                      "(force imbalance %.3g N)",
                      stats.residual);
        stats.failure = line;
        if (options_.trace) std::fprintf(options_.trace, "newton end failed (line search)\n");
        return stats;
      }
    }
    if (options_.trace) {
      std::fprintf(options_.trace,
                   "newton iteration %d residual %.4e at_vertex %zu step %.4g of %.4g "
                   "energy_change %.4e slope %.4e cg %lld projected %d eta %.3g ms %.1f probe_cg %lld "
                   "longest %.3g at %zu\n",
                   stats.iterations, stats.residual, largest_imbalance_vertex(g_), alpha / alpha_start, alpha_start,
                   e_trial - e, slope, static_cast<long long>(cg), project_used, eta,
                   std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() -
                                                             clock_start).count(),
                   static_cast<long long>(probe_cg), longest, longest_at);
      clock_start = std::chrono::steady_clock::now();
    }
    u.swap(trial_);
    e = e_trial;  // the line search's energy at this state (the same sums)
    gradient(u, g_);
    gnorm_prev = gnorm;
    gnorm = 0;
    for (const Vec3d& v : g_) gnorm += dot(v, v);
    gnorm = std::sqrt(gnorm);
    stats.residual = max_imbalance(g_);
    stats.energy = e;
    ++stats.iterations;
  }
  stats.converged = true;
  if (options_.trace) std::fprintf(options_.trace, "newton end converged %d\n", stats.iterations);
  return stats;
}

}  // namespace zona
