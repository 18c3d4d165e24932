// The multigrid preconditioner of the static solver's CG (docs/static.md, "Preconditioner: the
// measurements"): geometric multigrid with an embedding prolongation. The mesh is not nested
// in anything coarser, so each vertex is embedded in a uniform lattice (spacing a few mean edge
// lengths) and a displacement on the lattice's nodes is interpolated to it trilinearly; each
// coarser level is the lattice of twice the spacing, interpolated to the finer lattice's nodes
// the same way. Coarse operators are Galerkin (P^T A P, kept in 3 x 3 blocks, so every level is
// a BlockSparseMatrix; the finest level's rank-one part, nodal pressure's terms, is restricted
// and added into the first coarse level's blocks, so no coarser level keeps one), the smoother is a Chebyshev polynomial in the block-Jacobi-scaled
// operator, and the coarsest level is solved densely. One V-cycle is a fixed symmetric positive
// definite operator, as CG needs.
//
// The lattices and the patterns of the coarse operators are built once, at the first setup, from
// the positions given at construction (the rest positions: trilinear interpolation reproduces
// every affine displacement of them, the rigid motions of the rest shape included); each later
// setup recomputes only the values (the Galerkin products, the smoother's spectral bounds, the
// coarse factorisation).
#pragma once

#include <cstdint>
#include <memory>
#include <span>

#include "engine/core/vec.h"
#include "engine/solver/linear_solver.h"

namespace zona {

/// The hierarchy's settings (the defaults are the ones measured in docs/static.md).
struct MultigridOptions {
  /// The finest lattice's spacing over the mean distance between coupled vertices [-].
  double spacing_factor = 2.0;
  /// The coarsest level has at most this many unknowns (3 per node) and is solved densely.
  int64_t max_coarse_unknowns = 600;
  /// Chebyshev smoothing: degree (matrix products) before and after the coarse correction, and
  /// the interval [lambda_max / ratio, lambda_max] of D^-1 A it damps.
  int chebyshev_degree = 2;
  double chebyshev_ratio = 30.0;
  /// Power iterations estimating lambda_max(D^-1 A) per level and setup (warm-started from the
  /// last setup's vector), and the safety factor on the estimate.
  int power_iterations = 10;
  /// At each later setup, started from the last one's vector: at least this many, then on
  /// (up to power_iterations) until the estimate moves by under 1 % (the matrices of
  /// successive Newton iterations are close).
  int power_iterations_warm = 3;
  double lambda_safety = 1.1;
};

/// The lattice multigrid on a mesh with these vertex positions [m], (vertex_count), and `fixed`
/// (1: the vertex does not move, its masked row is the identity; empty: none), (vertex_count).
std::unique_ptr<Preconditioner> make_multigrid(std::span<const Vec3d> positions,
                                               std::span<const uint8_t> fixed,
                                               const MultigridOptions& options = {});

}  // namespace zona
