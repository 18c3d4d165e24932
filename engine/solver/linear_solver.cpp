// The linear solvers of a Newton step (linear_solver.h).
#include "engine/solver/linear_solver.h"

#include <cmath>

#include <Eigen/SparseCholesky>

#include "engine/core/parallel.h"
#ifdef ZONA_HAVE_CHOLMOD
#include <Eigen/CholmodSupport>
#endif

namespace zona {
namespace {

// Vertices per chunk of CG's vector passes (pooled_chunks: the same bits on any thread count).
constexpr size_t kVectorChunk = 4096;

class BlockJacobi final : public Preconditioner {
 public:
  const char* name() const override { return "block Jacobi"; }
  Status setup(const BlockSparseMatrix& a) override {
    a.diagonal(inverse_);
    for (size_t i = 0; i < inverse_.size(); ++i) {
      // (An indefinite block is kept: the exact Hessian's may be, and CG then reports the
      // direction of non-positive curvature it meets.)
      bool positive = false;
      inverse_[i] = inverse3(inverse_[i], &positive);
      for (int r = 0; r < 3; ++r)
        for (int c = 0; c < 3; ++c)
          if (!std::isfinite(inverse_[i].m[r][c]))
            return make_error("the Hessian's diagonal block of vertex %zu is singular", i);
    }
    return {};
  }
  void apply(std::span<const Vec3d> r, std::span<Vec3d> z) const override {
    pooled_chunks(r.size(), kVectorChunk, [&](size_t, size_t begin, size_t end) {
      for (size_t i = begin; i < end; ++i) z[i] = inverse_[i] * r[i];
    });
  }

 private:
  std::vector<Mat3d> inverse_;
};

// The exact oracle: CHOLMOD's supernodal Cholesky (Debian's libsuitesparse-dev, multithreaded
// through its BLAS) where the build found it, else Eigen's simplicial LDL^T. Both refuse a matrix
// that is not positive definite, so that Newton takes the projected Hessian instead.
class DirectSolver final : public LinearSolver {
 public:
#ifdef ZONA_HAVE_CHOLMOD
  // A matrix that is not positive definite is an answer here (Newton projects), not a warning.
  DirectSolver() {
    factor_.cholmod().print = 0;
  }
#endif
  const char* name() const override {
#ifdef ZONA_HAVE_CHOLMOD
    return "direct (CHOLMOD supernodal LL^T)";
#else
    return "direct (Eigen simplicial LDL^T)";
#endif
  }
  Status setup(const BlockSparseMatrix& a) override {
    matrix_ = a.to_eigen();
    if (!analysed_) {
      factor_.analyzePattern(matrix_);
      analysed_ = true;
    }
    factor_.factorize(matrix_);
#ifdef ZONA_HAVE_CHOLMOD
    if (factor_.info() != Eigen::Success)
      return make_error("the Hessian is not positive definite (CHOLMOD, %zu unknowns)",
                        static_cast<size_t>(matrix_.rows()));
#else
    if (factor_.info() != Eigen::Success)
      return make_error("the direct solver could not factor the Hessian (%zu unknowns)",
                        static_cast<size_t>(matrix_.rows()));
    if (!(factor_.vectorD().minCoeff() > 0))
      return make_error("the Hessian is not positive definite (a pivot of %.3g)",
                        factor_.vectorD().minCoeff());
#endif
    return {};
  }
  Result<LinearSolveStats> solve(std::span<const Vec3d> b, std::span<Vec3d> d,
                                 double) override {
    const Eigen::Index n = matrix_.rows();
    Eigen::Map<const Eigen::VectorXd> rhs(&b[0].x, n);
    Eigen::VectorXd x = factor_.solve(rhs);
    if (factor_.info() != Eigen::Success || !x.allFinite())
      return make_error("the direct solve of the Newton step failed");
    Eigen::Map<Eigen::VectorXd>(&d[0].x, n) = x;
    LinearSolveStats stats;
    const double bn = rhs.norm();
    stats.relative_residual = bn > 0 ? (matrix_ * x - rhs).norm() / bn : 0.0;
    return stats;
  }

 private:
  Eigen::SparseMatrix<double> matrix_;
#ifdef ZONA_HAVE_CHOLMOD
  Eigen::CholmodSupernodalLLT<Eigen::SparseMatrix<double>, Eigen::Lower> factor_;
#else
  Eigen::SimplicialLDLT<Eigen::SparseMatrix<double>, Eigen::Lower, Eigen::AMDOrdering<int> >
      factor_;
#endif
  bool analysed_ = false;
};

class CgSolver final : public LinearSolver {
 public:
  CgSolver(std::unique_ptr<Preconditioner> p, int64_t max_iterations)
      : preconditioner_(std::move(p)), max_iterations_(max_iterations) {
    name_ = std::string("CG, ") + preconditioner_->name();
  }
  const char* name() const override { return name_.c_str(); }
  Status setup(const BlockSparseMatrix& a) override {
    a_ = &a;
    const size_t n = a.rows();
    r_.resize(n);
    z_.resize(n);
    p_.resize(n);
    q_.resize(n);
    return preconditioner_->setup(a);
  }
  Status refresh(const BlockSparseMatrix& a) override {
    if (a_ == nullptr || a.rows() != r_.size()) return setup(a);
    a_ = &a;
    return preconditioner_->refresh(a);
  }
  Result<LinearSolveStats> solve(std::span<const Vec3d> b, std::span<Vec3d> x,
                                 double tolerance) override {
    const size_t n = b.size();
    a_->multiply(x, q_);
    // The vector passes on the shared pool, fused where they read the same vectors; their dot
    // products summed per fixed chunk, the chunks in order.
    const double bn = std::sqrt(pooled_chunk_sum(n, kVectorChunk, partial_, [&](size_t begin, size_t end) {
      double bb = 0;
      for (size_t i = begin; i < end; ++i) {
        r_[i] = b[i] - q_[i];
        bb += dot(b[i], b[i]);
      }
      return bb;
    }));
    LinearSolveStats stats;
    if (!(bn > 0)) {
      for (size_t i = 0; i < n; ++i) x[i] = Vec3d{0, 0, 0};
      return stats;
    }
    preconditioner_->apply(r_, z_);
    // r . z and r . r of the current r and z in one pass, each per chunk (partial_, rr_partial_).
    rr_partial_.resize(partial_.size());
    auto residual_dots = [&] {
      pooled_chunks(n, kVectorChunk, [&](size_t c, size_t begin, size_t end) {
        double rz = 0, rr = 0;
        for (size_t i = begin; i < end; ++i) {
          rz += dot(r_[i], z_[i]);
          rr += dot(r_[i], r_[i]);
        }
        partial_[c] = rz;
        rr_partial_[c] = rr;
      });
    };
    auto sum = [](const std::vector<double>& partial) {
      double total = 0;
      for (double value : partial) total += value;
      return total;
    };
    p_ = z_;
    residual_dots();
    double rz = sum(partial_);
    double rn = std::sqrt(sum(rr_partial_));
    while (rn > tolerance * bn) {
      if (stats.iterations >= max_iterations_)
        return make_error("CG (%s) did not reach a relative residual of %.3g in %lld iterations "
                          "(%.3g)",
                          preconditioner_->name(), tolerance,
                          static_cast<long long>(max_iterations_), rn / bn);
      a_->multiply(p_, q_);
      const double pq = pooled_chunk_sum(n, kVectorChunk, partial_, [&](size_t begin, size_t end) {
        double s = 0;
        for (size_t i = begin; i < end; ++i) s += dot(p_[i], q_[i]);
        return s;
      });
      if (!(pq > 0)) {
        // Truncated at the direction of non-positive curvature (Steihaug): the iterate so far
        // minimises the quadratic model over the directions CG has seen, where it is convex,
        // and descends; at the first iteration there is none, and the caller decides.
        if (stats.iterations == 0)
          return make_error("CG met a direction of non-positive curvature (%.3g)", pq);
        stats.relative_residual = rn / bn;
        stats.truncated = true;
        return stats;
      }
      const double alpha = rz / pq;
      pooled_chunks(n, kVectorChunk, [&](size_t, size_t begin, size_t end) {
        for (size_t i = begin; i < end; ++i) {
          x[i] += alpha * p_[i];
          r_[i] -= alpha * q_[i];
        }
      });
      preconditioner_->apply(r_, z_);
      residual_dots();
      const double rz_next = sum(partial_);
      const double beta = rz_next / rz;
      rz = rz_next;
      pooled_chunks(n, kVectorChunk, [&](size_t, size_t begin, size_t end) {
        for (size_t i = begin; i < end; ++i) p_[i] = z_[i] + beta * p_[i];
      });
      rn = std::sqrt(sum(rr_partial_));
      ++stats.iterations;
    }
    stats.relative_residual = rn / bn;
    return stats;
  }

 private:
  std::unique_ptr<Preconditioner> preconditioner_;
  int64_t max_iterations_;
  std::string name_;
  const BlockSparseMatrix* a_ = nullptr;
  std::vector<Vec3d> r_, z_, p_, q_;
  std::vector<double> partial_, rr_partial_;  // the dot products' sums per chunk
};

}  // namespace

std::unique_ptr<Preconditioner> make_block_jacobi() { return std::make_unique<BlockJacobi>(); }

std::unique_ptr<LinearSolver> make_direct_solver() { return std::make_unique<DirectSolver>(); }

std::unique_ptr<LinearSolver> make_cg_solver(std::unique_ptr<Preconditioner> preconditioner,
                                             int64_t max_iterations) {
  return std::make_unique<CgSolver>(std::move(preconditioner), max_iterations);
}

}  // namespace zona
