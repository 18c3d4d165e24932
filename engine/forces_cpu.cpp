// CPU element pass over the thread pool, the gather, stiffness assembly, power iteration.
#include "engine/forces_cpu.h"

#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstdlib>
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

// Element math of one batch, as the scalar functions compose it (SvkGradient... above, and
// kernels/element_eval.h): corner forces f, energy w [J], and the health quantities det F and,
// for SVK, the three leading minors of C - s^2 I (tet_health_from_strain).
template <bool kSvk, class P>
[[gnu::always_inline]] inline void batch_element_math(const TetShape<P>& shape, P lambda, P mu,
                                                      const Vec3<P> du[3], Vec3<P> f[4], P* w,
                                                      P* det_f, P* m1, P* m2, P* det_a) {
  const Mat3<P> h = tet_displacement_gradient_from_edges(shape, du);
  P psi;
  Mat3<P> p;
  if constexpr (kSvk) {
    const Mat3<P> e = green_strain(h);
    Mat3<P> fm = h;
    for (int i = 0; i < 3; ++i) fm.m[i][i] += P(1);
    *det_f = determinant(fm);
    Mat3<P> a = P(2) * e;
    const P shift = P(1) - P(kSvkCollapseStretch) * P(kSvkCollapseStretch);
    for (int i = 0; i < 3; ++i) a.m[i][i] += shift;
    *m1 = a.m[0][0];
    *m2 = a.m[0][0] * a.m[1][1] - a.m[0][1] * a.m[1][0];
    *det_a = determinant(a);
    const Mat3<P> stress = isotropic_stress(e, lambda, mu, &psi);
    p = stress + h * stress;
  } else {
    (void)m1, (void)m2, (void)det_a;
    *det_f = determinant(Mat3<P>::identity() + h);
    p = isotropic_stress(small_strain(h), lambda, mu, &psi);
  }
  tet_forces_from_stress(shape, p, f);
  *w = shape.volume * psi;
}

// x/y/z packs of corner c of tetrahedra tb[0..3] (16-byte loads and unpacks, no per-lane scalar
// gathers), then the edge differences u_{e+1} - u_0 lane by lane in double, as
// tet_displacement_gradient forms them.
[[gnu::always_inline]] inline void batch_edges(const Vec3d* ug, const Tet* tb, Vec3<P4> du[3]) {
  Vec3<P4> uc[4];
  for (int c = 0; c < 4; ++c)
    load_xyz_transposed(ug[tb[0][c]], ug[tb[1][c]], ug[tb[2][c]], ug[tb[3][c]], uc[c].x, uc[c].y,
                        uc[c].z);
  for (int e = 0; e < 3; ++e) du[e] = uc[e + 1] - uc[0];
}

// Stores the corner forces of four consecutive tetrahedra starting at `dst` (48 doubles,
// lane-major: tetrahedron, corner, xyz): three 4 x 4 transposes of the 12 component packs give
// them as 12 four-double stores.
[[gnu::always_inline]] inline void store_corner_forces4(const Vec3<P4> f[4], double* dst) {
  P4 col[12];
  for (int c = 0; c < 4; ++c) {
    col[3 * c] = f[c].x;
    col[3 * c + 1] = f[c].y;
    col[3 * c + 2] = f[c].z;
  }
  for (int b = 0; b < 3; ++b) {
    transpose4(col + 4 * b);
    for (int l = 0; l < 4; ++l) store4(col[4 * b + l], dst + 12 * l + 4 * b);
  }
}

// Health of the lanes [0, lanes) when some lane failed the packed check (rare path): the bits
// of tet_health_from_strain per lane, counts and the first offenders.
template <bool kSvk, class P>
void batch_health_slow(const P& det_f, const P& m1, const P& m2, const P& det_a, int64_t t0,
                       int lanes, TetChunkResult& r) {
  for (int l = 0; l < lanes; ++l) {
    uint32_t bits = det_f.v[l] > 0 ? 0u : uint32_t{kElementInverted};
    if (kSvk && !(m1.v[l] > 0 && m2.v[l] > 0 && det_a.v[l] > 0)) bits |= kElementCollapsing;
    if (bits) {
      r.health |= bits;
      if ((bits & kElementInverted) && r.inverted_count++ == 0)
        r.first_inverted = t0 + l;
      if ((bits & kElementCollapsing) && r.collapsing_count++ == 0)
        r.first_collapsing = t0 + l;
    }
  }
}

// The element pass over chunks with the batched SVK or linear kernel, float64 element math.
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
    double energy = 0;  // r.elastic_energy, in a register
    const int64_t begin = chunk * kTetChunk;
    const int64_t end = std::min(nt, begin + kTetChunk);
    for (int64_t t0 = begin; t0 < end; t0 += 4) {
      // Lanes past the end repeat the last tetrahedron; their results are dropped.
      const int lanes = static_cast<int>(std::min<int64_t>(4, end - t0));
      const Tet* tb = tets + t0;
      Tet tail[4];
      if (lanes < 4) {
        for (int l = 0; l < 4; ++l) tail[l] = tets[t0 + std::min(l, lanes - 1)];
        tb = tail;
      }
      // Shape and material: 15 four-lane loads from the model's batch layout.
      const double* batch = m.cpu_tet_batches.data() + (t0 / 4) * kCpuTetBatchStride;
      TetShape<P4> shape;
      for (int j = 0; j < 4; ++j)
        for (int i = 0; i < 3; ++i) shape.grad[j][i] = load4(batch + 4 * (3 * j + i));
      shape.volume = load4(batch + 4 * 12);
      const P4 lambda = load4(batch + 4 * 13);
      const P4 mu = load4(batch + 4 * 14);
      Vec3<P4> du[3];
      batch_edges(ug, tb, du);
      Vec3<P4> f[4];
      P4 w, det_f, m1(0.0), m2(0.0), det_a(0.0);
      batch_element_math<kSvk>(shape, lambda, mu, du, f, &w, &det_f, &m1, &m2, &det_a);
      if (lanes == 4) {
        store_corner_forces4(f, &out[4 * t0].x);
        for (int l = 0; l < 4; ++l) energy += w.v[l];
      } else {
        for (int l = 0; l < lanes; ++l) {
          for (int c = 0; c < 4; ++c)
            out[4 * (t0 + l) + c] = Vec3d{f[c].x.v[l], f[c].y.v[l], f[c].z.v[l]};
          energy += w.v[l];
        }
      }
      // Health by lane masks (repeated lanes past the end copy a valid lane).
      M4 ok = det_f.v > 0.0;
      if constexpr (kSvk) ok &= (m1.v > 0.0) & (m2.v > 0.0) & (det_a.v > 0.0);
      if (!all_lanes(ok)) batch_health_slow<kSvk>(det_f, m1, m2, det_a, t0, lanes, r);
    }
    r.elastic_energy = energy;
    s.tet_chunks[static_cast<size_t>(chunk)] = r;
  }
}

#if defined(__GNUC__) && !defined(__clang__) && defined(__x86_64__) && \
    !defined(__SANITIZE_THREAD__)
#define ZONA_HAVE_AVX512_PASS 1
// The float64 pass with eight tetrahedra per AVX-512 pack, chosen at run time on CPUs that have
// AVX-512F (cpu_simd_bits() == 512): the same lane operations, so the same bits as the four-lane
// pass and the scalar functions. Shapes come from two four-lane batches.
template <bool kSvk>
// AVX-512F brings FMA for 512-bit vectors: contraction is switched off here, or a * b + c would
// round once instead of twice and the bits would differ from the other passes.
__attribute__((target("avx512f"), optimize("fp-contract=off"), flatten)) void
tet_pass_chunks_batched8(void* context, int64_t chunk_begin, int64_t chunk_end) {
  const Model& m = *static_cast<PassContext*>(context)->model;
  State& s = *static_cast<PassContext*>(context)->state;
  const int64_t nt = static_cast<int64_t>(m.tet_count());
  const int64_t batches4 = static_cast<int64_t>(m.cpu_tet_batches.size()) / kCpuTetBatchStride;
  const Vec3d* ug = s.u.data();
  Vec3d* out = s.tet_force.data();
  const Tet* tets = m.tets.data();
  for (int64_t chunk = chunk_begin; chunk < chunk_end; ++chunk) {
    TetChunkResult r;
    double energy = 0;
    const int64_t begin = chunk * kTetChunk;
    const int64_t end = std::min(nt, begin + kTetChunk);
    for (int64_t t0 = begin; t0 < end; t0 += 8) {
      const int lanes = static_cast<int>(std::min<int64_t>(8, end - t0));
      const Tet* tb = tets + t0;
      Tet tail[8];
      if (lanes < 8) {
        for (int l = 0; l < 8; ++l) tail[l] = tets[t0 + std::min(l, lanes - 1)];
        tb = tail;
      }
      // The high half's batch may not exist at the very end: its lanes are dropped then.
      const double* lo = m.cpu_tet_batches.data() + (t0 / 4) * kCpuTetBatchStride;
      const double* hi = t0 / 4 + 1 < batches4 ? lo + kCpuTetBatchStride : lo;
      auto load = [lo, hi](int k) { return concat(load4(lo + 4 * k), load4(hi + 4 * k)); };
      TetShape<P8d> shape;
      for (int j = 0; j < 4; ++j)
        for (int i = 0; i < 3; ++i) shape.grad[j][i] = load(3 * j + i);
      shape.volume = load(12);
      const P8d lambda = load(13);
      const P8d mu = load(14);
      Vec3<P4> dlo[3], dhi[3];
      batch_edges(ug, tb, dlo);
      batch_edges(ug, tb + 4, dhi);
      Vec3<P8d> du[3];
      for (int e = 0; e < 3; ++e)
        du[e] = Vec3<P8d>{concat(dlo[e].x, dhi[e].x), concat(dlo[e].y, dhi[e].y),
                          concat(dlo[e].z, dhi[e].z)};
      Vec3<P8d> f[4];
      P8d w, det_f, m1(0.0), m2(0.0), det_a(0.0);
      batch_element_math<kSvk>(shape, lambda, mu, du, f, &w, &det_f, &m1, &m2, &det_a);
      if (lanes == 8) {
        for (int half = 0; half < 2; ++half) {
          Vec3<P4> fd[4];
          for (int c = 0; c < 4; ++c)
            fd[c] = Vec3<P4>{half_of(f[c].x, half), half_of(f[c].y, half), half_of(f[c].z, half)};
          store_corner_forces4(fd, &out[4 * (t0 + 4 * half)].x);
        }
        for (int l = 0; l < 8; ++l) energy += w.v[l];
      } else {
        for (int l = 0; l < lanes; ++l) {
          for (int c = 0; c < 4; ++c)
            out[4 * (t0 + l) + c] = Vec3d{f[c].x.v[l], f[c].y.v[l], f[c].z.v[l]};
          energy += w.v[l];
        }
      }
      M8d ok = det_f.v > 0.0;
      if constexpr (kSvk) ok &= (m1.v > 0.0) & (m2.v > 0.0) & (det_a.v > 0.0);
      if (!all_lanes(ok)) batch_health_slow<kSvk>(det_f, m1, m2, det_a, t0, lanes, r);
    }
    r.elastic_energy = energy;
    s.tet_chunks[static_cast<size_t>(chunk)] = r;
  }
}
#endif

// The same with float32 element math (ElementPrecision::kFloat32), eight tetrahedra per pack:
// edge differences formed in float64 and rounded, shapes and Lame coefficients rounded at build,
// corner forces widened back to float64 (the CUDA kernels' mixed precision). Lane by lane the
// fem_element.h functions at T = float, so bit-identical to them.
template <bool kSvk>
ZONA_SIMD_CLONES void tet_pass_chunks_batched_f32(void* context, int64_t chunk_begin,
                                                  int64_t chunk_end) {
  const Model& m = *static_cast<PassContext*>(context)->model;
  State& s = *static_cast<PassContext*>(context)->state;
  const int64_t nt = static_cast<int64_t>(m.tet_count());
  const Vec3d* ug = s.u.data();
  Vec3d* out = s.tet_force.data();
  const Tet* tets = m.tets.data();
  for (int64_t chunk = chunk_begin; chunk < chunk_end; ++chunk) {
    TetChunkResult r;
    double energy = 0;
    const int64_t begin = chunk * kTetChunk;
    const int64_t end = std::min(nt, begin + kTetChunk);
    for (int64_t t0 = begin; t0 < end; t0 += 8) {
      const int lanes = static_cast<int>(std::min<int64_t>(8, end - t0));
      const Tet* tb = tets + t0;
      Tet tail[8];
      if (lanes < 8) {
        for (int l = 0; l < 8; ++l) tail[l] = tets[t0 + std::min(l, lanes - 1)];
        tb = tail;
      }
      const float* batch = m.cpu_tet_batches_f32.data() + (t0 / 8) * kCpuTetBatchStrideF32;
      TetShape<P8f> shape;
      for (int j = 0; j < 4; ++j)
        for (int i = 0; i < 3; ++i) shape.grad[j][i] = load8f(batch + 8 * (3 * j + i));
      shape.volume = load8f(batch + 8 * 12);
      const P8f lambda = load8f(batch + 8 * 13);
      const P8f mu = load8f(batch + 8 * 14);
      Vec3<P4> lo[3], hi[3];
      batch_edges(ug, tb, lo);
      batch_edges(ug, tb + 4, hi);
      Vec3<P8f> du[3];
      for (int e = 0; e < 3; ++e)
        du[e] = Vec3<P8f>{narrow(lo[e].x, hi[e].x), narrow(lo[e].y, hi[e].y),
                          narrow(lo[e].z, hi[e].z)};
      Vec3<P8f> f[4];
      P8f w, det_f, m1(0.0f), m2(0.0f), det_a(0.0f);
      batch_element_math<kSvk>(shape, lambda, mu, du, f, &w, &det_f, &m1, &m2, &det_a);
      if (lanes == 8) {
        for (int half = 0; half < 2; ++half) {
          Vec3<P4> fd[4];
          for (int c = 0; c < 4; ++c)
            fd[c] = Vec3<P4>{widen(f[c].x, half), widen(f[c].y, half), widen(f[c].z, half)};
          store_corner_forces4(fd, &out[4 * (t0 + 4 * half)].x);
        }
        for (int l = 0; l < 8; ++l) energy += static_cast<double>(w.v[l]);
      } else {
        for (int l = 0; l < lanes; ++l) {
          for (int c = 0; c < 4; ++c)
            out[4 * (t0 + l) + c] = Vec3d{f[c].x.v[l], f[c].y.v[l], f[c].z.v[l]};
          energy += static_cast<double>(w.v[l]);
        }
      }
      M8 ok = det_f.v > 0.0f;
      if constexpr (kSvk) ok &= (m1.v > 0.0f) & (m2.v > 0.0f) & (det_a.v > 0.0f);
      if (!all_lanes(ok)) batch_health_slow<kSvk>(det_f, m1, m2, det_a, t0, lanes, r);
    }
    r.elastic_energy = energy;
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
      if (m.element_precision == ElementPrecision::kFloat32)  // build_model: no clamp then
        return svk ? &tet_pass_chunks_batched_f32<true> : &tet_pass_chunks_batched_f32<false>;
#ifdef ZONA_HAVE_AVX512_PASS
      if (m.inversion != InversionHandling::kClampStretch && cpu_simd_bits() >= 512)
        return svk ? &tet_pass_chunks_batched8<true> : &tet_pass_chunks_batched8<false>;
#endif
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

namespace {

// 512 when the CPU has AVX-512F and ZONA_CPU_SIMD_BITS does not say 256; read once.
int detect_simd_bits() {
#ifdef ZONA_HAVE_AVX512_PASS
  if (const char* env = std::getenv("ZONA_CPU_SIMD_BITS"); env && std::atoi(env) == 256)
    return 256;
  __builtin_cpu_init();
  return __builtin_cpu_supports("avx512f") ? 512 : 256;
#else
  return 256;
#endif
}

std::atomic<int>& simd_bits_setting() {
  static std::atomic<int> bits{detect_simd_bits()};
  return bits;
}

}  // namespace

int cpu_simd_bits() { return simd_bits_setting().load(std::memory_order_relaxed); }

void set_cpu_simd_bits(int bits) {
  simd_bits_setting().store(bits >= 512 ? detect_simd_bits() : 256, std::memory_order_relaxed);
}

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
