// The block sparse matrix (block_sparse.h).
#include "engine/core/block_sparse.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <memory>

#include "engine/core/parallel.h"
#include "engine/core/simd_pack.h"

namespace zona {

double dot_all(std::span<const Vec3d> a, std::span<const Vec3d> b) {
  double s = 0;
  for (size_t i = 0; i < a.size(); ++i) s += dot(a[i], b[i]);
  return s;
}

Mat3d inverse3(const Mat3d& a, bool* ok) {
  const double c00 = a.m[1][1] * a.m[2][2] - a.m[1][2] * a.m[2][1];
  const double c01 = a.m[1][2] * a.m[2][0] - a.m[1][0] * a.m[2][2];
  const double c02 = a.m[1][0] * a.m[2][1] - a.m[1][1] * a.m[2][0];
  const double det = a.m[0][0] * c00 + a.m[0][1] * c01 + a.m[0][2] * c02;
  const double s = 1.0 / det;
  Mat3d inv;
  inv.m[0][0] = s * c00;
  inv.m[1][0] = s * c01;
  inv.m[2][0] = s * c02;
  inv.m[0][1] = s * (a.m[0][2] * a.m[2][1] - a.m[0][1] * a.m[2][2]);
  inv.m[1][1] = s * (a.m[0][0] * a.m[2][2] - a.m[0][2] * a.m[2][0]);
  inv.m[2][1] = s * (a.m[0][1] * a.m[2][0] - a.m[0][0] * a.m[2][1]);
  inv.m[0][2] = s * (a.m[0][1] * a.m[1][2] - a.m[0][2] * a.m[1][1]);
  inv.m[1][2] = s * (a.m[0][2] * a.m[1][0] - a.m[0][0] * a.m[1][2]);
  inv.m[2][2] = s * (a.m[0][0] * a.m[1][1] - a.m[0][1] * a.m[1][0]);
  *ok = std::isfinite(s) && det > 0;
  return inv;
}

BlockSparseMatrix::BlockSparseMatrix(const std::vector<std::vector<int32_t>>& rows) {
  offsets_.assign(rows.size() + 1, 0);
  std::vector<int32_t> row;
  for (size_t i = 0; i < rows.size(); ++i) {
    row = rows[i];
    row.push_back(static_cast<int32_t>(i));
    std::sort(row.begin(), row.end());
    row.erase(std::unique(row.begin(), row.end()), row.end());
    cols_.insert(cols_.end(), row.begin(), row.end());
    offsets_[i + 1] = static_cast<int64_t>(cols_.size());
  }
  values_.assign(cols_.size(), Mat3d::zero());
  index_diagonal();
}

BlockSparseMatrix::BlockSparseMatrix(std::vector<int64_t> offsets, std::vector<int32_t> cols)
    : offsets_(std::move(offsets)), cols_(std::move(cols)) {
  values_.assign(cols_.size(), Mat3d::zero());
  index_diagonal();
}

void BlockSparseMatrix::index_diagonal() {
  diagonal_at_.resize(rows());
  for (size_t i = 0; i < rows(); ++i)
    diagonal_at_[i] = block_index(static_cast<int32_t>(i), static_cast<int32_t>(i));
}

int64_t BlockSparseMatrix::block_index(int32_t i, int32_t j) const {
  const Mat3d* p = find(i, j);
  ZONA_ASSERT(p != nullptr);
  return p - values_.data();
}

void BlockSparseMatrix::set_zero() {
  // (Tens of megabytes at 64k vertices: on the shared pool.)
  pooled_chunks(values_.size(), 1 << 16, [&](size_t, size_t begin, size_t end) {
    std::fill(values_.begin() + static_cast<std::ptrdiff_t>(begin),
              values_.begin() + static_cast<std::ptrdiff_t>(end), Mat3d::zero());
  });
  std::fill(coefficients_.begin(), coefficients_.end(), 0.0);
  std::fill(r1_vectors_.begin(), r1_vectors_.end(), Vec3d{0, 0, 0});
  r1_by_row_stale_ = true;
}

void BlockSparseMatrix::refresh_rank_one_rows() const {
  if (!r1_by_row_stale_) return;
  r1_row_vectors_.resize(r1_row_positions_.size());
  pooled_ranges(r1_row_positions_.size(), 1 << 14, [&](size_t, size_t begin, size_t end) {
    for (size_t q = begin; q < end; ++q)
      r1_row_vectors_[q] = r1_vectors_[static_cast<size_t>(r1_row_positions_[q])];
  });
  r1_by_row_stale_ = false;
}

const Mat3d* BlockSparseMatrix::find(int32_t i, int32_t j) const {
  const auto begin = cols_.begin() + offsets_[static_cast<size_t>(i)];
  const auto end = cols_.begin() + offsets_[static_cast<size_t>(i) + 1];
  const auto it = std::lower_bound(begin, end, j);
  if (it == end || *it != j) return nullptr;
  return &values_[static_cast<size_t>(it - cols_.begin())];
}

Mat3d* BlockSparseMatrix::find(int32_t i, int32_t j) {
  return const_cast<Mat3d*>(static_cast<const BlockSparseMatrix*>(this)->find(i, j));
}

void BlockSparseMatrix::set_rank_one_pattern(std::vector<int64_t> offsets,
                                             std::vector<int32_t> vertices) {
  ZONA_ASSERT(!offsets.empty() && offsets.back() == static_cast<int64_t>(vertices.size()));
  r1_offsets_ = std::move(offsets);
  r1_vertices_ = std::move(vertices);
  const size_t terms = r1_offsets_.size() - 1;
  coefficients_.assign(terms, 0.0);
  r1_vectors_.assign(r1_vertices_.size(), Vec3d{0, 0, 0});
  r1_by_row_stale_ = true;
  r1_scratch_.assign(terms, 0.0);
  std::vector<int32_t> term(r1_vertices_.size());
  for (size_t k = 0; k < terms; ++k)
    for (int64_t p = r1_offsets_[k]; p < r1_offsets_[k + 1]; ++p)
      term[static_cast<size_t>(p)] = static_cast<int32_t>(k);
  // By row: counting sort of the positions by their vertex.
  r1_row_offsets_.assign(rows() + 1, 0);
  for (int32_t v : r1_vertices_) {
    ZONA_ASSERT(v >= 0 && static_cast<size_t>(v) < rows());
    ++r1_row_offsets_[static_cast<size_t>(v) + 1];
  }
  for (size_t i = 0; i < rows(); ++i) r1_row_offsets_[i + 1] += r1_row_offsets_[i];
  r1_row_positions_.resize(r1_vertices_.size());
  std::vector<int64_t> next(r1_row_offsets_.begin(), r1_row_offsets_.end() - 1);
  for (size_t p = 0; p < r1_vertices_.size(); ++p)
    r1_row_positions_[static_cast<size_t>(next[static_cast<size_t>(r1_vertices_[p])]++)] =
        static_cast<int64_t>(p);
  r1_row_term_.resize(r1_row_positions_.size());
  for (size_t q = 0; q < r1_row_positions_.size(); ++q)
    r1_row_term_[q] = term[static_cast<size_t>(r1_row_positions_[q])];
}

namespace {
// y_i = sum_k values_k x_cols_k over rows [begin, end): the products' bulk, with an AVX2 clone.
ZONA_SIMD_CLONES void block_rows(size_t begin, size_t end, const int64_t* offsets,
                                 const int32_t* cols, const Mat3d* values, const Vec3d* x,
                                 Vec3d* y) {
  for (size_t i = begin; i < end; ++i) {
    double s0 = 0, s1 = 0, s2 = 0;
    for (int64_t k = offsets[i]; k < offsets[i + 1]; ++k) {
      const Mat3d& m = values[k];
      const Vec3d v = x[cols[k]];
      s0 += m.m[0][0] * v.x + m.m[0][1] * v.y + m.m[0][2] * v.z;
      s1 += m.m[1][0] * v.x + m.m[1][1] * v.y + m.m[1][2] * v.z;
      s2 += m.m[2][0] * v.x + m.m[2][1] * v.y + m.m[2][2] * v.z;
    }
    y[i] = Vec3d{s0, s1, s2};
  }
}

// scratch_k = c_k (g_k . x) over terms [begin, end) of the rank-one part.
ZONA_SIMD_CLONES void rank_one_dots(size_t begin, size_t end, const int64_t* offsets,
                                    const int32_t* vertices, const Vec3d* vectors,
                                    const double* coefficients, const Vec3d* x, double* scratch) {
  for (size_t k = begin; k < end; ++k) {
    double s = 0;
    for (int64_t p = offsets[k]; p < offsets[k + 1]; ++p) {
      const Vec3d g = vectors[p], v = x[vertices[p]];
      s += g.x * v.x + g.y * v.y + g.z * v.z;
    }
    scratch[k] = coefficients[k] * s;
  }
}

// y_i += sum over row i's rank-one entries q of scratch_term(q) g_q, rows [begin, end) (the
// entries in row order).
ZONA_SIMD_CLONES void rank_one_rows(size_t begin, size_t end, const int64_t* row_offsets,
                                    const int32_t* term, const Vec3d* vectors,
                                    const double* scratch, Vec3d* y) {
  for (size_t i = begin; i < end; ++i) {
    double s0 = y[i].x, s1 = y[i].y, s2 = y[i].z;
    for (int64_t q = row_offsets[i]; q < row_offsets[i + 1]; ++q) {
      const double c = scratch[term[q]];
      const Vec3d g = vectors[q];
      s0 += c * g.x;
      s1 += c * g.y;
      s2 += c * g.z;
    }
    y[i] = Vec3d{s0, s1, s2};
  }
}
}  // namespace

void BlockSparseMatrix::multiply(std::span<const Vec3d> x, std::span<Vec3d> y) const {
  ZONA_ASSERT(x.size() == rows() && y.size() == rows());
  // Rows (and terms) split over the machine's threads (each row written by one: the same bits
  // for any count); short matrices stay on the caller's thread.
  const size_t terms = rank_one_terms();
  if (terms > 0) refresh_rank_one_rows();
  // Ranges of about kBlocksPerRange blocks: a coarse multigrid level's rows hold some hundred
  // blocks each, a fine mesh's some fifteen.
  constexpr size_t kBlocksPerRange = 16384;
  const size_t per_row = rows() > 0 ? std::max<size_t>(1, block_count() / rows()) : 1;
  const size_t min_rows = std::max<size_t>(16, kBlocksPerRange / per_row);
  if (terms > 0)
    pooled_ranges(terms, 1024, [&](size_t, size_t begin, size_t end) {
      rank_one_dots(begin, end, r1_offsets_.data(), r1_vertices_.data(), r1_vectors_.data(),
                    coefficients_.data(), x.data(), r1_scratch_.data());
    });
  pooled_ranges(rows(), min_rows, [&](size_t, size_t begin, size_t end) {
    block_rows(begin, end, offsets_.data(), cols_.data(), values_.data(), x.data(), y.data());
    if (terms > 0)
      rank_one_rows(begin, end, r1_row_offsets_.data(), r1_row_term_.data(), r1_row_vectors_.data(),
                    r1_scratch_.data(), y.data());
  });
}

void BlockSparseMatrix::diagonal(std::vector<Mat3d>& out) const {
  out.resize(rows());
  const bool rank_one = rank_one_terms() > 0;
  if (rank_one) refresh_rank_one_rows();
  // Row by row; a row's rank-one entries in row order, which is their terms' order.
  pooled_ranges(rows(), 1024, [&](size_t, size_t begin, size_t end) {
    for (size_t i = begin; i < end; ++i) {
      Mat3d d = diagonal_block(i);
      if (rank_one)
        for (int64_t q = r1_row_offsets_[i]; q < r1_row_offsets_[i + 1]; ++q) {
          const Vec3d& g = r1_row_vectors_[static_cast<size_t>(q)];
          d = d + coefficients_[static_cast<size_t>(r1_row_term_[static_cast<size_t>(q)])] *
                      outer(g, g);
        }
      out[i] = d;
    }
  });
}

void BlockSparseMatrix::apply_mask(std::span<const uint8_t> mask) {
  ZONA_ASSERT(mask.size() == rows());
  pooled_ranges(rows(), 2048, [&](size_t, size_t begin, size_t end) {
    for (size_t i = begin; i < end; ++i)
      for (int64_t k = offsets_[i]; k < offsets_[i + 1]; ++k) {
        const size_t j = static_cast<size_t>(cols_[static_cast<size_t>(k)]);
        if (!mask[i] && !mask[j]) continue;
        values_[static_cast<size_t>(k)] = i == j ? Mat3d::identity() : Mat3d::zero();
      }
  });
  for (size_t p = 0; p < r1_vertices_.size(); ++p)
    if (mask[static_cast<size_t>(r1_vertices_[p])]) r1_vectors_[p] = Vec3d{0, 0, 0};
  r1_by_row_stale_ = true;
}

Eigen::SparseMatrix<double> BlockSparseMatrix::to_eigen() const {
  const Eigen::Index n = static_cast<Eigen::Index>(3 * rows());
  std::vector<Eigen::Triplet<double>> entries;
  entries.reserve(9 * cols_.size());
  for (size_t i = 0; i < rows(); ++i)
    for (int64_t k = offsets_[i]; k < offsets_[i + 1]; ++k) {
      const size_t j = static_cast<size_t>(cols_[static_cast<size_t>(k)]);
      const Mat3d& b = values_[static_cast<size_t>(k)];
      for (int r = 0; r < 3; ++r)
        for (int c = 0; c < 3; ++c)
          entries.emplace_back(static_cast<Eigen::Index>(3 * i) + r,
                               static_cast<Eigen::Index>(3 * j) + c, b.m[r][c]);
    }
  for (size_t k = 0; k < rank_one_terms(); ++k)
    for (int64_t p = r1_offsets_[k]; p < r1_offsets_[k + 1]; ++p)
      for (int64_t q = r1_offsets_[k]; q < r1_offsets_[k + 1]; ++q) {
        const Vec3d a = coefficients_[k] * r1_vectors_[static_cast<size_t>(p)];
        const Vec3d& b = r1_vectors_[static_cast<size_t>(q)];
        const Eigen::Index i = 3 * r1_vertices_[static_cast<size_t>(p)];
        const Eigen::Index j = 3 * r1_vertices_[static_cast<size_t>(q)];
        for (int r = 0; r < 3; ++r)
          for (int c = 0; c < 3; ++c) entries.emplace_back(i + r, j + c, a[r] * b[c]);
      }
  Eigen::SparseMatrix<double> a(n, n);
  a.setFromTriplets(entries.begin(), entries.end());
  return a;
}

Status BlockSparseMatrix::write_matrix_market(const std::string& path) const {
  std::unique_ptr<FILE, int (*)(FILE*)> f(std::fopen(path.c_str(), "w"), &std::fclose);
  if (!f) return make_error("%s: cannot open for writing", path.c_str());
  const Eigen::SparseMatrix<double> a = to_eigen();
  int64_t count = 0;
  for (Eigen::Index c = 0; c < a.outerSize(); ++c)
    for (Eigen::SparseMatrix<double>::InnerIterator it(a, c); it; ++it)
      if (it.row() >= it.col()) ++count;
  std::fprintf(f.get(), "%%%%MatrixMarket matrix coordinate real symmetric\n%zu %zu %lld\n",
               3 * rows(), 3 * rows(), static_cast<long long>(count));
  for (Eigen::Index c = 0; c < a.outerSize(); ++c)
    for (Eigen::SparseMatrix<double>::InnerIterator it(a, c); it; ++it)
      if (it.row() >= it.col())
        std::fprintf(f.get(), "%lld %lld %.17g\n", static_cast<long long>(it.row() + 1),
                     static_cast<long long>(it.col() + 1), it.value());
  if (std::ferror(f.get())) return make_error("%s: write failed", path.c_str());
  return {};
}

}  // namespace zona
