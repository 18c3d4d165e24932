// A symmetric matrix of 3 x 3 blocks on a fixed sparsity pattern (block CSR, every row holding
// its own diagonal block and both triangles stored), plus an optional sum of rank-one terms
// sum_k c_k g_k g_k^T kept as vectors (each g_k on a fixed set of vertices): the Hessian a
// Newton solver factors, multiplies and builds its preconditioner from. Nodal pressure's
// vertex terms are such rank-one terms over a vertex's star; assembled, they would couple the
// 2-ring and multiply the blocks by five, so they stay vectors and every product, diagonal and
// Galerkin product applies them as such (the direct solver's to_eigen() assembles them). The
// patterns are made once; each evaluation zeroes the values and adds into them (add() finds a
// block by binary search in its row, which is a few dozen columns long).
#pragma once

#include <cstdint>
#include <span>
#include <string>
#include <vector>

#include <Eigen/SparseCore>

#include "engine/core/base.h"
#include "engine/core/vec.h"

namespace zona {

/// sum_i a_i . b_i over two block vectors of the same length.
double dot_all(std::span<const Vec3d> a, std::span<const Vec3d> b);
/// The inverse of a 3 x 3 block by its cofactors; *ok is false where the block is not positive
/// definite enough to invert (determinant not positive, or the inverse not finite).
Mat3d inverse3(const Mat3d& a, bool* ok);

class BlockSparseMatrix {
 public:
  BlockSparseMatrix() = default;
  /// From each row's columns (any order, duplicates allowed; the diagonal is added).
  explicit BlockSparseMatrix(const std::vector<std::vector<int32_t>>& rows);
  /// From CSR arrays: offsets (rows + 1), sorted unique columns per row, each with its diagonal.
  BlockSparseMatrix(std::vector<int64_t> offsets, std::vector<int32_t> cols);

  size_t rows() const { return offsets_.empty() ? 0 : offsets_.size() - 1; }
  size_t block_count() const { return cols_.size(); }
  std::span<const int64_t> offsets() const { return offsets_; }
  std::span<const int32_t> cols() const { return cols_; }
  std::span<Mat3d> values() { return values_; }
  std::span<const Mat3d> values() const { return values_; }

  void set_zero();
  /// The block (i, j), or nullptr where the pattern has none.
  Mat3d* find(int32_t i, int32_t j);
  const Mat3d* find(int32_t i, int32_t j) const;
  /// Where block (i, j) sits in values(); the pattern must hold it.
  int64_t block_index(int32_t i, int32_t j) const;
  /// Row i's diagonal block (every row holds one).
  Mat3d& diagonal_block(size_t i) { return values_[static_cast<size_t>(diagonal_at_[i])]; }
  const Mat3d& diagonal_block(size_t i) const {
    return values_[static_cast<size_t>(diagonal_at_[i])];
  }
  /// Adds b to block (i, j); the pattern must hold it.
  void add(int32_t i, int32_t j, const Mat3d& b) {
    Mat3d* p = find(i, j);
    ZONA_ASSERT(p != nullptr);
    *p = *p + b;
  }
  /// The rank-one part's pattern: term k's vector lives on vertices[offsets[k] ..
  /// offsets[k + 1]) (distinct within a term); its values start at zero.
  void set_rank_one_pattern(std::vector<int64_t> offsets, std::vector<int32_t> vertices);
  size_t rank_one_terms() const { return coefficients_.size(); }
  std::span<const int64_t> rank_one_offsets() const { return r1_offsets_; }
  std::span<const int32_t> rank_one_vertices() const { return r1_vertices_; }
  /// c_k [matrix units / vector units^2], (terms).
  std::span<double> rank_one_coefficients() { return coefficients_; }
  std::span<const double> rank_one_coefficients() const { return coefficients_; }
  /// The vectors' entries, at the positions of rank_one_vertices().
  std::span<Vec3d> rank_one_vectors() {
    r1_by_row_stale_ = true;
    return r1_vectors_;
  }
  std::span<const Vec3d> rank_one_vectors() const { return r1_vectors_; }

  /// y = A x, (rows).
  void multiply(std::span<const Vec3d> x, std::span<Vec3d> y) const;
  /// The diagonal blocks, (rows).
  void diagonal(std::vector<Mat3d>& out) const;
  /// Rows and columns of the vertices with mask[v] != 0 replaced by the identity (fixed
  /// vertices: the solution there is the right-hand side); the rank-one vectors' entries there
  /// zeroed.
  void apply_mask(std::span<const uint8_t> mask);
  /// The scalar matrix (3 rows) x (3 rows), both triangles, the rank-one part assembled.
  Eigen::SparseMatrix<double> to_eigen() const;
  /// Writes the scalar matrix as a Matrix Market file (coordinate real symmetric: the lower
  /// triangle, 1-based).
  Status write_matrix_market(const std::string& path) const;

 private:
  std::vector<int64_t> offsets_;
  std::vector<int32_t> cols_;
  std::vector<Mat3d> values_;
  std::vector<int64_t> diagonal_at_;  // each row's diagonal block in values_
  void index_diagonal();
  // The rank-one part, and per row the positions of its entries in r1_vectors_ (by row, from
  // r1_row_offsets_) with each position's term (fixed with the pattern).
  std::vector<int64_t> r1_offsets_;
  std::vector<int32_t> r1_vertices_;
  std::vector<double> coefficients_;
  std::vector<Vec3d> r1_vectors_;
  std::vector<int64_t> r1_row_offsets_;
  std::vector<int64_t> r1_row_positions_;
  std::vector<int32_t> r1_row_term_;
  mutable std::vector<double> r1_scratch_;  // c_k (g_k . x) of the product in progress
  // r1_vectors_ in row order (r1_row_positions_'s), for the products' row pass (sequential
  // reads); rebuilt by the first product after the vectors may have changed.
  void refresh_rank_one_rows() const;
  mutable std::vector<Vec3d> r1_row_vectors_;
  mutable bool r1_by_row_stale_ = true;
};

}  // namespace zona
