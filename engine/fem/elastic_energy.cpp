// The elastic energy term over the model (elastic_energy.h): element loops over elastic_term.h.
#include "engine/fem/elastic_energy.h"

#include <algorithm>
#include <cmath>
#include <limits>

#include <Eigen/Dense>

#include "engine/core/parallel.h"

namespace zona {
namespace {

// Each vertex's star: its elements' corners, first seen first (offsets (vertex_count + 1)).
// With `slots`, also where each adjacency entry's corners sit in its vertex's star: corner c of
// entry k at star position slots[4 k + c] (a star has at most 255 vertices).
void vertex_stars(const Model& m, std::vector<int64_t>& offsets, std::vector<int32_t>& star,
                  std::vector<uint8_t>* slots = nullptr) {
  offsets.assign(1, 0);
  star.clear();
  if (slots) slots->assign(4 * m.adjacency.tets.size(), 0);
  for (size_t v = 0; v < m.vertex_count(); ++v) {
    const size_t begin = star.size();
    for (int32_t k = m.adjacency.offsets[v]; k < m.adjacency.offsets[v + 1]; ++k)
      for (int c = 0; c < 4; ++c) {
        const int32_t w = m.tets[static_cast<size_t>(m.adjacency.tets[static_cast<size_t>(k)])][c];
        const auto at = std::find(star.begin() + static_cast<std::ptrdiff_t>(begin), star.end(), w);
        const size_t i = static_cast<size_t>(at - star.begin()) - begin;
        if (at == star.end()) star.push_back(w);
        if (slots) {
          ZONA_ASSERT(i < 256);
          (*slots)[4 * static_cast<size_t>(k) + static_cast<size_t>(c)] = static_cast<uint8_t>(i);
        }
      }
    offsets.push_back(static_cast<int64_t>(star.size()));
  }
}

}  // namespace

Result<ElasticEnergy> ElasticEnergy::create(const Model& model) {
  if (model.constitutive == ConstitutiveModel::kSvk &&
      model.inversion == InversionHandling::kClampStretch)
    return make_error(
        "the clamped St Venant-Kirchhoff law has no energy of its own: use inversion 'report' "
        "or the stable neo-Hookean law");
  return ElasticEnergy(model);
}

ElasticEnergy::ElasticEnergy(const Model& model) : model_(&model) {
  if (!model.nodal_pressure) return;
  pressure_.assign(model.vertex_count(), 0.0);
  scratch_.assign(model.vertex_count(), 0.0);
  vertex_stars(model, star_offsets_, star_, &star_slot_);
}

void ElasticEnergy::star_gradient(size_t v, std::span<const Vec3d> u, Vec3d* out) const {
  const Model& m = *model_;
  const int64_t s0 = star_offsets_[v];
  std::fill(out, out + (star_offsets_[v + 1] - s0), Vec3d{0, 0, 0});
  for (int32_t k = m.adjacency.offsets[v]; k < m.adjacency.offsets[v + 1]; ++k) {
    const size_t t = static_cast<size_t>(m.adjacency.tets[static_cast<size_t>(k)]);
    Vec3d ue[4], dj[4];
    corners(u, t, ue);
    tet_volume_gradient(m.tet_shape[t], ue, dj);
    const uint8_t* slot = &star_slot_[4 * static_cast<size_t>(k)];
    for (int c = 0; c < 4; ++c) out[slot[c]] += (0.25 * m.tet_shape[t].volume) * dj[c];
  }
}

void ElasticEnergy::corners(std::span<const Vec3d> x, size_t t, Vec3d out[4]) const {
  for (int c = 0; c < 4; ++c) out[c] = x[static_cast<size_t>(model_->tets[t][c])];
}

ElementLaw<double> ElasticEnergy::law(size_t t) const {
  const Lame& lame = model_->tet_lame(t);
  ElementLaw<double> law;
  law.model = model_->constitutive;
  law.lambda = lame.lambda;
  law.mu = lame.mu;
  law.nodal = model_->nodal_pressure && model_->constitutive == ConstitutiveModel::kStableNeoHookean;
  if (law.nodal) {
    double p = 0;
    for (int c = 0; c < 4; ++c) p += pressure_[static_cast<size_t>(model_->tets[t][c])];
    law.pressure = 0.25 * p;
    law.element_lambda = model_->nodal_stabilisation * lame.lambda;
  }
  if (barrier_volume_ > 0 && law.model == ConstitutiveModel::kStableNeoHookean) {
    law.barrier_volume = barrier_volume_;
    law.barrier_stiffness = lame.mu;
  }
  return law;
}

void ElasticEnergy::colour_runs() {
  const Model& m = *model_;
  if (!colour_offsets_.empty() || m.tet_count() == 0) return;
  // Greedy colouring of runs of kRun consecutive elements (the mesh's order keeps a run's
  // blocks close in memory): each run takes the first colour that no run sharing a corner with
  // it has yet.
  const size_t runs = (m.tet_count() + kRun - 1) / kRun;
  std::vector<int32_t> colour(runs, -1);
  std::vector<uint8_t> taken;
  int32_t colours = 0;
  for (size_t r = 0; r < runs; ++r) {
    taken.assign(static_cast<size_t>(colours) + 1, 0);
    for (size_t t = r * kRun; t < std::min(m.tet_count(), (r + 1) * kRun); ++t)
      for (int32_t v : m.tets[t])
        for (int32_t k = m.adjacency.offsets[static_cast<size_t>(v)];
             k < m.adjacency.offsets[static_cast<size_t>(v) + 1]; ++k) {
          const int32_t c =
              colour[static_cast<size_t>(m.adjacency.tets[static_cast<size_t>(k)]) / kRun];
          if (c >= 0) taken[static_cast<size_t>(c)] = 1;
        }
    int32_t c = 0;
    while (taken[static_cast<size_t>(c)]) ++c;
    colour[r] = c;
    colours = std::max(colours, c + 1);
  }
  colour_offsets_.assign(static_cast<size_t>(colours) + 1, 0);
  for (int32_t c : colour) ++colour_offsets_[static_cast<size_t>(c) + 1];
  for (size_t c = 0; c < static_cast<size_t>(colours); ++c)
    colour_offsets_[c + 1] += colour_offsets_[c];
  colour_runs_.resize(runs);
  std::vector<int64_t> next(colour_offsets_.begin(), colour_offsets_.end() - 1);
  for (size_t r = 0; r < runs; ++r)
    colour_runs_[static_cast<size_t>(next[static_cast<size_t>(colour[r])]++)] =
        static_cast<int32_t>(r);
  run_sum_.assign(runs, 0.0);
}

template <class F>
double ElasticEnergy::coloured_sum(const F& f) {
  colour_runs();
  const size_t nt = model_->tet_count();
  for (size_t c = 0; c + 1 < colour_offsets_.size(); ++c) {
    const size_t begin = static_cast<size_t>(colour_offsets_[c]);
    pooled_ranges(static_cast<size_t>(colour_offsets_[c + 1]) - begin, 8,
                  [&](size_t, size_t b, size_t e) {
                    for (size_t k = begin + b; k < begin + e; ++k) {
                      const size_t r = static_cast<size_t>(colour_runs_[k]);
                      double sum = 0;
                      for (size_t t = r * kRun; t < std::min(nt, (r + 1) * kRun); ++t) sum += f(t);
                      run_sum_[r] = sum;
                    }
                  });
  }
  double total = 0;
  for (double x : run_sum_) total += x;
  return total;
}

double ElasticEnergy::vertex_pressures(std::span<const Vec3d> u) {
  const Model& m = *model_;
  // Pass 1: sum_e V_e / 4 (J_e - 1) at each corner.
  std::fill(scratch_.begin(), scratch_.end(), 0.0);
  coloured_sum([&](size_t t) {
    Vec3d ue[4];
    corners(u, t, ue);
    const double q = 0.25 * m.tet_shape[t].volume *
                     snh_volume_change(tet_displacement_gradient(m.tet_shape[t], ue));
    for (int c = 0; c < 4; ++c) scratch_[static_cast<size_t>(m.tets[t][c])] += q;
    return 0.0;
  });
  // Pass 2: Jbar_v - 1, the pressure lambda_v (Jbar_v - 1) and the energy V_v lambda_v / 2
  // (Jbar_v - 1)^2, per fixed chunk of vertices, the chunks summed in order.
  return pooled_chunk_sum(m.vertex_count(), 4096, chunk_sum_, [&](size_t begin, size_t end) {
    double energy = 0;
    for (size_t v = begin; v < end; ++v) {
      const double inv_volume = m.vertex_inverse_volume[v];
      const double jm1 = scratch_[v] * inv_volume;
      pressure_[v] = m.vertex_lambda[v] * jm1;
      if (inv_volume > 0) energy += 0.5 * m.vertex_lambda[v] * jm1 * jm1 / inv_volume;
    }
    return energy;
  });
}

double ElasticEnergy::energy(std::span<const Vec3d> u) {
  const Model& m = *model_;
  ZONA_ASSERT(u.size() == m.vertex_count());
  const double w = m.nodal_pressure ? vertex_pressures(u) : 0.0;
  return w + coloured_sum([&](size_t t) {
    Vec3d ue[4];
    corners(u, t, ue);
    // The element part (element_stress leaves the pressure's energy to the vertices' sum).
    Mat3d p;
    double jm1;
    return m.tet_shape[t].volume *
           element_stress(law(t), tet_displacement_gradient(m.tet_shape[t], ue), &p, &jm1);
  });
}

double ElasticEnergy::add_gradient_energy(std::span<const Vec3d> u, std::span<Vec3d> g) {
  const Model& m = *model_;
  ZONA_ASSERT(u.size() == m.vertex_count() && g.size() == m.vertex_count());
  const double w = m.nodal_pressure ? vertex_pressures(u) : 0.0;
  return w + coloured_sum([&](size_t t) {
    Vec3d ue[4], ge[4];
    corners(u, t, ue);
    const double e = tet_energy_gradient(m.tet_shape[t], law(t), ue, ge);
    for (int c = 0; c < 4; ++c) g[static_cast<size_t>(m.tets[t][c])] += ge[c];
    return e;
  });
}

void ElasticEnergy::add_hessian_product(std::span<const Vec3d> u, std::span<const Vec3d> v,
                                        std::span<Vec3d> y) {
  const Model& m = *model_;
  ZONA_ASSERT(u.size() == m.vertex_count() && v.size() == u.size() && y.size() == u.size());
  if (m.nodal_pressure) vertex_pressures(u);
  // The element part (the vertices' pressures held).
  for (size_t t = 0; t < m.tet_count(); ++t) {
    Vec3d ue[4], ve[4], ye[4];
    corners(u, t, ue);
    corners(v, t, ve);
    tet_hessian_product(m.tet_shape[t], law(t), ue, ve, ye);
    for (int c = 0; c < 4; ++c) y[static_cast<size_t>(m.tets[t][c])] += ye[c];
  }
  if (!m.nodal_pressure) return;
  // The vertices' rank-one terms sum_v (lambda_v / V_v) g_v (g_v . v), in the force's two
  // passes: s_v = g_v . v = sum_e V_e / 4 dJ_e[v] per vertex, then each element's corners get
  // V_e dJ_e/du times the corner mean of (lambda_v / V_v) s_v.
  std::fill(scratch_.begin(), scratch_.end(), 0.0);
  for (size_t t = 0; t < m.tet_count(); ++t) {
    Vec3d ue[4], ve[4], dj[4];
    corners(u, t, ue);
    corners(v, t, ve);
    tet_volume_gradient(m.tet_shape[t], ue, dj);
    double djv = 0;
    for (int c = 0; c < 4; ++c) djv += dot(dj[c], ve[c]);
    for (int c = 0; c < 4; ++c)
      scratch_[static_cast<size_t>(m.tets[t][c])] += 0.25 * m.tet_shape[t].volume * djv;
  }
  for (size_t k = 0; k < m.vertex_count(); ++k)
    scratch_[k] *= m.vertex_lambda[k] * m.vertex_inverse_volume[k];
  for (size_t t = 0; t < m.tet_count(); ++t) {
    Vec3d ue[4], dj[4];
    corners(u, t, ue);
    tet_volume_gradient(m.tet_shape[t], ue, dj);
    double mean = 0;
    for (int c = 0; c < 4; ++c) mean += scratch_[static_cast<size_t>(m.tets[t][c])];
    const double w = 0.25 * m.tet_shape[t].volume * mean;
    for (int c = 0; c < 4; ++c) y[static_cast<size_t>(m.tets[t][c])] += w * dj[c];
  }
}

void ElasticEnergy::add_hessian_diagonal(std::span<const Vec3d> u, std::span<Mat3d> d) {
  const Model& m = *model_;
  ZONA_ASSERT(u.size() == m.vertex_count() && d.size() == u.size());
  if (m.nodal_pressure) vertex_pressures(u);
  for (size_t t = 0; t < m.tet_count(); ++t) {
    Vec3d ue[4];
    Mat3d de[4];
    corners(u, t, ue);
    tet_hessian_diagonal(m.tet_shape[t], law(t), ue, de);
    for (int c = 0; c < 4; ++c) {
      Mat3d& block = d[static_cast<size_t>(m.tets[t][c])];
      block = block + de[c];
    }
  }
  if (!m.nodal_pressure) return;
  // The rank-one terms' diagonal blocks: for each vertex v and each vertex w of its star,
  // (lambda_v / V_v) g_v[w] g_v[w]^T with g_v[w] = sum over v's elements holding w of
  // V_e / 4 dJ_e/du_w.
  for (size_t v = 0; v < m.vertex_count(); ++v) {
    star_part_.resize(static_cast<size_t>(star_offsets_[v + 1] - star_offsets_[v]));
    star_gradient(v, u, star_part_.data());
    const double c = m.vertex_lambda[v] * m.vertex_inverse_volume[v];
    for (size_t i = 0; i < star_part_.size(); ++i) {
      Mat3d& block = d[static_cast<size_t>(star_[static_cast<size_t>(star_offsets_[v]) + i])];
      block = block + c * outer(star_part_[i], star_part_[i]);
    }
  }
}

double ElasticEnergy::min_volume_ratio(std::span<const Vec3d> u) const {
  const Model& m = *model_;
  double lo = std::numeric_limits<double>::infinity();
  for (size_t t = 0; t < m.tet_count(); ++t) {
    Vec3d ue[4];
    corners(u, t, ue);
    lo = std::min(lo, 1.0 + snh_volume_change(tet_displacement_gradient(m.tet_shape[t], ue)));
  }
  return lo;
}

BlockSparseMatrix ElasticEnergy::hessian_pattern(const Model& m) {
  const size_t n = m.vertex_count();
  // Row v: the corners of v's elements.
  std::vector<std::vector<int32_t>> rows(n);
  for (size_t v = 0; v < n; ++v)
    for (int32_t k = m.adjacency.offsets[v]; k < m.adjacency.offsets[v + 1]; ++k)
      for (int32_t w : m.tets[static_cast<size_t>(m.adjacency.tets[static_cast<size_t>(k)])])
        rows[v].push_back(w);
  BlockSparseMatrix h(rows);
  if (m.nodal_pressure) {
    std::vector<int64_t> offsets;
    std::vector<int32_t> star;
    vertex_stars(m, offsets, star);
    h.set_rank_one_pattern(std::move(offsets), std::move(star));
  }
  return h;
}

namespace {

// The 9 x 9 matrix d^2 Psi / dF^2 of a law at h (row and column k = 3 r + c for F's entry
// (r, c)), symmetrised; with `project`, its negative eigenvalues clamped to zero (in closed
// form for the stable neo-Hookean law, by a 9 x 9 eigendecomposition for the others), into out.
void stress_tangent(const ElementLaw<double>& law, const Mat3d& h, bool project, double out[9][9]) {
  if (law.model == ConstitutiveModel::kStableNeoHookean) {
    // Closed form, and its projection too (snh_project_tangent): no eigendecomposition.
    snh_stress_tangent(law, h, out);
    if (project) snh_project_tangent(law, h, out);
    return;
  }
  Eigen::Matrix<double, 9, 9> q;
  for (int k = 0; k < 9; ++k) {
    Mat3d df = Mat3d::zero();
    df.m[k / 3][k % 3] = 1;
    const Mat3d dp = element_stress_differential(law, h, df);
    for (int r = 0; r < 3; ++r)
      for (int c = 0; c < 3; ++c) q(3 * r + c, k) = dp.m[r][c];
  }
  q = 0.5 * (q + q.transpose()).eval();
  if (project) {
    // Most elements are near rest, where the tangent is positive definite: a Cholesky factor
    // says so for a fraction of an eigendecomposition's cost.
    Eigen::LLT<Eigen::Matrix<double, 9, 9>> llt(q);
    if (llt.info() != Eigen::Success) {
      Eigen::SelfAdjointEigenSolver<Eigen::Matrix<double, 9, 9>> eig(q);
      Eigen::Matrix<double, 9, 1> d = eig.eigenvalues().cwiseMax(0.0);
      q = eig.eigenvectors() * d.asDiagonal() * eig.eigenvectors().transpose();
    }
  }
  for (int r = 0; r < 9; ++r)
    for (int c = 0; c < 9; ++c) out[r][c] = q(r, c);
}

// Adds an element's 16 blocks V sum_{c, d} grad_a[c] q(3 r + c, 3 s + d) grad_b[d] (rows r,
// columns s) to the blocks at values[slots[4 a + b]]. dF = sum_a v_a grad_a^T: F's entry (r, c)
// moves by grad_a[c] per unit of u_a[r]. qg(3 r + c, 3 s + b') = sum_d q(3 r + c, 3 s + d)
// grad_b'[d] first, then grad_a.
inline void add_element_blocks(const double (&q)[9][9], const Vec3d (&grad)[4], double volume,
                               const int64_t* slots, Mat3d* values) {
  double qg[9][12];
  for (int row = 0; row < 9; ++row)
    for (int col = 0; col < 3; ++col)
      for (int b = 0; b < 4; ++b) {
        double sum = 0;
        for (int d = 0; d < 3; ++d) sum += q[row][3 * col + d] * grad[b][d];
        qg[row][3 * b + col] = sum;
      }
  for (int a = 0; a < 4; ++a)
    for (int b = 0; b < 4; ++b) {
      Mat3d& block = values[slots[4 * a + b]];
      for (int r = 0; r < 3; ++r)
        for (int c2 = 0; c2 < 3; ++c2) {
          double sum = 0;
          for (int c = 0; c < 3; ++c) sum += grad[a][c] * qg[3 * r + c][3 * b + c2];
          block.m[r][c2] += volume * sum;
        }
    }
}

}  // namespace

void ElasticEnergy::index_blocks(const BlockSparseMatrix& h) {
  const Model& m = *model_;
  if (indexed_cols_ == h.cols().data() && indexed_blocks_ == h.block_count() &&
      !element_slot_.empty())
    return;
  element_slot_.resize(16 * m.tet_count());
  for (size_t t = 0; t < m.tet_count(); ++t)
    for (int a = 0; a < 4; ++a)
      for (int b = 0; b < 4; ++b)
        element_slot_[16 * t + static_cast<size_t>(4 * a + b)] =
            h.block_index(m.tets[t][a], m.tets[t][b]);
  indexed_cols_ = h.cols().data();
  indexed_blocks_ = h.block_count();
}

void ElasticEnergy::add_hessian(std::span<const Vec3d> u, BlockSparseMatrix& hm, bool project) {
  const Model& m = *model_;
  ZONA_ASSERT(u.size() == m.vertex_count() && hm.rows() == u.size());
  index_blocks(hm);
  std::span<Mat3d> values = hm.values();
  if (m.nodal_pressure) {
    vertex_pressures(u);
    element_dj_.resize(4 * m.tet_count());
  }
  auto element = [&](size_t t) {
    const int64_t* slots = &element_slot_[16 * t];
    // The 16 blocks are scattered over the matrix: fetch them while the tangent is computed.
    for (int k = 0; k < 16; ++k) {
      const char* block = reinterpret_cast<const char*>(&values[static_cast<size_t>(slots[k])]);
      __builtin_prefetch(block, 1);
      __builtin_prefetch(block + sizeof(Mat3d) - 1, 1);
    }
    Vec3d ue[4];
    corners(u, t, ue);
    const TetShape<double>& s = m.tet_shape[t];
    if (m.nodal_pressure) {
      // V_e / 4 dJ_e/du at each corner, for the vertices' rank-one terms below.
      Vec3d dj[4];
      tet_volume_gradient(s, ue, dj);
      for (int c = 0; c < 4; ++c)
        element_dj_[4 * t + static_cast<size_t>(c)] = (0.25 * s.volume) * dj[c];
    }
    double q[9][9];
    stress_tangent(law(t), tet_displacement_gradient(s, ue), project, q);
    add_element_blocks(q, s.grad, s.volume, slots, values.data());
  };
  // No two runs of a colour share a block: each colour's runs go side by side, and every
  // block sums its elements in colour order (the same bits for any thread count).
  coloured_sum([&](size_t t) {
    element(t);
    return 0.0;
  });
  if (!m.nodal_pressure) return;
  // The rank-one terms (lambda_v / V_v) g_v g_v^T, g_v over v's star, as the matrix's rank-one
  // part (hessian_pattern's, in star order).
  ZONA_ASSERT(hm.rank_one_terms() == m.vertex_count() &&
              hm.rank_one_vectors().size() == star_.size());
  std::span<double> coefficient = hm.rank_one_coefficients();
  std::span<Vec3d> vectors = hm.rank_one_vectors();
  // g_v = sum over v's elements of their corners' V_e / 4 dJ_e/du, gathered from the element
  // pass in adjacency order (star_gradient's sums).
  pooled_ranges(m.vertex_count(), 1024, [&](size_t, size_t begin, size_t end) {
    for (size_t v = begin; v < end; ++v) {
      coefficient[v] = m.vertex_lambda[v] * m.vertex_inverse_volume[v];  // this term's alone
      Vec3d* out = vectors.data() + star_offsets_[v];
      std::fill(out, out + (star_offsets_[v + 1] - star_offsets_[v]), Vec3d{0, 0, 0});
      for (int32_t k = m.adjacency.offsets[v]; k < m.adjacency.offsets[v + 1]; ++k) {
        const Vec3d* dj =
            &element_dj_[4 * static_cast<size_t>(m.adjacency.tets[static_cast<size_t>(k)])];
        const uint8_t* slot = &star_slot_[4 * static_cast<size_t>(k)];
        for (int c = 0; c < 4; ++c) out[slot[c]] += dj[c];
      }
    }
  });
}

}  // namespace zona
