// The block sparse matrix with a rank-one part (engine/core/block_sparse.h): its product,
// diagonal, mask and scalar form agree with the dense matrix blocks + sum_k c_k g_k g_k^T.
#include "engine/core/block_sparse.h"

#include <gtest/gtest.h>

#include <cmath>
#include <vector>

#include <Eigen/Dense>

namespace zona {
namespace {

// Five vertices on a chain (each coupled to its neighbours), and three rank-one terms over
// vertex sets that reach beyond the chain's pattern.
struct Fixture {
  BlockSparseMatrix a;
  Eigen::MatrixXd dense;
  Fixture() {
    std::vector<std::vector<int32_t>> rows(5);
    for (int32_t i = 0; i < 5; ++i)
      for (int32_t j : {i - 1, i + 1})
        if (j >= 0 && j < 5) rows[static_cast<size_t>(i)].push_back(j);
    a = BlockSparseMatrix(rows);
    a.set_rank_one_pattern({0, 3, 5, 9}, {0, 2, 4, 1, 3, 4, 0, 1, 2});
    dense = Eigen::MatrixXd::Zero(15, 15);
    for (size_t i = 0; i < a.rows(); ++i)
      for (int64_t k = a.offsets()[i]; k < a.offsets()[i + 1]; ++k) {
        const size_t j = static_cast<size_t>(a.cols()[static_cast<size_t>(k)]);
        Mat3d b;
        for (int r = 0; r < 3; ++r)
          for (int c = 0; c < 3; ++c)
            b.m[r][c] = std::sin(1.3 * static_cast<double>(3 * (i + j) + static_cast<size_t>(r + c)) + 0.2);
        a.values()[static_cast<size_t>(k)] = b;
        for (int r = 0; r < 3; ++r)
          for (int c = 0; c < 3; ++c)
            dense(static_cast<Eigen::Index>(3 * i) + r, static_cast<Eigen::Index>(3 * j) + c) =
                b.m[r][c];
      }
    for (size_t k = 0; k < a.rank_one_terms(); ++k) {
      a.rank_one_coefficients()[k] = 0.5 + static_cast<double>(k);
      Eigen::VectorXd g = Eigen::VectorXd::Zero(15);
      for (int64_t p = a.rank_one_offsets()[k]; p < a.rank_one_offsets()[k + 1]; ++p) {
        const double s = static_cast<double>(p);
        const Vec3d v{std::cos(s), std::sin(2 * s), 0.3 * s - 1};
        a.rank_one_vectors()[static_cast<size_t>(p)] = v;
        const Eigen::Index i = 3 * a.rank_one_vertices()[static_cast<size_t>(p)];
        g.segment<3>(i) += Eigen::Vector3d(v.x, v.y, v.z);
      }
      dense += a.rank_one_coefficients()[k] * g * g.transpose();
    }
  }
};

// a x and the diagonal blocks of a against the dense matrix `dense`.
void expect_product_and_diagonal(const BlockSparseMatrix& a, const Eigen::MatrixXd& dense,
                                 const std::vector<Vec3d>& x) {
  const size_t n = x.size();
  Eigen::VectorXd xd(static_cast<Eigen::Index>(3 * n));
  for (size_t i = 0; i < n; ++i)
    xd.segment<3>(static_cast<Eigen::Index>(3 * i)) = Eigen::Vector3d(x[i].x, x[i].y, x[i].z);
  std::vector<Vec3d> y(n);
  a.multiply(x, y);
  const Eigen::VectorXd yd = dense * xd;
  for (size_t i = 0; i < n; ++i)
    for (int r = 0; r < 3; ++r)
      EXPECT_NEAR(y[i][r], yd(static_cast<Eigen::Index>(3 * i) + r), 1e-12 * yd.norm());
  std::vector<Mat3d> d;
  a.diagonal(d);
  for (size_t i = 0; i < n; ++i)
    for (int r = 0; r < 3; ++r)
      for (int c = 0; c < 3; ++c)
        EXPECT_NEAR(
            d[i].m[r][c],
            dense(static_cast<Eigen::Index>(3 * i) + r, static_cast<Eigen::Index>(3 * i) + c),
            1e-12);
}

TEST(BlockSparseMatrix, RankOnePartIsInTheProductDiagonalAndScalarForm) {
  Fixture f;
  std::vector<Vec3d> x(5);
  for (size_t i = 0; i < 5; ++i)
    x[i] = Vec3d{1.0 + static_cast<double>(i), -0.5 * static_cast<double>(i), 0.25};
  expect_product_and_diagonal(f.a, f.dense, x);
  const Eigen::MatrixXd assembled = Eigen::MatrixXd(f.a.to_eigen());
  EXPECT_LE((assembled - f.dense).cwiseAbs().maxCoeff(), 1e-12);
}

TEST(BlockSparseMatrix, MaskRemovesTheRankOnePartsOfFixedVertices) {
  Fixture f;
  const std::vector<uint8_t> mask{0, 1, 0, 0, 1};
  f.a.apply_mask(mask);
  // Fixed rows and columns are the identity's; the free ones keep the blocks and the rank-one
  // terms restricted to the free vertices.
  const Fixture g;
  Eigen::MatrixXd expect = Eigen::MatrixXd::Zero(15, 15);
  for (size_t i = 0; i < 5; ++i)
    for (size_t j = 0; j < 5; ++j) {
      const Eigen::Index a = static_cast<Eigen::Index>(3 * i), b = static_cast<Eigen::Index>(3 * j);
      if (mask[i] || mask[j])
        expect.block<3, 3>(a, b) =
            i == j ? Eigen::Matrix3d(Eigen::Matrix3d::Identity()) : Eigen::Matrix3d::Zero();
      else
        expect.block<3, 3>(a, b) = g.dense.block<3, 3>(a, b);
    }
  EXPECT_LE((Eigen::MatrixXd(f.a.to_eigen()) - expect).cwiseAbs().maxCoeff(), 1e-12);
}

// The products read the rank-one vectors through a row-ordered copy made by the first product
// after they may have changed: a product after the mask, or after new vectors written through
// rank_one_vectors(), uses the new ones.
TEST(BlockSparseMatrix, AProductAfterTheRankOneVectorsChangeUsesTheNewOnes) {
  Fixture f;
  std::vector<Vec3d> x(5);
  for (size_t i = 0; i < 5; ++i)
    x[i] = Vec3d{0.5 - static_cast<double>(i), 1.0 + 0.25 * static_cast<double>(i), -0.75};
  auto expect_product = [&](const Eigen::MatrixXd& dense) {
    expect_product_and_diagonal(f.a, dense, x);
  };
  expect_product(f.dense);
  // New vectors: every entry doubled, so each term's c g g^T four times over.
  Eigen::MatrixXd blocks = f.dense;
  for (size_t k = 0; k < f.a.rank_one_terms(); ++k) {
    Eigen::VectorXd g = Eigen::VectorXd::Zero(15);
    for (int64_t p = f.a.rank_one_offsets()[k]; p < f.a.rank_one_offsets()[k + 1]; ++p) {
      const Vec3d v = f.a.rank_one_vectors()[static_cast<size_t>(p)];
      g.segment<3>(3 * f.a.rank_one_vertices()[static_cast<size_t>(p)]) +=
          Eigen::Vector3d(v.x, v.y, v.z);
    }
    blocks -= f.a.rank_one_coefficients()[k] * g * g.transpose();
  }
  const Eigen::MatrixXd rank_one = f.dense - blocks;
  for (Vec3d& v : f.a.rank_one_vectors()) v = 2.0 * v;
  expect_product(blocks + 4.0 * rank_one);
  // The mask: the fixed vertex's rows and columns become the identity's.
  f.a.apply_mask(std::vector<uint8_t>{0, 0, 1, 0, 0});
  const Eigen::MatrixXd scalar = Eigen::MatrixXd(f.a.to_eigen());
  EXPECT_EQ(scalar(6, 6), 1.0);
  expect_product(scalar);
}

}  // namespace
}  // namespace zona
