// CPU element pass over the thread pool, the gather, stiffness assembly, power iteration.
#include "engine/forces_cpu.h"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <vector>

#include "engine/simd_pack.h"

namespace zona {
namespace {

// One element evaluation per formulation: forces f[4] [N] written, energy [J] returned,
// ElementHealth bits in *bits. Each is a thin wrapper over fem_element.h.

struct SvkGradientClamped {
  static double eval(const Model& m, size_t t, const Vec3d u[4], Vec3d f[4], uint32_t* bits) {
    const TetShape<double>& s = m.tet_shape[t];
    const Lame& l = m.tet_lame(t);
    const Mat3d h = tet_displacement_gradient(s, u);
    const Mat3d e = green_strain(h);
    *bits = tet_health_from_strain(h, e);
    const bool clamp = m.clamp_stretch == kSvkCollapseStretch
                           ? *bits != 0
                           : tet_health_from_strain(h, e, m.clamp_stretch) != 0;
    double psi;
    Mat3d p;
    if (clamp) {
      psi = svk_first_piola_clamped(h, l.lambda, l.mu, m.clamp_stretch, &p);
      *bits |= kElementClamped;
    } else {
      const Mat3d stress = isotropic_stress(e, l.lambda, l.mu, &psi);
      p = stress + h * stress;
    }
    tet_forces_from_stress(s, p, f);
    return s.volume * psi;
  }
};

// Health for the tensor forms: they never form H, so it is formed here for the checks only.
inline uint32_t tensor_form_health(const Model& m, size_t t, const Vec3d u[4]) {
  const Mat3d h = tet_displacement_gradient(m.tet_shape[t], u);
  if (m.constitutive == ConstitutiveModel::kSvk) return tet_health(h);
  return determinant(Mat3d::identity() + h) > 0 ? 0u : uint32_t{kElementInverted};
}

struct SvkTensorStored {
  static double eval(const Model& m, size_t t, const Vec3d u[4], Vec3d f[4], uint32_t* bits) {
    *bits = tensor_form_health(m, t, u);
    return tet_svk_forces_tensor(m.tensors.tet(t), u, f);
  }
};

struct SvkTensorRebuilt {
  static double eval(const Model& m, size_t t, const Vec3d u[4], Vec3d f[4], uint32_t* bits) {
    *bits = tensor_form_health(m, t, u);
    const Lame& l = m.tet_lame(t);
    return tet_svk_forces_rebuilt(m.tet_shape[t], l.lambda, l.mu, u, f);
  }
};

struct LinearTensorStored {
  static double eval(const Model& m, size_t t, const Vec3d u[4], Vec3d f[4], uint32_t* bits) {
    *bits = tensor_form_health(m, t, u);
    return tet_linear_forces_tensor(m.tensors.tet(t), u, f);
  }
};

struct LinearTensorRebuilt {
  static double eval(const Model& m, size_t t, const Vec3d u[4], Vec3d f[4], uint32_t* bits) {
    *bits = tensor_form_health(m, t, u);
    const Lame& l = m.tet_lame(t);
    return tet_linear_forces_rebuilt(m.tet_shape[t], l.lambda, l.mu, u, f);
  }
};

struct PassContext {
  const Model* model;
  State* state;
};

// ---------------------------------------------------------------------------------------------
// Batched gradient-form kernels: four tetrahedra per lane-parallel evaluation of the SAME
// fem_element.h functions, instantiated on a four-wide double pack. Each lane performs exactly
// the scalar operations in the scalar order, so the results are bit-identical to the scalar
// element functions (tests check it); only the instruction count drops (AVX: 4 per op).
// GCC builds an AVX2 clone and a baseline clone and picks one at load time; FMA is left out on
// purpose, because contracting a*b+c would change the bits between the clones.

// Lane l of the pack built from four scalars picked by `get(tet)`.
template <class Get>
[[gnu::always_inline]] inline P4 gather4(const size_t t[4], Get get) {
  return P4(get(t[0]), get(t[1]), get(t[2]), get(t[3]));
}

// The element pass over chunks with the batched SVK or linear kernel.
template <bool kSvk>
ZONA_SIMD_CLONES void tet_pass_chunks_batched(void* context, int64_t chunk_begin,
                                              int64_t chunk_end) {
  const Model& m = *static_cast<PassContext*>(context)->model;
  State& s = *static_cast<PassContext*>(context)->state;
  const int64_t nt = static_cast<int64_t>(m.tet_count());
  const Vec3d* ug = s.u.data();
  Vec3d* out = s.tet_force.data();
  const Tet* tets = m.tets.data();
  for (int64_t chunk = chunk_begin; chunk < chunk_end; ++chunk) {
    TetChunkResult r;
    const int64_t begin = chunk * kTetChunk;
    const int64_t end = std::min(nt, begin + kTetChunk);
    for (int64_t t0 = begin; t0 < end; t0 += 4) {
      // Lanes past the end repeat the last tetrahedron; their results are dropped.
      const int lanes = static_cast<int>(std::min<int64_t>(4, end - t0));
      size_t t[4];
      for (int l = 0; l < 4; ++l) t[l] = static_cast<size_t>(t0 + std::min(l, lanes - 1));
      // Shape and material: 15 four-lane loads from the model's batch layout.
      const double* batch = m.cpu_tet_batches.data() + (t0 / 4) * kCpuTetBatchStride;
      auto load = [batch](int k) {
        P4 lanes4;
        std::memcpy(&lanes4.v, batch + 4 * k, sizeof lanes4.v);
        return lanes4;
      };
      TetShape<P4> shape;
      for (int j = 0; j < 4; ++j)
        for (int i = 0; i < 3; ++i) shape.grad[j][i] = load(3 * j + i);
      shape.volume = load(12);
      const P4 lambda = load(13);
      const P4 mu = load(14);
      // Edge displacements formed in double per lane, exactly as tet_displacement_gradient.
      Vec3<P4> du[3];
      for (int e = 0; e < 3; ++e)
        for (int i = 0; i < 3; ++i)
          du[e][i] = gather4(t, [&](size_t q) {
            return ug[tets[q][e + 1]][i] - ug[tets[q][0]][i];
          });
      const Mat3<P4> h = tet_displacement_gradient_from_edges(shape, du);
      P4 psi;
      Mat3<P4> p;
      P4 det_f, m1, m2, det_a;
      if constexpr (kSvk) {
        const Mat3<P4> e = green_strain(h);
        // Health, as tet_health_from_strain computes it.
        Mat3<P4> f = h;
        for (int i = 0; i < 3; ++i) f.m[i][i] += P4(1.0);
        det_f = determinant(f);
        Mat3<P4> a = P4(2.0) * e;
        const P4 shift = P4(1.0) - P4(kSvkCollapseStretch) * P4(kSvkCollapseStretch);
        for (int i = 0; i < 3; ++i) a.m[i][i] += shift;
        m1 = a.m[0][0];
        m2 = a.m[0][0] * a.m[1][1] - a.m[0][1] * a.m[1][0];
        det_a = determinant(a);
        const Mat3<P4> stress = isotropic_stress(e, lambda, mu, &psi);
        p = stress + h * stress;
      } else {
        det_f = determinant(Mat3<P4>::identity() + h);
        p = isotropic_stress(small_strain(h), lambda, mu, &psi);
      }
      Vec3<P4> f[4];
      tet_forces_from_stress(shape, p, f);
      const P4 w = shape.volume * psi;
      for (int l = 0; l < lanes; ++l) {
        const size_t tl = t[l];
        for (int c = 0; c < 4; ++c) out[4 * tl + c] = Vec3d{f[c].x.v[l], f[c].y.v[l], f[c].z.v[l]};
        r.elastic_energy += w.v[l];
        uint32_t bits = det_f.v[l] > 0 ? 0u : uint32_t{kElementInverted};
        if (kSvk && !(m1.v[l] > 0 && m2.v[l] > 0 && det_a.v[l] > 0)) bits |= kElementCollapsing;
        if (bits) {
          r.health |= bits;
          if ((bits & kElementInverted) && r.inverted_count++ == 0)
            r.first_inverted = static_cast<int64_t>(tl);
          if ((bits & kElementCollapsing) && r.collapsing_count++ == 0)
            r.first_collapsing = static_cast<int64_t>(tl);
        }
      }
    }
    s.tet_chunks[static_cast<size_t>(chunk)] = r;
  }
}

// The element pass over chunks [chunk_begin, chunk_end) for one element kind.
template <class Kernel>
void tet_pass_chunks(void* context, int64_t chunk_begin, int64_t chunk_end) {
  const Model& m = *static_cast<PassContext*>(context)->model;
  State& s = *static_cast<PassContext*>(context)->state;
  const int64_t nt = static_cast<int64_t>(m.tet_count());
  const Vec3d* ug = s.u.data();
  Vec3d* out = s.tet_force.data();
  for (int64_t chunk = chunk_begin; chunk < chunk_end; ++chunk) {
    TetChunkResult r;
    const int64_t end = std::min(nt, (chunk + 1) * kTetChunk);
    for (int64_t ti = chunk * kTetChunk; ti < end; ++ti) {
      const size_t t = static_cast<size_t>(ti);
      const Tet& e = m.tets[t];
      const Vec3d u[4] = {ug[e[0]], ug[e[1]], ug[e[2]], ug[e[3]]};
      uint32_t bits = 0;
      Vec3d f[4];
      r.elastic_energy += Kernel::eval(m, t, u, f, &bits);
      for (int c = 0; c < 4; ++c) out[4 * t + c] = f[c];
      if (bits) {
        // Rare path: counts and the first offender for the message.
        r.health |= bits;
        if (bits & kElementInverted) {
          if (r.inverted_count++ == 0) r.first_inverted = ti;
        }
        if (bits & kElementCollapsing) {
          if (r.collapsing_count++ == 0) r.first_collapsing = ti;
        }
        if (bits & kElementClamped) ++r.clamped_count;
      }
    }
    s.tet_chunks[static_cast<size_t>(chunk)] = r;
  }
}

ThreadPool::ChunkFn select_tet_pass(const Model& m) {
  const bool svk = m.constitutive == ConstitutiveModel::kSvk;
  switch (m.formulation) {
    case Formulation::kGradient:
      if (!svk) return &tet_pass_chunks_batched<false>;
      return m.inversion == InversionHandling::kClampStretch
                 ? &tet_pass_chunks<SvkGradientClamped>
                 : &tet_pass_chunks_batched<true>;
    case Formulation::kTensorStored:
      return svk ? &tet_pass_chunks<SvkTensorStored> : &tet_pass_chunks<LinearTensorStored>;
    case Formulation::kTensorRebuilt:
      return svk ? &tet_pass_chunks<SvkTensorRebuilt> : &tet_pass_chunks<LinearTensorRebuilt>;
  }
  return &tet_pass_chunks_batched<true>;
}

void gather_chunks(void* context, int64_t chunk_begin, int64_t chunk_end) {
  const Model& m = *static_cast<PassContext*>(context)->model;
  State& s = *static_cast<PassContext*>(context)->state;
  const int64_t nv = static_cast<int64_t>(m.vertex_count());
  const int64_t end = std::min(nv, chunk_end * kVertexChunk);
  for (int64_t v = chunk_begin * kVertexChunk; v < end; ++v)
    s.force[static_cast<size_t>(v)] = gather_vertex_force(m, s, static_cast<size_t>(v));
}

}  // namespace

void compute_tet_forces(const Model& model, State& state) {
  PassContext context{&model, &state};
  state.pool->run(static_cast<int64_t>(state.tet_chunks.size()), select_tet_pass(model), &context);
}

void reduce_tet_chunks(const State& state, StepDiagnostics& diag) {
  diag.elastic_energy = 0;
  diag.element_health = 0;
  diag.inverted_count = diag.collapsing_count = diag.clamped_count = 0;
  diag.first_inverted = diag.first_collapsing = -1;
  // Chunk order: the same sum for every thread count.
  for (const TetChunkResult& r : state.tet_chunks) {
    diag.elastic_energy += r.elastic_energy;
    diag.element_health |= r.health;
    diag.inverted_count += r.inverted_count;
    diag.collapsing_count += r.collapsing_count;
    diag.clamped_count += r.clamped_count;
    if (diag.first_inverted < 0) diag.first_inverted = r.first_inverted;
    if (diag.first_collapsing < 0) diag.first_collapsing = r.first_collapsing;
  }
}

void compute_elastic_forces(const Model& model, State& state) {
  compute_tet_forces(model, state);
  PassContext context{&model, &state};
  state.pool->run(static_cast<int64_t>(state.vertex_chunks.size()), &gather_chunks, &context);
  reduce_tet_chunks(state, state.diag);
}

Eigen::SparseMatrix<double> assemble_stiffness(const Model& model, std::span<const Vec3d> u) {
  ZONA_ASSERT(u.size() == model.vertex_count());
  const size_t nt = model.tet_count();
  std::vector<Eigen::Triplet<double>> triplets;
  triplets.reserve(nt * 144);
  double k[144];
  for (size_t t = 0; t < nt; ++t) {
    const Tet& e = model.tets[t];
    const Lame& l = model.tet_lame(t);
    if (model.constitutive == ConstitutiveModel::kSvk) {
      const Vec3d ue[4] = {u[e[0]], u[e[1]], u[e[2]], u[e[3]]};
      tet_svk_stiffness(model.tet_shape[t], l.lambda, l.mu, ue, k);
    } else {
      tet_linear_stiffness(model.tet_shape[t], l.lambda, l.mu, k);
    }
    for (int a = 0; a < 4; ++a)
      for (int i = 0; i < 3; ++i)
        for (int b = 0; b < 4; ++b)
          for (int j = 0; j < 3; ++j)
            triplets.emplace_back(3 * e[a] + i, 3 * e[b] + j, k[(3 * a + i) * 12 + 3 * b + j]);
  }
  const Eigen::Index n = static_cast<Eigen::Index>(3 * model.vertex_count());
  Eigen::SparseMatrix<double> matrix(n, n);
  matrix.setFromTriplets(triplets.begin(), triplets.end());
  return matrix;
}

double estimate_max_frequency(const Model& model, int iterations) {
  const size_t nv = model.vertex_count();
  std::vector<Vec3d> x(nv), z(nv), y(nv);
  std::vector<double> inv_sqrt_mass(nv, 0.0);
  for (size_t v = 0; v < nv; ++v)
    if (!model.vertex_fixed[v] && model.vertex_mass[v] > 0)
      inv_sqrt_mass[v] = 1.0 / std::sqrt(model.vertex_mass[v]);
  // A fixed pseudo-random start vector (the iteration must see every mode).
  uint64_t seed = 0x9E3779B97F4A7C15ull;
  auto next = [&seed] {
    seed = seed * 6364136223846793005ull + 1442695040888963407ull;
    return static_cast<double>(seed >> 11) / 9007199254740992.0 - 0.5;
  };
  for (size_t v = 0; v < nv; ++v) {
    const double w = inv_sqrt_mass[v] > 0 ? 1.0 : 0.0;
    x[v] = Vec3d{w * next(), w * next(), w * next()};
  }
  double lambda_max = 0;
  for (int it = 0; it < iterations; ++it) {
    // y = M^-1/2 K M^-1/2 x, with K x from the linear element forces (f = -K x).
    for (size_t v = 0; v < nv; ++v) z[v] = inv_sqrt_mass[v] * x[v];
    std::fill(y.begin(), y.end(), Vec3d{0, 0, 0});
    for (size_t t = 0; t < model.tet_count(); ++t) {
      const Tet& e = model.tets[t];
      const Lame& l = model.tet_lame(t);
      const Vec3d ze[4] = {z[e[0]], z[e[1]], z[e[2]], z[e[3]]};
      Vec3d f[4];
      tet_linear_forces(model.tet_shape[t], l.lambda, l.mu, ze, f);
      for (int c = 0; c < 4; ++c) y[e[c]] -= f[c];
    }
    double xy = 0, xx = 0, yy = 0;
    for (size_t v = 0; v < nv; ++v) {
      y[v] = inv_sqrt_mass[v] * y[v];
      xy += dot(x[v], y[v]);
      xx += dot(x[v], x[v]);
      yy += dot(y[v], y[v]);
    }
    if (!(xx > 0) || !(yy > 0)) return 0;
    lambda_max = std::max(lambda_max, xy / xx);
    const double inv = 1.0 / std::sqrt(yy);
    for (size_t v = 0; v < nv; ++v) x[v] = inv * y[v];
  }
  return std::sqrt(lambda_max);
}

}  // namespace zona
