// The block sparse matrix (block_sparse.h).
#include "engine/core/block_sparse.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <memory>

#include "engine/core/parallel.h"

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
}

BlockSparseMatrix::BlockSparseMatrix(std::vector<int64_t> offsets, std::vector<int32_t> cols)
    : offsets_(std::move(offsets)), cols_(std::move(cols)) {
  values_.assign(cols_.size(), Mat3d::zero());
}

void BlockSparseMatrix::set_zero() { std::fill(values_.begin(), values_.end(), Mat3d::zero()); }

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

void BlockSparseMatrix::multiply(std::span<const Vec3d> x, std::span<Vec3d> y) const {
  ZONA_ASSERT(x.size() == rows() && y.size() == rows());
  // Rows split over the machine's threads (each row written by one: the same bits for any
  // count); short matrices stay on the caller's thread.
  static const int threads = setup_thread_count(0);
  parallel_ranges(rows(), threads, 1024, [&](size_t, size_t begin, size_t end) {
    for (size_t i = begin; i < end; ++i) {
      Vec3d s{0, 0, 0};
      for (int64_t k = offsets_[i]; k < offsets_[i + 1]; ++k)
        s += values_[static_cast<size_t>(k)] *
             x[static_cast<size_t>(cols_[static_cast<size_t>(k)])];
      y[i] = s;
    }
  });
}

void BlockSparseMatrix::diagonal(std::vector<Mat3d>& out) const {
  out.resize(rows());
  for (size_t i = 0; i < rows(); ++i) out[i] = *find(static_cast<int32_t>(i), static_cast<int32_t>(i));
}

void BlockSparseMatrix::apply_mask(std::span<const uint8_t> mask) {
  ZONA_ASSERT(mask.size() == rows());
  for (size_t i = 0; i < rows(); ++i)
    for (int64_t k = offsets_[i]; k < offsets_[i + 1]; ++k) {
      const size_t j = static_cast<size_t>(cols_[static_cast<size_t>(k)]);
      if (!mask[i] && !mask[j]) continue;
      values_[static_cast<size_t>(k)] = i == j ? Mat3d::identity() : Mat3d::zero();
    }
}

Eigen::SparseMatrix<double> BlockSparseMatrix::to_eigen() const {
  const Eigen::Index n = static_cast<Eigen::Index>(3 * rows());
  Eigen::SparseMatrix<double> a(n, n);
  std::vector<Eigen::Index> per_column(static_cast<size_t>(n));
  for (size_t i = 0; i < rows(); ++i)
    for (int r = 0; r < 3; ++r)
      per_column[3 * i + static_cast<size_t>(r)] = 3 * (offsets_[i + 1] - offsets_[i]);
  a.reserve(per_column);
  // Symmetric: column j of block row i is row j of block column i, so filling columns from
  // rows keeps each column's entries in ascending order.
  for (size_t i = 0; i < rows(); ++i)
    for (int64_t k = offsets_[i]; k < offsets_[i + 1]; ++k) {
      const size_t j = static_cast<size_t>(cols_[static_cast<size_t>(k)]);
      const Mat3d& b = values_[static_cast<size_t>(k)];
      for (int r = 0; r < 3; ++r)
        for (int c = 0; c < 3; ++c)
          a.insert(static_cast<Eigen::Index>(3 * i) + r, static_cast<Eigen::Index>(3 * j) + c) =
              b.m[r][c];
    }
  a.makeCompressed();
  return a;
}

Status BlockSparseMatrix::write_matrix_market(const std::string& path) const {
  std::unique_ptr<FILE, int (*)(FILE*)> f(std::fopen(path.c_str(), "w"), &std::fclose);
  if (!f) return make_error("%s: cannot open for writing", path.c_str());
  int64_t count = 0;
  for (size_t i = 0; i < rows(); ++i)
    for (int64_t k = offsets_[i]; k < offsets_[i + 1]; ++k) {
      const size_t j = static_cast<size_t>(cols_[static_cast<size_t>(k)]);
      if (j < i) count += 9;
      if (j == i) count += 6;
    }
  std::fprintf(f.get(), "%%%%MatrixMarket matrix coordinate real symmetric\n%zu %zu %lld\n",
               3 * rows(), 3 * rows(), static_cast<long long>(count));
  for (size_t i = 0; i < rows(); ++i)
    for (int64_t k = offsets_[i]; k < offsets_[i + 1]; ++k) {
      const size_t j = static_cast<size_t>(cols_[static_cast<size_t>(k)]);
      if (j > i) continue;
      const Mat3d& b = values_[static_cast<size_t>(k)];
      for (int r = 0; r < 3; ++r)
        for (int c = 0; c < 3; ++c) {
          const size_t row = 3 * i + static_cast<size_t>(r), col = 3 * j + static_cast<size_t>(c);
          if (col > row) continue;
          std::fprintf(f.get(), "%zu %zu %.17g\n", row + 1, col + 1, b.m[r][c]);
        }
    }
  if (std::ferror(f.get())) return make_error("%s: write failed", path.c_str());
  return {};
}

}  // namespace zona
