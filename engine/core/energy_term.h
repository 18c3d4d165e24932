// One physical term of the cell's total potential, as a static solver sees it: the energy, its
// gradient, a Hessian-vector product and the Hessian's 3 x 3 diagonal blocks, at a displacement
// field u [m], (vertex_count). Evaluating never changes the term (no friction anchor moves, no
// state advances: a line search evaluates many trial states); what a term keeps from step to
// step changes only in its owner's commit, after a step is accepted.
//
// The terms: the elastic energy (engine/fem/elastic_energy.h), the needle's and the holding
// rim's penalty contact with the rim's friction, and the suction (engine/tools/tool_terms.h).
// The explicit step evaluates the same laws per vertex through their host/device functions.
#pragma once

#include <span>

#include "engine/core/block_sparse.h"
#include "engine/core/vec.h"

namespace zona {

/// A term of the total potential. Arrays are (vertex_count); the add_ functions add into them.
class EnergyTerm {
 public:
  virtual ~EnergyTerm() = default;
  /// A short name for messages ("elastic", "needle contact", ...).
  virtual const char* name() const = 0;
  /// E(u) [J].
  virtual double energy(std::span<const Vec3d> u) = 0;
  /// Adds dE/du at u to g [N].
  virtual void add_gradient(std::span<const Vec3d> u, std::span<Vec3d> g) = 0;
  /// Adds (d^2 E / du^2) v to y [N], v [m].
  virtual void add_hessian_product(std::span<const Vec3d> u, std::span<const Vec3d> v,
                                   std::span<Vec3d> y) = 0;
  /// Adds the Hessian's diagonal 3 x 3 blocks to d [N/m].
  virtual void add_hessian_diagonal(std::span<const Vec3d> u, std::span<Mat3d> d) = 0;
  /// Adds the Hessian at u into h [N/m], exact or (`project`) with each of its pieces (an
  /// element, a contact point) projected to positive semi-definite (a projected Newton's
  /// matrix). The pattern must hold the blocks the term couples (ElasticEnergy::hessian_pattern
  /// holds every term's).
  virtual void add_hessian(std::span<const Vec3d> u, BlockSparseMatrix& h, bool project) = 0;
};

}  // namespace zona
