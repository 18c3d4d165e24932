// Projected Newton on a sum of energy terms (engine/core/energy_term.h), projected where needed:
// each iteration assembles the exact Hessian and solves with it (CG truncated where it meets a
// direction of non-positive curvature after its first iteration, Steihaug's rule); where that
// gives no direction (that direction at CG's first iteration, the factorisation a non-positive
// pivot, or the step does not descend), the Hessian with every piece projected to positive
// semi-definite; it solves
// H d = -g
// (linear_solver.h) to a relative residual set by the Eisenstat-Walker forcing term, and takes
// the largest step of a backtracking line search that lowers the total energy (Armijo). The
// energy is +infinity at a collapsed element (the volume barrier), so no accepted state inverts
// one. Fixed vertices do not move.
//
// Converged (docs/static.md, "Converged"): the largest vertex force imbalance |g_v| over the
// free vertices at most `tolerance` [N].
#pragma once

#include <cstdint>
#include <cstdio>
#include <functional>
#include <span>
#include <string>
#include <vector>

#include "engine/core/base.h"
#include "engine/core/block_sparse.h"
#include "engine/core/energy_term.h"
#include "engine/solver/linear_solver.h"

namespace zona {

struct NewtonOptions {
  int max_iterations = 30;
  /// Eisenstat-Walker (choice 2): eta_k = gamma (|g_k| / |g_{k-1}|)^alpha, in [eta_min, eta_max].
  double forcing_gamma = 0.9, forcing_alpha = 2.0;
  double forcing_min = 1e-6, forcing_max = 0.1;
  /// Line search: sufficient decrease c1 and the smallest step tried.
  double armijo = 1e-4;
  double min_step = 1e-10;
  /// The line search starts from the step that moves no vertex farther than this [m]; 0: the
  /// full Newton step. A contact that the Hessian does not see yet (a point just outside a
  /// tool) and the cell's weakly held rigid motions make full steps overshoot by orders of
  /// magnitude; a cap of a fraction of the contact's length scale keeps each trial local.
  double max_displacement = 0;
  /// Where each iteration writes one line (its residual and the vertex it sits at, the line
  /// search's step, the energy change, CG iterations) and each solve its end; null: nowhere.
  /// The diagnostic of docs/static.md's "Cost" (ZONA_NEWTON_TRACE).
  std::FILE* trace = nullptr;
  /// With a trace, each iteration's system solved a second time from zero to this relative
  /// residual, its CG iterations traced as `probe_cg` (the preconditioner's count at a fixed
  /// tolerance, comparable across meshes; ZONA_KRYLOV_PROBE); 0: none. The step is unchanged.
  double krylov_probe = 0;
};

/// How a solve went.
struct NewtonStats {
  int iterations = 0;          ///< Newton iterations
  int projected = 0;           ///< of them, on the projected Hessian
  /// of them, where the exact Hessian showed a direction of non-positive curvature (CG
  /// truncated there, or no direction on it and the projected one taken)
  int negative_curvature = 0;
  int64_t krylov = 0;          ///< CG iterations summed over them
  double residual = 0;         ///< largest free vertex force imbalance at the end [N]
  double energy = 0;           ///< total energy at the end [J]
  bool converged = false;
  std::string failure;         ///< why not, one line
};

class NewtonSolver {
 public:
  /// `pattern`: holds every block the terms couple (ElasticEnergy::hessian_pattern); `fixed`:
  /// 1 for vertices that do not move, (vertex_count).
  NewtonSolver(std::vector<EnergyTerm*> terms, BlockSparseMatrix pattern,
               std::vector<uint8_t> fixed, std::unique_ptr<LinearSolver> linear,
               NewtonOptions options = {});

  NewtonOptions& options() { return options_; }
  /// Adds a term (its blocks must be in the pattern).
  void add_term(EnergyTerm* term) { terms_.push_back(term); }
  /// Minimises the terms' sum from u (updated in place) to the force tolerance [N].
  NewtonStats solve(std::vector<Vec3d>& u, double tolerance);

  /// Total energy [J] and, if g is non-empty, its gradient (fixed vertices zeroed) [N].
  double evaluate(std::span<const Vec3d> u, std::span<Vec3d> g);
  /// The Hessian at u, exact or projected, masked.
  const BlockSparseMatrix& hessian(std::span<const Vec3d> u, bool project);
  const char* linear_solver_name() const { return linear_->name(); }
  /// Called with each iteration's masked Hessian, state and gradient before its solve (the
  /// matrix export of docs/static.md's preconditioner study); empty: none.
  std::function<void(const BlockSparseMatrix&, std::span<const Vec3d> u,
                     std::span<const Vec3d> g)>
      on_hessian;

 private:
  // The gradient alone (fixed vertices zeroed) [N].
  void gradient(std::span<const Vec3d> u, std::span<Vec3d> g);
  double max_imbalance(std::span<const Vec3d> g) const;
  size_t largest_imbalance_vertex(std::span<const Vec3d> g) const;

  std::vector<EnergyTerm*> terms_;
  BlockSparseMatrix h_;
  std::vector<uint8_t> fixed_;
  std::unique_ptr<LinearSolver> linear_;
  NewtonOptions options_;
  std::vector<Vec3d> g_, d_, trial_, rhs_, probe_;
};

}  // namespace zona
