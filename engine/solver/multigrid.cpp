// The lattice-embedding multigrid preconditioner (multigrid.h).
#include "engine/solver/multigrid.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <string>
#include <vector>

#include <Eigen/Dense>

#include "engine/core/parallel.h"

namespace zona {
namespace {

// Vertices per range of the cycle's vector passes on the shared pool (short levels stay on the
// caller's thread).
constexpr size_t kVectorRange = 2048;

// Interpolation to the nodes of a level from the next coarser lattice: per fine node, up to 8
// (coarse node, trilinear weight) pairs; a fixed vertex has none.
struct Interpolation {
  std::vector<int64_t> offsets;  // (fine nodes + 1)
  std::vector<int32_t> nodes;    // coarse node per pair
  std::vector<double> weights;   // its weight [-]
  size_t coarse_count = 0;
  // The pairs by coarse node (P^T's rows, for gathers by coarse node): node I's pairs are
  // by_node[by_node_offsets[I] .. by_node_offsets[I + 1]), ascending, each with its fine node
  // in row (per pair).
  std::vector<int64_t> by_node_offsets, by_node;
  std::vector<int32_t> row;
  void transpose() {
    const size_t pairs = nodes.size(), fine = offsets.size() - 1;
    row.resize(pairs);
    for (size_t i = 0; i < fine; ++i)
      for (int64_t q = offsets[i]; q < offsets[i + 1]; ++q)
        row[static_cast<size_t>(q)] = static_cast<int32_t>(i);
    by_node_offsets.assign(coarse_count + 1, 0);
    for (int32_t n : nodes) ++by_node_offsets[static_cast<size_t>(n) + 1];
    for (size_t n = 0; n < coarse_count; ++n) by_node_offsets[n + 1] += by_node_offsets[n];
    by_node.resize(pairs);
    std::vector<int64_t> fill(by_node_offsets.begin(), by_node_offsets.end() - 1);
    for (size_t q = 0; q < pairs; ++q)
      by_node[static_cast<size_t>(fill[static_cast<size_t>(nodes[q])]++)] = static_cast<int64_t>(q);
  }
};

// Embeds `points` (those with skip[i] == 0) in the lattice of spacing h whose first node lies
// just below their bounding box; keeps the lattice nodes that carry a weight, in lexicographic
// order, and returns their positions in `coarse_points`.
Interpolation embed(std::span<const Vec3d> points, std::span<const uint8_t> skip, double h,
                    std::vector<Vec3d>& coarse_points) {
  Vec3d lo{INFINITY, INFINITY, INFINITY};
  for (const Vec3d& p : points)
    for (int c = 0; c < 3; ++c) lo[c] = std::min(lo[c], p[c]);
  // Below the box by a hair: the smallest coordinate falls inside the first cell, not on its
  // far face.
  const Vec3d origin = lo - Vec3d{1e-9 * h, 1e-9 * h, 1e-9 * h};
  int64_t dims[3] = {0, 0, 0};
  std::vector<std::array<int64_t, 3>> cell(points.size());
  for (size_t i = 0; i < points.size(); ++i)
    for (int c = 0; c < 3; ++c) {
      cell[i][static_cast<size_t>(c)] =
          static_cast<int64_t>(std::floor((points[i][c] - origin[c]) / h));
      dims[c] = std::max(dims[c], cell[i][static_cast<size_t>(c)] + 2);
    }
  auto linear = [&](int64_t x, int64_t y, int64_t z) { return (x * dims[1] + y) * dims[2] + z; };

  // The pairs, with lattice nodes by linear index first; compacted below.
  Interpolation p;
  p.offsets.assign(points.size() + 1, 0);
  std::vector<int64_t> lattice;
  for (size_t i = 0; i < points.size(); ++i) {
    p.offsets[i] = static_cast<int64_t>(lattice.size());
    if (!skip.empty() && skip[i]) continue;
    double f[3];
    for (int c = 0; c < 3; ++c)
      f[c] = (points[i][c] - origin[c]) / h - static_cast<double>(cell[i][static_cast<size_t>(c)]);
    for (int corner = 0; corner < 8; ++corner) {
      double w = 1.0;
      int64_t idx[3];
      for (int c = 0; c < 3; ++c) {
        const int o = (corner >> c) & 1;
        w *= o ? f[c] : 1.0 - f[c];
        idx[c] = cell[i][static_cast<size_t>(c)] + o;
      }
      // A point on a lattice plane has zero weights on the far side: no node for them.
      if (w <= 1e-12) continue;
      lattice.push_back(linear(idx[0], idx[1], idx[2]));
      p.weights.push_back(w);
    }
  }
  p.offsets[points.size()] = static_cast<int64_t>(lattice.size());
  std::vector<int64_t> used = lattice;
  std::sort(used.begin(), used.end());
  used.erase(std::unique(used.begin(), used.end()), used.end());
  p.nodes.resize(lattice.size());
  for (size_t k = 0; k < lattice.size(); ++k)
    p.nodes[k] = static_cast<int32_t>(std::lower_bound(used.begin(), used.end(), lattice[k]) -
                                      used.begin());
  p.coarse_count = used.size();
  coarse_points.resize(used.size());
  for (size_t n = 0; n < used.size(); ++n) {
    const int64_t z = used[n] % dims[2], y = (used[n] / dims[2]) % dims[1],
                  x = used[n] / (dims[1] * dims[2]);
    coarse_points[n] = origin + h * Vec3d{static_cast<double>(x), static_cast<double>(y),
                                          static_cast<double>(z)};
  }
  return p;
}

struct Level {
  // The operator: level 0's is the caller's matrix, the others' are Galerkin products.
  const BlockSparseMatrix* a = nullptr;
  BlockSparseMatrix galerkin;
  // To this level from the next coarser one (absent on the coarsest).
  Interpolation p;
  // The Galerkin product's plan: T = A P (rows of this level, columns of the coarser), then
  // A_c = P^T T; each pair's destination block found once, at the build.
  std::vector<int64_t> t_offsets;
  std::vector<int32_t> t_cols;
  std::vector<Mat3d> t_values;
  std::vector<int32_t> t_target;  // per (block k of A, pair of P's row cols[k])
  std::vector<int32_t> c_target;  // per (row i, pair of P's row i, block of T's row i)
  // Where each row's t_target entries start (rows + 1) and each pair's c_target entries
  // (pairs + 1): the passes run by row (T) and by coarse row (A_c) in parallel.
  std::vector<int64_t> t_row_start, c_pair_start;
  // The rank-one part's restriction c_k = P^T g_k, added into the coarser operator's blocks as
  // c_k c_k^T (no level below the finest keeps a rank-one part: there every term spans some 30
  // lattice nodes, so as vectors a coarse product would cost more than the fine one). Per
  // (position p of A's rank-one vectors, pair of P's row at p's vertex) the position in c;
  // c's terms by node (offsets, nodes, values); per coarse row, the positions of c on it.
  std::vector<int32_t> r1_target;
  std::vector<int64_t> r1_term_start;  // where each term's r1_target entries start (terms + 1)
  std::vector<int64_t> c1_offsets;
  std::vector<int32_t> c1_nodes, c1_term;
  std::vector<Vec3d> c1_values;
  std::vector<int64_t> c1_row_offsets, c1_row_positions;
  // Chebyshev smoothing on D^-1 A.
  std::vector<Mat3d> dinv;
  double lambda_max = 0;
  std::vector<Vec3d> power;
  // Scratch of one cycle.
  std::vector<Vec3d> x, b, r, d, q;
};

class LatticeMultigrid final : public Preconditioner {
 public:
  LatticeMultigrid(std::span<const Vec3d> positions, std::span<const uint8_t> fixed,
                   const MultigridOptions& options)
      : positions_(positions.begin(), positions.end()),
        fixed_(fixed.begin(), fixed.end()),
        options_(options) {}

  const char* name() const override { return "lattice multigrid"; }

  Status setup(const BlockSparseMatrix& a) override {
    if (a.rows() != positions_.size())
      return make_error("multigrid: the matrix has %zu block rows for %zu positions", a.rows(),
                        positions_.size());
    // The hierarchy follows the pattern: built at the first setup, rebuilt if the pattern
    // changes (it does not within a run).
    if (levels_.empty() || a.block_count() != pattern_blocks_) build(a);
    levels_[0].a = &a;
    for (size_t l = 0; l + 1 < levels_.size(); ++l) {
      galerkin(levels_[l], levels_[l + 1].galerkin);
      if (Status s = smoother(levels_[l], l); !s) return s;
    }
    return factor_coarsest();
  }

  // The finest level's smoother follows the matrix (its diagonal blocks and spectral bound);
  // the coarse operators and the coarsest factor stay the last setup's, which keeps the cycle
  // symmetric positive definite (each level's smoother is the one of its own operator).
  Status refresh(const BlockSparseMatrix& a) override {
    if (levels_.empty() || a.block_count() != pattern_blocks_) return setup(a);
    levels_[0].a = &a;
    return smoother(levels_[0], 0);
  }

  void apply(std::span<const Vec3d> r, std::span<Vec3d> z) const override { cycle(0, r, z); }

  std::string structure() const override {
    std::string out;
    for (size_t l = 0; l < levels_.size(); ++l) {
      const BlockSparseMatrix& a = *levels_[l].a;
      out += (l ? "; " : "") + std::string("level ") + std::to_string(l) + ": " +
             std::to_string(a.rows()) + " rows, " + std::to_string(a.block_count()) + " blocks";
      if (a.rank_one_terms() > 0)
        out += " + " + std::to_string(a.rank_one_vertices().size()) + " rank-one entries";
    }
    return out;
  }

 private:
  void build(const BlockSparseMatrix& a);
  void galerkin(Level& fine, BlockSparseMatrix& coarse) const;
  Status smoother(Level& lv, size_t l) const;
  Status factor_coarsest();
  void chebyshev(Level& lv, std::span<const Vec3d> b, std::span<Vec3d> x, bool zero) const;
  void cycle(size_t l, std::span<const Vec3d> b, std::span<Vec3d> x) const;

  std::vector<Vec3d> positions_;
  std::vector<uint8_t> fixed_;
  MultigridOptions options_;
  size_t pattern_blocks_ = 0;
  // mutable: a cycle writes the levels' scratch (apply is const, the operator is fixed).
  mutable std::vector<Level> levels_;
  Eigen::LDLT<Eigen::MatrixXd> coarse_;
  mutable Eigen::VectorXd coarse_rhs_;
};

void LatticeMultigrid::build(const BlockSparseMatrix& a) {
  levels_.clear();
  pattern_blocks_ = a.block_count();
  // The lattice spacing follows the mean distance between coupled free vertices (the blocks'
  // pairs and, with a rank-one part, every pair of a term's vertices: the assembled matrix's
  // pattern).
  std::vector<std::vector<int32_t>> coupled(a.rows());
  for (size_t i = 0; i < a.rows(); ++i)
    coupled[i].assign(a.cols().begin() + a.offsets()[i], a.cols().begin() + a.offsets()[i + 1]);
  std::span<const int64_t> r1_off = a.rank_one_offsets();
  std::span<const int32_t> r1_vert = a.rank_one_vertices();
  for (size_t k = 0; k < a.rank_one_terms(); ++k)
    for (int64_t e = r1_off[k]; e < r1_off[k + 1]; ++e) {
      std::vector<int32_t>& row = coupled[static_cast<size_t>(r1_vert[static_cast<size_t>(e)])];
      row.insert(row.end(), r1_vert.begin() + r1_off[k], r1_vert.begin() + r1_off[k + 1]);
    }
  double sum = 0;
  int64_t count = 0;
  for (size_t i = 0; i < a.rows(); ++i) {
    std::vector<int32_t>& row = coupled[i];
    std::sort(row.begin(), row.end());
    row.erase(std::unique(row.begin(), row.end()), row.end());
    if (!fixed_.empty() && fixed_[i]) continue;
    for (int32_t jj : row) {
      const size_t j = static_cast<size_t>(jj);
      if (j == i || (!fixed_.empty() && fixed_[j])) continue;
      sum += norm(positions_[i] - positions_[j]);
      ++count;
    }
  }
  coupled.clear();
  double h = options_.spacing_factor * (count > 0 ? sum / static_cast<double>(count) : 1.0);

  std::vector<Vec3d> points = positions_, coarse_points;
  std::span<const uint8_t> skip = fixed_;
  const BlockSparseMatrix* pattern = &a;
  levels_.emplace_back();
  while (static_cast<int64_t>(3 * points.size()) > options_.max_coarse_unknowns) {
    Interpolation p = embed(points, skip, h, coarse_points);
    // A lattice no coarser than its points (a tiny or degenerate mesh) ends the hierarchy.
    if (p.coarse_count == 0 || p.coarse_count >= points.size()) break;
    Level& fine = levels_.back();
    fine.p = std::move(p);
    fine.p.transpose();
    const Interpolation& ip = fine.p;
    const size_t n = pattern->rows();
    // T = A P: row i's columns are the coarse nodes of its neighbours' pairs.
    fine.t_offsets.assign(n + 1, 0);
    fine.t_cols.clear();
    std::vector<int32_t> row;
    for (size_t i = 0; i < n; ++i) {
      row.clear();
      for (int64_t k = pattern->offsets()[i]; k < pattern->offsets()[i + 1]; ++k) {
        const size_t j = static_cast<size_t>(pattern->cols()[static_cast<size_t>(k)]);
        for (int64_t q = ip.offsets[j]; q < ip.offsets[j + 1]; ++q)
          row.push_back(ip.nodes[static_cast<size_t>(q)]);
      }
      std::sort(row.begin(), row.end());
      row.erase(std::unique(row.begin(), row.end()), row.end());
      fine.t_cols.insert(fine.t_cols.end(), row.begin(), row.end());
      fine.t_offsets[i + 1] = static_cast<int64_t>(fine.t_cols.size());
    }
    fine.t_values.assign(fine.t_cols.size(), Mat3d::zero());
    fine.t_target.clear();
    fine.t_row_start.assign(1, 0);
    for (size_t i = 0; i < n; ++i) {
      const auto t_begin = fine.t_cols.begin() + fine.t_offsets[i];
      const auto t_end = fine.t_cols.begin() + fine.t_offsets[i + 1];
      for (int64_t k = pattern->offsets()[i]; k < pattern->offsets()[i + 1]; ++k) {
        const size_t j = static_cast<size_t>(pattern->cols()[static_cast<size_t>(k)]);
        for (int64_t q = ip.offsets[j]; q < ip.offsets[j + 1]; ++q)
          fine.t_target.push_back(static_cast<int32_t>(
              std::lower_bound(t_begin, t_end, ip.nodes[static_cast<size_t>(q)]) -
              fine.t_cols.begin()));
      }
      fine.t_row_start.push_back(static_cast<int64_t>(fine.t_target.size()));
    }
    // The rank-one part's restriction: each term's coarse nodes, and where each fine entry's
    // pairs land among them.
    fine.r1_target.clear();
    fine.r1_term_start.assign(1, 0);
    fine.c1_offsets.assign(1, 0);
    fine.c1_nodes.clear();
    fine.c1_term.clear();
    if (pattern->rank_one_terms() > 0) {
      std::span<const int64_t> off = pattern->rank_one_offsets();
      std::span<const int32_t> vert = pattern->rank_one_vertices();
      std::vector<int32_t> nodes;
      for (size_t k = 0; k + 1 < off.size(); ++k) {
        nodes.clear();
        for (int64_t e = off[k]; e < off[k + 1]; ++e) {
          const size_t j = static_cast<size_t>(vert[static_cast<size_t>(e)]);
          for (int64_t q = ip.offsets[j]; q < ip.offsets[j + 1]; ++q)
            nodes.push_back(ip.nodes[static_cast<size_t>(q)]);
        }
        std::sort(nodes.begin(), nodes.end());
        nodes.erase(std::unique(nodes.begin(), nodes.end()), nodes.end());
        for (int64_t e = off[k]; e < off[k + 1]; ++e) {
          const size_t j = static_cast<size_t>(vert[static_cast<size_t>(e)]);
          for (int64_t q = ip.offsets[j]; q < ip.offsets[j + 1]; ++q)
            fine.r1_target.push_back(static_cast<int32_t>(
                fine.c1_offsets.back() + (std::lower_bound(nodes.begin(), nodes.end(),
                                                           ip.nodes[static_cast<size_t>(q)]) -
                                          nodes.begin())));
        }
        fine.r1_term_start.push_back(static_cast<int64_t>(fine.r1_target.size()));
        fine.c1_nodes.insert(fine.c1_nodes.end(), nodes.begin(), nodes.end());
        fine.c1_term.insert(fine.c1_term.end(), nodes.size(), static_cast<int32_t>(k));
        fine.c1_offsets.push_back(static_cast<int64_t>(fine.c1_nodes.size()));
      }
      // Per coarse row, the positions of c on it.
      fine.c1_row_offsets.assign(ip.coarse_count + 1, 0);
      for (int32_t node : fine.c1_nodes) ++fine.c1_row_offsets[static_cast<size_t>(node) + 1];
      for (size_t r = 0; r < ip.coarse_count; ++r)
        fine.c1_row_offsets[r + 1] += fine.c1_row_offsets[r];
      fine.c1_row_positions.resize(fine.c1_nodes.size());
      std::vector<int64_t> fill(fine.c1_row_offsets.begin(), fine.c1_row_offsets.end() - 1);
      for (size_t q = 0; q < fine.c1_nodes.size(); ++q)
        fine.c1_row_positions[static_cast<size_t>(
            fill[static_cast<size_t>(fine.c1_nodes[q])]++)] = static_cast<int64_t>(q);
    }
    fine.c1_values.assign(fine.c1_nodes.size(), Vec3d{0, 0, 0});
    // A_c = P^T T: coarse row I gathers T's rows i over the pairs (i, I).
    std::vector<std::vector<int32_t>> rows(ip.coarse_count);
    for (size_t i = 0; i < n; ++i)
      for (int64_t q = ip.offsets[i]; q < ip.offsets[i + 1]; ++q) {
        std::vector<int32_t>& r = rows[static_cast<size_t>(ip.nodes[static_cast<size_t>(q)])];
        r.insert(r.end(), fine.t_cols.begin() + fine.t_offsets[i],
                 fine.t_cols.begin() + fine.t_offsets[i + 1]);
      }
    // c_k c_k^T couples every pair of a term's nodes.
    for (size_t k = 0; k + 1 < fine.c1_offsets.size(); ++k)
      for (int64_t e = fine.c1_offsets[k]; e < fine.c1_offsets[k + 1]; ++e) {
        std::vector<int32_t>& r = rows[static_cast<size_t>(fine.c1_nodes[static_cast<size_t>(e)])];
        r.insert(r.end(), fine.c1_nodes.begin() + fine.c1_offsets[k],
                 fine.c1_nodes.begin() + fine.c1_offsets[k + 1]);
      }
    for (std::vector<int32_t>& r : rows) {
      std::sort(r.begin(), r.end());
      r.erase(std::unique(r.begin(), r.end()), r.end());
    }
    Level coarse;
    coarse.galerkin = BlockSparseMatrix(rows);
    rows.clear();
    fine.c_target.clear();
    fine.c_pair_start.clear();
    for (size_t i = 0; i < n; ++i)
      for (int64_t q = ip.offsets[i]; q < ip.offsets[i + 1]; ++q) {
        const int32_t ci = ip.nodes[static_cast<size_t>(q)];
        fine.c_pair_start.push_back(static_cast<int64_t>(fine.c_target.size()));
        for (int64_t t = fine.t_offsets[i]; t < fine.t_offsets[i + 1]; ++t)
          fine.c_target.push_back(static_cast<int32_t>(
              coarse.galerkin.block_index(ci, fine.t_cols[static_cast<size_t>(t)])));
      }
    fine.c_pair_start.push_back(static_cast<int64_t>(fine.c_target.size()));
    levels_.push_back(std::move(coarse));
    levels_.back().a = &levels_.back().galerkin;
    // levels_ may have moved: the pattern of the next round is the new coarse operator.
    pattern = &levels_.back().galerkin;
    points = coarse_points;
    skip = {};
    h *= 2.0;
  }
  for (size_t l = 1; l < levels_.size(); ++l) levels_[l].a = &levels_[l].galerkin;
  for (size_t l = 0; l < levels_.size(); ++l) {
    Level& lv = levels_[l];
    const size_t n = l == 0 ? a.rows() : lv.galerkin.rows();
    for (std::vector<Vec3d>* v : {&lv.x, &lv.b, &lv.r, &lv.d, &lv.q}) v->assign(n, Vec3d{0, 0, 0});
    // The power iteration's start: a fixed, non-smooth vector (deterministic runs).
    lv.power.resize(n);
    for (size_t i = 0; i < n; ++i)
      lv.power[i] = Vec3d{1.0 + 0.5 * std::sin(1.7 * static_cast<double>(i)),
                          1.0 + 0.5 * std::cos(2.3 * static_cast<double>(i)),
                          1.0 + 0.5 * std::sin(0.9 * static_cast<double>(i) + 1.0)};
  }
}

void LatticeMultigrid::galerkin(Level& fine, BlockSparseMatrix& coarse) const {
  const BlockSparseMatrix& a = *fine.a;
  const Interpolation& ip = fine.p;
  std::span<const Mat3d> av = a.values();
  // T = A P, row by row (a row's blocks take only its own sums, in a fixed order).
  pooled_ranges(a.rows(), 256, [&](size_t, size_t begin, size_t end) {
    for (size_t i = begin; i < end; ++i) {
      std::fill(fine.t_values.begin() + fine.t_offsets[i],
                fine.t_values.begin() + fine.t_offsets[i + 1], Mat3d::zero());
      size_t pos = static_cast<size_t>(fine.t_row_start[i]);
      for (int64_t k = a.offsets()[i]; k < a.offsets()[i + 1]; ++k) {
        const size_t j = static_cast<size_t>(a.cols()[static_cast<size_t>(k)]);
        for (int64_t q = ip.offsets[j]; q < ip.offsets[j + 1]; ++q) {
          Mat3d& t = fine.t_values[static_cast<size_t>(fine.t_target[pos++])];
          t = t + ip.weights[static_cast<size_t>(q)] * av[static_cast<size_t>(k)];
        }
      }
    }
  });
  // A_c = P^T T by coarse row: row I takes its pairs (i, I) in ascending i, each pair's T row
  // into I's blocks (the order of a pass over i: the same sums).
  coarse.set_zero();
  std::span<Mat3d> cv = coarse.values();
  pooled_ranges(ip.coarse_count, 64, [&](size_t, size_t begin, size_t end) {
    for (size_t row = begin; row < end; ++row)
      for (int64_t e = ip.by_node_offsets[row]; e < ip.by_node_offsets[row + 1]; ++e) {
        const size_t q = static_cast<size_t>(ip.by_node[static_cast<size_t>(e)]);
        const size_t i = static_cast<size_t>(ip.row[q]);
        const double w = ip.weights[q];
        size_t pos = static_cast<size_t>(fine.c_pair_start[q]);
        for (int64_t t = fine.t_offsets[i]; t < fine.t_offsets[i + 1]; ++t) {
          Mat3d& c = cv[static_cast<size_t>(fine.c_target[pos++])];
          c = c + w * fine.t_values[static_cast<size_t>(t)];
        }
      }
  });
  if (a.rank_one_terms() == 0) return;
  // c_k = P^T g_k, then c_k c_k^T into the coarse blocks, row by row (each row written by one
  // thread, in a fixed order: the same bits on any thread count).
  std::span<const int32_t> vert = a.rank_one_vertices();
  std::span<const Vec3d> g = a.rank_one_vectors();
  std::span<const double> coef = a.rank_one_coefficients();
  std::span<const int64_t> off = a.rank_one_offsets();
  // c_k term by term (a term's entries land in its own c_k).
  pooled_ranges(a.rank_one_terms(), 256, [&](size_t, size_t begin, size_t end) {
    for (size_t k = begin; k < end; ++k) {
      std::fill(fine.c1_values.begin() + fine.c1_offsets[k],
                fine.c1_values.begin() + fine.c1_offsets[k + 1], Vec3d{0, 0, 0});
      size_t pos = static_cast<size_t>(fine.r1_term_start[k]);
      for (int64_t pp = off[k]; pp < off[k + 1]; ++pp) {
        const size_t p = static_cast<size_t>(pp);
        const size_t j = static_cast<size_t>(vert[p]);
        for (int64_t q = ip.offsets[j]; q < ip.offsets[j + 1]; ++q)
          fine.c1_values[static_cast<size_t>(fine.r1_target[pos++])] +=
              ip.weights[static_cast<size_t>(q)] * g[p];
      }
    }
  });
  pooled_ranges(coarse.rows(), 64, [&](size_t, size_t begin, size_t end) {
    for (size_t row = begin; row < end; ++row)
      for (int64_t r = fine.c1_row_offsets[row]; r < fine.c1_row_offsets[row + 1]; ++r) {
        const size_t pa = static_cast<size_t>(fine.c1_row_positions[static_cast<size_t>(r)]);
        const size_t k = static_cast<size_t>(fine.c1_term[pa]);
        const Vec3d ca = coef[k] * fine.c1_values[pa];
        for (int64_t pb = fine.c1_offsets[k]; pb < fine.c1_offsets[k + 1]; ++pb) {
          Mat3d& block =
              *coarse.find(static_cast<int32_t>(row), fine.c1_nodes[static_cast<size_t>(pb)]);
          block = block + outer(ca, fine.c1_values[static_cast<size_t>(pb)]);
        }
      }
  });
}

Status LatticeMultigrid::smoother(Level& lv, size_t l) const {
  const BlockSparseMatrix& a = *lv.a;
  a.diagonal(lv.dinv);
  if (const size_t i = invert_blocks(lv.dinv, true); i < lv.dinv.size())
    return make_error("multigrid: the diagonal block of node %zu on level %zu is not positive "
                      "definite",
                      i, l);
  // lambda_max(D^-1 A) by power iteration; the vector is kept for the next setup, whose matrix
  // is close to this one.
  std::vector<Vec3d>& v = lv.power;
  double lambda = 0;
  // Warm (a setup after the first): at least power_iterations_warm, on until the estimate
  // moves by under 1 % (a matrix far from the last one takes the full count).
  const bool warm = lv.lambda_max > 0;
  for (int it = 0; it < options_.power_iterations; ++it) {
    a.multiply(v, lv.q);
    pooled_ranges(v.size(), kVectorRange, [&](size_t, size_t begin, size_t end) {
      for (size_t i = begin; i < end; ++i) lv.q[i] = lv.dinv[i] * lv.q[i];
    });
    const double vn = std::sqrt(dot_all(v, v)), qn = std::sqrt(dot_all(lv.q, lv.q));
    if (!(qn > 0)) break;
    const double previous = lambda;
    lambda = qn / vn;
    pooled_ranges(v.size(), kVectorRange, [&](size_t, size_t begin, size_t end) {
      for (size_t i = begin; i < end; ++i) v[i] = lv.q[i] / qn;
    });
    if (warm && it + 1 >= options_.power_iterations_warm &&
        std::fabs(lambda - previous) <= 1e-2 * lambda)
      break;
  }
  if (!(lambda > 0) || !std::isfinite(lambda))
    return make_error("multigrid: no spectral bound on level %zu", l);
  lv.lambda_max = options_.lambda_safety * lambda;
  return {};
}

Status LatticeMultigrid::factor_coarsest() {
  const Level& lv = levels_.back();
  const BlockSparseMatrix& a = *lv.a;
  const Eigen::Index n = static_cast<Eigen::Index>(3 * a.rows());
  Eigen::MatrixXd dense = Eigen::MatrixXd::Zero(n, n);
  for (size_t i = 0; i < a.rows(); ++i)
    for (int64_t k = a.offsets()[i]; k < a.offsets()[i + 1]; ++k) {
      const Eigen::Index j = a.cols()[static_cast<size_t>(k)];
      const Mat3d& b = a.values()[static_cast<size_t>(k)];
      for (int r = 0; r < 3; ++r)
        for (int c = 0; c < 3; ++c)
          dense(static_cast<Eigen::Index>(3 * i) + r, 3 * j + c) = b.m[r][c];
    }
  std::span<const int64_t> off = a.rank_one_offsets();
  std::span<const int32_t> vert = a.rank_one_vertices();
  std::span<const Vec3d> g = a.rank_one_vectors();
  for (size_t k = 0; k < a.rank_one_terms(); ++k)
    for (int64_t p = off[k]; p < off[k + 1]; ++p)
      for (int64_t q = off[k]; q < off[k + 1]; ++q) {
        const Vec3d x = a.rank_one_coefficients()[k] * g[static_cast<size_t>(p)];
        const Vec3d& y = g[static_cast<size_t>(q)];
        const Eigen::Index i = 3 * vert[static_cast<size_t>(p)], j = 3 * vert[static_cast<size_t>(q)];
        for (int r = 0; r < 3; ++r)
          for (int c = 0; c < 3; ++c) dense(i + r, j + c) += x[r] * y[c];
      }
  coarse_.compute(dense);
  if (coarse_.info() != Eigen::Success || !coarse_.isPositive())
    return make_error("multigrid: the coarsest operator (%lld unknowns) is not positive definite",
                      static_cast<long long>(n));
  coarse_rhs_.resize(n);
  return {};
}

// Chebyshev iteration on D^-1 A x = D^-1 b over [lambda_max / ratio, lambda_max] (Saad,
// Iterative Methods, Alg. 12.1): degree k costs k - 1 products, plus one for the residual when
// x does not start at zero. The same polynomial before and after the coarse correction keeps
// the cycle symmetric.
void LatticeMultigrid::chebyshev(Level& lv, std::span<const Vec3d> b, std::span<Vec3d> x,
                                 bool zero) const {
  const BlockSparseMatrix& a = *lv.a;
  const size_t n = b.size();
  const double upper = lv.lambda_max, lower = upper / options_.chebyshev_ratio;
  const double theta = 0.5 * (upper + lower), delta = 0.5 * (upper - lower);
  const double sigma = theta / delta;
  double rho = 1.0 / sigma;
  std::vector<Vec3d>& z = lv.r;
  std::vector<Vec3d>& d = lv.d;
  ZONA_ASSERT(options_.chebyshev_degree >= 1);
  // (The vector passes elementwise on the shared pool.)
  if (!zero) a.multiply(x, lv.q);
  pooled_ranges(n, kVectorRange, [&](size_t, size_t begin, size_t end) {
    for (size_t i = begin; i < end; ++i) {
      if (zero) {
        x[i] = Vec3d{0, 0, 0};
        z[i] = lv.dinv[i] * b[i];
      } else {
        z[i] = lv.dinv[i] * (b[i] - lv.q[i]);
      }
      d[i] = z[i] / theta;
      x[i] += d[i];
    }
  });
  for (int it = 1; it < options_.chebyshev_degree; ++it) {
    a.multiply(d, lv.q);
    const double rho_next = 1.0 / (2.0 * sigma - rho);
    const double c1 = rho_next * rho, c2 = 2.0 * rho_next / delta;
    pooled_ranges(n, kVectorRange, [&](size_t, size_t begin, size_t end) {
      for (size_t i = begin; i < end; ++i) {
        z[i] -= lv.dinv[i] * lv.q[i];
        d[i] = c1 * d[i] + c2 * z[i];
        x[i] += d[i];
      }
    });
    rho = rho_next;
  }
}

void LatticeMultigrid::cycle(size_t l, std::span<const Vec3d> b, std::span<Vec3d> x) const {
  if (l + 1 == levels_.size()) {
    const Eigen::Index n = coarse_rhs_.size();
    coarse_rhs_ = Eigen::Map<const Eigen::VectorXd>(&b[0].x, n);
    Eigen::Map<Eigen::VectorXd>(&x[0].x, n) = coarse_.solve(coarse_rhs_);
    return;
  }
  Level& lv = levels_[l];
  Level& coarse = levels_[l + 1];
  const size_t n = b.size();
  chebyshev(lv, b, x, true);
  // Restrict the residual: b_c = P^T (b - A x), gathered by coarse node (each node's pairs in
  // ascending fine node: the sums of a scatter over the fine nodes).
  lv.a->multiply(x, lv.q);
  std::vector<Vec3d>& r = lv.r;
  pooled_ranges(n, kVectorRange, [&](size_t, size_t begin, size_t end) {
    for (size_t i = begin; i < end; ++i) r[i] = b[i] - lv.q[i];
  });
  const Interpolation& ip = lv.p;
  pooled_ranges(ip.coarse_count, kVectorRange, [&](size_t, size_t begin, size_t end) {
    for (size_t node = begin; node < end; ++node) {
      Vec3d sum{0, 0, 0};
      for (int64_t e = ip.by_node_offsets[node]; e < ip.by_node_offsets[node + 1]; ++e) {
        const size_t q = static_cast<size_t>(ip.by_node[static_cast<size_t>(e)]);
        sum += ip.weights[q] * r[static_cast<size_t>(ip.row[q])];
      }
      coarse.b[node] = sum;
    }
  });
  cycle(l + 1, coarse.b, coarse.x);
  // Prolong the correction: x += P x_c.
  pooled_ranges(n, kVectorRange, [&](size_t, size_t begin, size_t end) {
    for (size_t i = begin; i < end; ++i)
      for (int64_t q = ip.offsets[i]; q < ip.offsets[i + 1]; ++q)
        x[i] += ip.weights[static_cast<size_t>(q)] *
                coarse.x[static_cast<size_t>(ip.nodes[static_cast<size_t>(q)])];
  });
  chebyshev(lv, b, x, false);
}

}  // namespace

std::unique_ptr<Preconditioner> make_multigrid(std::span<const Vec3d> positions,
                                               std::span<const uint8_t> fixed,
                                               const MultigridOptions& options) {
  return std::make_unique<LatticeMultigrid>(positions, fixed, options);
}

}  // namespace zona
