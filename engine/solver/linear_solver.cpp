// The linear solvers of a Newton step (linear_solver.h).
#include "engine/solver/linear_solver.h"

#include <dlfcn.h>

#include <algorithm>
#include <cmath>
#include <cstdlib>

#include <Eigen/SparseCholesky>

#include "engine/core/parallel.h"
#ifdef ZONA_HAVE_CHOLMOD
#include <Eigen/CholmodSupport>
#endif

namespace zona {
namespace {

// Vertices per chunk of CG's vector passes (pooled_chunks: the same bits on any thread count).
constexpr size_t kVectorChunk = 4096;

}  // namespace

size_t invert_blocks(std::vector<Mat3d>& blocks, bool positive) {
  std::vector<uint8_t> failed(blocks.size(), 0);
  pooled_ranges(blocks.size(), 2048, [&](size_t, size_t begin, size_t end) {
    for (size_t i = begin; i < end; ++i) {
      bool definite = false;
      blocks[i] = inverse3(blocks[i], &definite);
      bool finite = true;
      for (int r = 0; r < 3; ++r)
        for (int c = 0; c < 3; ++c) finite = finite && std::isfinite(blocks[i].m[r][c]);
      failed[i] = !finite || (positive && !definite) ? 1 : 0;
    }
  });
  for (size_t i = 0; i < blocks.size(); ++i)
    if (failed[i]) return i;
  return blocks.size();
}

namespace {

class BlockJacobi final : public Preconditioner {
 public:
  const char* name() const override { return "block Jacobi"; }
  Status setup(const BlockSparseMatrix& a) override {
    a.diagonal(inverse_);
    // (An indefinite block is kept: the exact Hessian's may be, and CG then reports the
    // direction of non-positive curvature it meets.)
    if (const size_t i = invert_blocks(inverse_, false); i < inverse_.size())
      return make_error("the Hessian's diagonal block of vertex %zu is singular", i);
    return {};
  }
  void apply(std::span<const Vec3d> r, std::span<Vec3d> z) const override {
    pooled_chunks(r.size(), kVectorChunk, [&](size_t, size_t begin, size_t end) {
      for (size_t i = begin; i < end; ++i) z[i] = inverse_[i] * r[i];
    });
  }
  const Mat3d* diagonal_blocks() const override { return inverse_.data(); }

 private:
  std::vector<Mat3d> inverse_;
};

// The factorisation of the exact oracle, as a preconditioner: CHOLMOD's supernodal Cholesky
// (Debian's libsuitesparse-dev, multithreaded through its BLAS) where the build found it, else
// Eigen's simplicial LDL^T. setup factors the matrix and refuses one that is not positive
// definite (Newton then takes the projected Hessian); refresh only copies the new values in,
// keeping the factor of the last setup's matrix, and factor() brings it up to date on demand.
class Factorisation final : public Preconditioner {
 public:
#ifdef ZONA_HAVE_CHOLMOD
  // A matrix that is not positive definite is an answer here (Newton projects), not a warning.
  Factorisation() { factor_.cholmod().print = 0; }
  const char* name() const override { return "CHOLMOD supernodal LL^T"; }
#else
  const char* name() const override { return "Eigen simplicial LDL^T"; }
#endif
  Status setup(const BlockSparseMatrix& a) override {
    copy_values(a);
    return factor();
  }
  Status refresh(const BlockSparseMatrix& a) override {
    copy_values(a);
    return {};
  }
  void apply(std::span<const Vec3d> r, std::span<Vec3d> z) const override {
    const Eigen::Index n = matrix_.rows();
    Eigen::Map<Eigen::VectorXd>(&z[0].x, n) =
        factor_.solve(Eigen::Map<const Eigen::VectorXd>(&r[0].x, n));
  }
  bool current() const { return current_; }
  // Factors the values copied in last (the pattern analysed once).
  Status factor() {
    if (!analysed_) {
      factor_.analyzePattern(matrix_);
      analysed_ = true;
    }
    factor_.factorize(matrix_);
    current_ = false;
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
    current_ = true;
    return {};
  }

 private:
  // The matrix's values into matrix_, whose pattern (column-major, both triangles) is built
  // once with a map from each 3 x 3 block, and each pair of a rank-one term's vertices, to the
  // block's place in its columns: the same pattern again costs one pass over the values.
  void copy_values(const BlockSparseMatrix& a) {
    current_ = false;
    if (matrix_.rows() == 0) {
      matrix_ = a.to_eigen();
      matrix_.makeCompressed();
      const int* outer = matrix_.outerIndexPtr();
      const int* inner = matrix_.innerIndexPtr();
      // The block (i, j)'s row 3 i within column 3 j (columns 3 j + 1 and 3 j + 2 alike).
      auto place = [&](int64_t i, int64_t j) {
        const int* begin = inner + outer[3 * j];
        return static_cast<int32_t>(std::lower_bound(begin, inner + outer[3 * j + 1],
                                                     static_cast<int>(3 * i)) - begin);
      };
      block_place_.resize(a.block_count());
      for (size_t i = 0; i < a.rows(); ++i)
        for (int64_t k = a.offsets()[i]; k < a.offsets()[i + 1]; ++k)
          block_place_[static_cast<size_t>(k)] =
              place(static_cast<int64_t>(i), a.cols()[static_cast<size_t>(k)]);
      pair_place_.clear();
      const std::span<const int64_t> off = a.rank_one_offsets();
      const std::span<const int32_t> vert = a.rank_one_vertices();
      for (size_t k = 0; k < a.rank_one_terms(); ++k)
        for (int64_t p = off[k]; p < off[k + 1]; ++p)
          for (int64_t q = off[k]; q < off[k + 1]; ++q)
            pair_place_.push_back(place(vert[static_cast<size_t>(p)], vert[static_cast<size_t>(q)]));
      return;
    }
    ZONA_ASSERT(a.block_count() == block_place_.size());
    double* value = matrix_.valuePtr();
    const int* outer = matrix_.outerIndexPtr();
    std::fill(value, value + matrix_.nonZeros(), 0.0);
    // Adds entry(r, c) to the block of column block j whose rows start `at` into its columns.
    auto add = [&](int64_t j, int32_t at, const auto& entry) {
      for (int c = 0; c < 3; ++c) {
        double* column = value + outer[3 * j + c] + at;
        for (int r = 0; r < 3; ++r) column[r] += entry(r, c);
      }
    };
    for (size_t k = 0; k < a.block_count(); ++k) {
      const Mat3d& b = a.values()[k];
      add(a.cols()[k], block_place_[k], [&](int r, int c) { return b.m[r][c]; });
    }
    const std::span<const int64_t> off = a.rank_one_offsets();
    const std::span<const int32_t> vert = a.rank_one_vertices();
    const std::span<const Vec3d> vec = a.rank_one_vectors();
    size_t pair = 0;
    for (size_t k = 0; k < a.rank_one_terms(); ++k)
      for (int64_t p = off[k]; p < off[k + 1]; ++p) {
        const Vec3d u = a.rank_one_coefficients()[k] * vec[static_cast<size_t>(p)];
        for (int64_t q = off[k]; q < off[k + 1]; ++q) {
          const Vec3d& w = vec[static_cast<size_t>(q)];
          add(vert[static_cast<size_t>(q)], pair_place_[pair++],
              [&](int r, int c) { return u[r] * w[c]; });
        }
      }
  }

  Eigen::SparseMatrix<double> matrix_;
  std::vector<int32_t> block_place_, pair_place_;
#ifdef ZONA_HAVE_CHOLMOD
  Eigen::CholmodSupernodalLLT<Eigen::SparseMatrix<double>, Eigen::Lower> factor_;
#else
  Eigen::SimplicialLDLT<Eigen::SparseMatrix<double>, Eigen::Lower, Eigen::AMDOrdering<int> >
      factor_;
#endif
  bool analysed_ = false;
  bool current_ = false;  // factor_ is of the values in matrix_
};

class CgSolver final : public LinearSolver {
 public:
  CgSolver(std::unique_ptr<Preconditioner> p, int64_t max_iterations)
      : preconditioner_(std::move(p)), max_iterations_(max_iterations) {
    name_ = std::string("CG, ") + preconditioner_->name();
  }
  const char* name() const override { return name_.c_str(); }
  /// The iterations the last solve that returned an error completed.
  int64_t last_iterations() const { return last_iterations_; }
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
      if (stats.iterations >= max_iterations_) {
        last_iterations_ = max_iterations_;
        return make_error("CG (%s) did not reach a relative residual of %.3g in %lld iterations "
                          "(%.3g)",
                          preconditioner_->name(), tolerance,
                          static_cast<long long>(max_iterations_), rn / bn);
      }
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
        if (stats.iterations == 0) {
          last_iterations_ = 0;
          return make_error("CG met a direction of non-positive curvature (%.3g)", pq);
        }
        stats.relative_residual = rn / bn;
        stats.truncated = true;
        return stats;
      }
      const double alpha = rz / pq;
      if (const Mat3d* blocks = preconditioner_->diagonal_blocks()) {
        // The update, z = M^-1 r and the residual's dots in one pass (the same sums per chunk).
        pooled_chunks(n, kVectorChunk, [&](size_t c, size_t begin, size_t end) {
          double rz_c = 0, rr_c = 0;
          for (size_t i = begin; i < end; ++i) {
            x[i] += alpha * p_[i];
            r_[i] -= alpha * q_[i];
            z_[i] = blocks[i] * r_[i];
            rz_c += dot(r_[i], z_[i]);
            rr_c += dot(r_[i], r_[i]);
          }
          partial_[c] = rz_c;
          rr_partial_[c] = rr_c;
        });
      } else {
        pooled_chunks(n, kVectorChunk, [&](size_t, size_t begin, size_t end) {
          for (size_t i = begin; i < end; ++i) {
            x[i] += alpha * p_[i];
            r_[i] -= alpha * q_[i];
          }
        });
        preconditioner_->apply(r_, z_);
        residual_dots();
      }
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
  int64_t last_iterations_ = 0;  // iterations the last failed solve completed
  std::string name_;
  const BlockSparseMatrix* a_ = nullptr;
  std::vector<Vec3d> r_, z_, p_, q_;
  std::vector<double> partial_, rr_partial_;  // the dot products' sums per chunk
};

// The exact oracle: Newton's systems solved to a relative residual of kExactResidual. A whole
// setup factors the matrix (the first iteration of each load step, and wherever Newton asks);
// a refresh keeps that factor and CG preconditioned by it finishes the solve, a few iterations
// while the matrix is near the one factored. Where it is not (CG past kRefineIterations, or a
// direction of non-positive curvature), the current matrix is factored and the solve redone.
class DirectSolver final : public LinearSolver {
 public:
  static constexpr double kExactResidual = 1e-12;
  static constexpr int64_t kRefineIterations = 40;
  DirectSolver() {
    auto f = std::make_unique<Factorisation>();
    factor_ = f.get();
    cg_ = std::make_unique<CgSolver>(std::move(f), kRefineIterations);
    name_ = std::string("direct (") + factor_->name() + ")";
  }
  const char* name() const override { return name_.c_str(); }
  Status setup(const BlockSparseMatrix& a) override { return cg_->setup(a); }
  Status refresh(const BlockSparseMatrix& a) override { return cg_->refresh(a); }
  Result<LinearSolveStats> solve(std::span<const Vec3d> b, std::span<Vec3d> d,
                                 double) override {
    const std::vector<Vec3d> start(d.begin(), d.end());
    Result<LinearSolveStats> r = cg_->solve(b, d, kExactResidual);
    const bool solved = r.ok() && !r->truncated;
    if (!solved && !factor_->current()) {  // the kept factor is too far: factor this matrix
      const int64_t spent = r.ok() ? r->iterations : cg_->last_iterations();
      if (Status st = factor_->factor(); !st) return st.error();
      std::copy(start.begin(), start.end(), d.begin());
      r = cg_->solve(b, d, kExactResidual);
      if (r.ok()) r->iterations += spent;
    }
    if (!r.ok() || r->truncated)
      return make_error("the direct solve of the Newton step failed (%s)",
                        r.ok() ? "a direction of non-positive curvature" : r.error().message.c_str());
    return r;
  }

 private:
  Factorisation* factor_;  // owned by cg_
  std::unique_ptr<CgSolver> cg_;
  std::string name_;
};

}  // namespace

std::unique_ptr<Preconditioner> make_block_jacobi() { return std::make_unique<BlockJacobi>(); }

std::unique_ptr<LinearSolver> make_direct_solver() { return std::make_unique<DirectSolver>(); }

std::string direct_solver_note() {
#ifdef ZONA_HAVE_CHOLMOD
  // OpenBLAS (CHOLMOD's BLAS on Debian) reads its settings when it loads, before main.
  if (std::getenv("OPENBLAS_THREAD_TIMEOUT") == nullptr &&
      dlsym(RTLD_DEFAULT, "openblas_get_config") != nullptr)
    return "direct solver: OpenBLAS's idle threads spin for about 0.1 s after each call and "
           "take the cores from zona's; OPENBLAS_THREAD_TIMEOUT=4 in the environment puts them "
           "to sleep at once (docs/static.md, \"The direct oracle\")";
#endif
  return {};
}

std::unique_ptr<LinearSolver> make_cg_solver(std::unique_ptr<Preconditioner> preconditioner,
                                             int64_t max_iterations) {
  return std::make_unique<CgSolver>(std::move(preconditioner), max_iterations);
}

}  // namespace zona
