// The linear solves of a Newton step, H d = -g on the assembled projected Hessian
// (block_sparse.h): a sparse direct factorisation (the exact oracle) or the preconditioned
// conjugate gradient (the fast path), its preconditioner behind an interface so that the
// multigrid chosen in docs/static.md drops in beside the block Jacobi one.
#pragma once

#include <memory>
#include <span>
#include <string>
#include <vector>

#include "engine/core/base.h"
#include "engine/core/block_sparse.h"

namespace zona {

/// z = M^-1 r for a symmetric positive definite approximation M of the matrix given to setup.
class Preconditioner {
 public:
  virtual ~Preconditioner() = default;
  virtual const char* name() const = 0;
  /// Builds from the matrix (after its mask).
  virtual Status setup(const BlockSparseMatrix& a) = 0;
  /// Takes a matrix of the pattern of the last setup whose values moved a little (the next
  /// Newton iteration's): whatever is cheap to redo is redone, the rest is kept from the last
  /// setup, and M stays symmetric positive definite. By default the whole setup.
  virtual Status refresh(const BlockSparseMatrix& a) { return setup(a); }
  virtual void apply(std::span<const Vec3d> r, std::span<Vec3d> z) const = 0;
  /// Where M^-1 is block diagonal (z_i = B_i r_i): the blocks B_i, so that CG can fuse the
  /// application into its vector passes; null otherwise.
  virtual const Mat3d* diagonal_blocks() const { return nullptr; }
  /// Its structure after a setup, for benchmarks and traces ("" by default); the multigrid's:
  /// each level's block rows and blocks.
  virtual std::string structure() const { return {}; }
};

/// The inverse of each vertex's 3 x 3 diagonal block.
std::unique_ptr<Preconditioner> make_block_jacobi();

/// Inverts each 3 x 3 block in place, on the shared pool (the preconditioners' diagonal
/// blocks). Returns the first block whose inverse fails (not finite; with `positive`, not
/// positive definite), or blocks.size() when none does.
size_t invert_blocks(std::vector<Mat3d>& blocks, bool positive);

/// How a solve ended.
struct LinearSolveStats {
  int64_t iterations = 0;      ///< CG iterations (the direct solver's: CG on its factor)
  double relative_residual = 0;  ///< |H d + g| / |g| reached
  /// CG met a direction of non-positive curvature after its first iteration and returned the
  /// iterate before it (which descends where the matrix is the Hessian of an energy).
  bool truncated = false;
};

/// Solves a d = b.
class LinearSolver {
 public:
  virtual ~LinearSolver() = default;
  virtual const char* name() const = 0;
  /// Takes the matrix of this Newton iteration (masked; kept by reference until the solve).
  virtual Status setup(const BlockSparseMatrix& a) = 0;
  /// The same for a matrix close to the last setup's (Preconditioner::refresh); by default the
  /// whole setup.
  virtual Status refresh(const BlockSparseMatrix& a) { return setup(a); }
  /// Solves to a relative residual `tolerance` (the direct solver: to 1e-12 always); d is the
  /// starting guess on entry (CG), the solution on exit.
  virtual Result<LinearSolveStats> solve(std::span<const Vec3d> b, std::span<Vec3d> d,
                                         double tolerance) = 0;
};

/// The sparse direct solver, the exact oracle: CHOLMOD's supernodal Cholesky where the build has
/// libcholmod (ZONA_HAVE_CHOLMOD), else Eigen's simplicial LDL^T with AMD ordering (the pattern
/// analysed once). setup factors and refuses a matrix that is not positive definite; refresh
/// keeps the last factor, and solve finishes with CG on it to a relative residual of 1e-12,
/// factoring the current matrix where that CG does not converge in 40 iterations.
std::unique_ptr<LinearSolver> make_direct_solver();
/// A note for a run that uses the direct solver ("" when there is nothing to say): where its
/// BLAS is OpenBLAS and OPENBLAS_THREAD_TIMEOUT is unset, the spinning of its idle threads.
std::string direct_solver_note();
/// CG preconditioned by `preconditioner`, at most max_iterations.
std::unique_ptr<LinearSolver> make_cg_solver(std::unique_ptr<Preconditioner> preconditioner,
                                             int64_t max_iterations);

}  // namespace zona
