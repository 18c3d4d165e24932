// CPU element pass over the thread pool, the gather, stiffness assembly, power iteration.
// (Over 800 lines: the batched SIMD passes for each law, precision and health filter are
// template instances of one loop; the next split would be the scalar reference passes.)
#include "engine/fem/forces_cpu.h"

#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <type_traits>
#include <vector>

#include "engine/core/simd_pack.h"
#include "engine/fem/element_eval.h"

#if defined(__x86_64__)
#include <immintrin.h>
#endif

namespace zona {
namespace {

// One element evaluation per formulation that the batched passes below do not cover (the tensor
// forms): eval_element (engine/fem/element_eval.h), the function
// the CUDA kernels call, here in float64: forces f[4] [N] written, energy [J] returned,
// ElementHealth bits in *bits.
template <ElementKind K>
struct ElementOf {
  static double eval(const Model& m, size_t t, const Vec3d u[4], Vec3d f[4], uint32_t* bits) {
    const Lame& l = m.tet_lame(t);
    const double* tensors = nullptr;
    if constexpr (element_kind_stored(K)) tensors = m.tensors.tet(t);
    return eval_element<K, double>(m.tet_shape[t], l.lambda, l.mu, tensors, 0.0, true, u, f,
                                   bits);
  }
};
using SvkTensorStored = ElementOf<ElementKind::kSvkStored>;
using SvkTensorRebuilt = ElementOf<ElementKind::kSvkRebuilt>;
using LinearTensorStored = ElementOf<ElementKind::kLinearStored>;
using LinearTensorRebuilt = ElementOf<ElementKind::kLinearRebuilt>;

struct PassContext {
  const Model* model;
  State* state;
};

// ---------------------------------------------------------------------------------------------
// Batched gradient-form kernels: four or eight tetrahedra per lane-parallel evaluation of the
// SAME fem_element.h functions, instantiated on a pack type (simd_pack.h). Each lane performs
// exactly the scalar operations in the scalar order, so the results are bit-identical to the
// scalar element functions (tests check it); only the instruction count drops.

// Element math of one batch, as eval_element composes it (engine/fem/element_eval.h):
// corner forces f and energy w [J]. Returns |H|^2 (Frobenius) per lane, the health check's
// filter (batch_pass), and hands it to `filter` as soon as it is formed: the clamped passes
// test it there, while few packs are live, rather than beside the forces' 12 packs.
template <bool kSvk, class P, class Filter>
[[gnu::always_inline]] inline P batch_element_math(const TetShape<P>& shape, P lambda, P mu,
                                                   const Vec3<P> du[3], Vec3<P> f[4], P* w,
                                                   Filter&& filter) {
  const Mat3<P> h = tet_displacement_gradient_from_edges(shape, du);
  P h_sq = h.m[0][0] * h.m[0][0];
  for (int k = 1; k < 9; ++k) h_sq += h.m[k / 3][k % 3] * h.m[k / 3][k % 3];
  filter(h_sq);
  P psi;
  Mat3<P> p;
  if constexpr (kSvk) {
    const Mat3<P> stress = isotropic_stress(green_strain(h), lambda, mu, &psi);
    p = stress + h * stress;
  } else {
    p = isotropic_stress(small_strain(h), lambda, mu, &psi);
  }
  tet_forces_from_stress(shape, p, f);
  *w = shape.volume * psi;
  return h_sq;
}

// The same element math with fused multiply-adds (P4 or P8d only; inside the FMA passes): ~145
// packed operations per batch instead of ~300. *w is -4 times the elements' energy (batch_pass
// multiplies the chunk's sum by -1/4, exactly). Not bit-identical to fem_element.h (each fused
// a * b + c rounds once, and the algebra is rearranged to save operations), but the same
// operations in the same order for four and eight lanes, so the AVX2 and AVX-512 FMA passes
// agree bit for bit, and with any thread count. The rearrangement, with E2 = 2 E = H + H^T +
// H^T H (SVK; H + H^T for the linear model):
//   -V S = k_mu E2 + k_lam tr(E2) I,  k_mu = -V mu, k_lam = -V lambda / 2;
//   V psi = V (mu E:E + lambda/2 tr(E)^2) = -(k_mu E2:E2 + k_lam tr(E2)^2) / 4 = -(Q : E2) / 4;
// P' = -V P = Q + H Q with Q = -V S, and f_j = P' g_j. For SVK the health filter |H|^2 comes
// from the trace already formed: tr(E2) = 2 tr(H) + |H|^2 (its rounding, a few ulp of |H|^2 +
// 4 |tr H|, is far inside the margins of kHealthCheckSkipBelowGradientSq; a NaN or an
// infinity in H still gives a NaN, which the filter does not pass). E2 and Q are symmetric.
template <bool kSvk, class P, class Filter>
[[gnu::always_inline]] inline P batch_element_math_fma(const TetShape<P>& shape, P lambda, P mu,
                                                       const Vec3<P> du[3], Vec3<P> f[4], P* w,
                                                       Filter&& filter) {
  const Vec3<P>* g = shape.grad;
  P h[3][3];
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c)
      h[r][c] = fmadd(du[2][r], g[3][c], fmadd(du[1][r], g[2][c], du[0][r] * g[1][c]));
  P e[3][3];  // E2
  for (int r = 0; r < 3; ++r)
    for (int c = r; c < 3; ++c) {
      P sum = h[r][c] + h[c][r];
      if constexpr (kSvk)  // H + H^T + H^T H
        sum = fmadd(h[2][r], h[2][c], fmadd(h[1][r], h[1][c], fmadd(h[0][r], h[0][c], sum)));
      e[r][c] = e[c][r] = sum;
    }
  const P tr = e[0][0] + e[1][1] + e[2][2];
  P h_sq;
  if constexpr (kSvk) {
    h_sq = fmadd(P(-2.0), h[0][0] + h[1][1] + h[2][2], tr);
  } else {
    h_sq = h[0][0] * h[0][0];
    for (int k = 1; k < 9; ++k) h_sq = fmadd(h[k / 3][k % 3], h[k / 3][k % 3], h_sq);
  }
  filter(h_sq);
  const P neg_v = -shape.volume;
  const P k_mu = neg_v * mu;
  const P k_lam = (neg_v * lambda) * P(0.5);
  const P lam_tr = k_lam * tr;
  P q[3][3];  // Q = -V S
  for (int r = 0; r < 3; ++r) {
    q[r][r] = fmadd(k_mu, e[r][r], lam_tr);
    for (int c = r + 1; c < 3; ++c) q[r][c] = q[c][r] = k_mu * e[r][c];
  }
  // -4 V psi = Q : E2 (batch_pass scales the chunk's sum by -1/4).
  const P q_diag = fmadd(q[2][2], e[2][2], fmadd(q[1][1], e[1][1], q[0][0] * e[0][0]));
  const P q_off = fmadd(q[1][2], e[1][2], fmadd(q[0][2], e[0][2], q[0][1] * e[0][1]));
  *w = fmadd(P(2.0), q_off, q_diag);
  // P' = -V P: Q + H Q (SVK) or Q (linear).
  P pm[3][3];
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j)
      pm[i][j] = kSvk ? fmadd(h[i][2], q[2][j], fmadd(h[i][1], q[1][j], fmadd(h[i][0], q[0][j],
                                                                               q[i][j])))
                      : q[i][j];
  for (int k = 1; k < 4; ++k)
    for (int i = 0; i < 3; ++i)
      f[k][i] = fmadd(pm[i][2], g[k][2], fmadd(pm[i][1], g[k][1], pm[i][0] * g[k][0]));
  // The element's forces sum to zero exactly, as in tet_forces_from_stress: -(f1 + f2) - f3 is
  // -((f1 + f2) + f3) bit for bit (rounding to nearest is symmetric), one operation less.
  for (int i = 0; i < 3; ++i) f[0][i] = fnmsub(f[1][i] + f[2][i], P(1.0), f[3][i]);
  return h_sq;
}

// The three leading minors of C - s^2 I = 2E + (1 - s^2) I, as tet_health_from_strain forms
// them: all positive iff every principal stretch exceeds s.
template <class P>
[[gnu::always_inline]] inline void batch_stretch_minors(const Mat3<P>& e, P stretch, P* m1, P* m2,
                                                        P* det_a) {
  Mat3<P> a = P(2) * e;
  const P shift = P(1) - stretch * stretch;
  for (int i = 0; i < 3; ++i) a.m[i][i] += shift;
  *m1 = a.m[0][0];
  *m2 = a.m[0][0] * a.m[1][1] - a.m[0][1] * a.m[1][0];
  *det_a = determinant(a);
}

// The quantities tet_health_from_strain tests, in its order: det F and, for SVK, the three
// leading minors of C - s^2 I (s the collapse stretch). Where `clamp_minors` is given (three
// packs), also the minors at `clamp_stretch`, which decide the clamped SVK's clamp when that
// stretch is not the collapse stretch.
template <bool kSvk, class P>
[[gnu::always_inline]] inline void batch_health_values(const TetShape<P>& shape,
                                                       const Vec3<P> du[3], P* det_f, P* m1, P* m2,
                                                       P* det_a, double clamp_stretch = 0,
                                                       P* clamp_minors = nullptr) {
  const Mat3<P> h = tet_displacement_gradient_from_edges(shape, du);
  if constexpr (kSvk) {
    const Mat3<P> e = green_strain(h);
    Mat3<P> fm = h;
    for (int i = 0; i < 3; ++i) fm.m[i][i] += P(1);
    *det_f = determinant(fm);
    batch_stretch_minors(e, P(kSvkCollapseStretch), m1, m2, det_a);
    if (clamp_minors)
      batch_stretch_minors(e, P(clamp_stretch), &clamp_minors[0], &clamp_minors[1],
                           &clamp_minors[2]);
  } else {
    (void)m1, (void)m2, (void)det_a, (void)clamp_stretch, (void)clamp_minors;
    *det_f = determinant(Mat3<P>::identity() + h);
  }
}

// Adds corner force `f` (x, y, z, 0) into its block (AssemblyPlan::corner_code `code`).
[[gnu::always_inline]] inline void scatter_corner(double* blocks, int32_t code, P4 f) {
  store4(load4(blocks + code) + f, blocks + code);
}

// Scatters the corner forces of four consecutive tetrahedra (lanes) to their blocks, lane by lane
// (ascending tetrahedron) and corner by corner; `code` points at lane 0, corner 0 of them in the
// batch layout (corner c of lane l at 8 c + l). One 4 x 4 transpose per corner gives each lane's
// (x, y, z, 0).
[[gnu::always_inline]] inline void scatter_corner_forces4(const Vec3<P4> f[4], double* blocks,
                                                          const int32_t* code) {
  P4 corner[4][4];  // [corner][lane]
  for (int c = 0; c < 4; ++c) {
    corner[c][0] = f[c].x;
    corner[c][1] = f[c].y;
    corner[c][2] = f[c].z;
    corner[c][3] = zero4();
    transpose4(corner[c]);
  }
  for (int l = 0; l < 4; ++l)
    for (int c = 0; c < 4; ++c) scatter_corner(blocks, code[8 * c + l], corner[c][l]);
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

// Lane-wise helpers for the clamped SVK below: a where the mask holds, else b; the square root of
// each lane (correctly rounded, as std::sqrt); whether no lane of a mask holds.
template <class P, class M>
[[gnu::always_inline]] inline P select_lanes(M mask, P a, P b) {
  P r;
  r.v = mask ? a.v : b.v;
  return r;
}
template <class P, class M>
[[gnu::always_inline]] inline Vec3<P> select_lanes(M mask, const Vec3<P>& a, const Vec3<P>& b) {
  return Vec3<P>{select_lanes(mask, a.x, b.x), select_lanes(mask, a.y, b.y),
                 select_lanes(mask, a.z, b.z)};
}
// x86-64: two 128-bit square roots (SSE2), where std::sqrt lane by lane would store every lane and
// test it for errno.
[[gnu::always_inline]] inline P4 sqrt_lanes(P4 a) {
  P4 r;
#if defined(__x86_64__)
  const V2 lo = __builtin_shufflevector(a.v, a.v, 0, 1);
  const V2 hi = __builtin_shufflevector(a.v, a.v, 2, 3);
  r.v = __builtin_shufflevector(V2(_mm_sqrt_pd(lo)), V2(_mm_sqrt_pd(hi)), 0, 1, 2, 3);
#else
  for (int l = 0; l < 4; ++l) r.v[l] = std::sqrt(a.v[l]);
#endif
  return r;
}
[[gnu::always_inline]] inline P8d sqrt_lanes(P8d a) {
  return concat(sqrt_lanes(half_of(a, 0)), sqrt_lanes(half_of(a, 1)));
}
template <class M>
[[gnu::always_inline]] inline bool no_lane(M mask) {
  return all_lanes(mask == 0);
}

// svk_first_piola_clamped (fem_element.h) on every lane of a pack: each lane performs the scalar
// function's operations in its order, and where the scalar function branches on a value the
// pack forms both sides and keeps the lane's (a Jacobi rotation a lane has finished or skips,
// the overflow-safe tangent, the sort, the reflection, the Gram-Schmidt fallback). So each
// lane's P and energy density are the scalar function's bits (forces_simd_test checks it on
// inverted, collapsed, degenerate and random elements). Keep the two in step.
template <class P>
[[gnu::always_inline]] inline P batch_svk_first_piola_clamped(const Mat3<P>& h, P lambda, P mu,
                                                              P stretch_min, Mat3<P>* p) {
  using Mask = decltype(P{}.v > P{}.v);
  Mat3<P> f = h;
  for (int i = 0; i < 3; ++i) f.m[i][i] += P(1);
  // symmetric_eigen3(F^T F): `active` lanes have not left the sweep loop.
  Mat3<P> a = transpose(f) * f;
  Mat3<P> v = Mat3<P>::identity();
  Mask active = P(0.0).v == P(0.0).v;
  for (int sweep = 0; sweep < 8; ++sweep) {
    const P off = a.m[0][1] * a.m[0][1] + a.m[0][2] * a.m[0][2] + a.m[1][2] * a.m[1][2];
    const P diag = a.m[0][0] * a.m[0][0] + a.m[1][1] * a.m[1][1] + a.m[2][2] * a.m[2][2];
    active &= off.v > (P(1e-30) * diag).v;
    if (no_lane(active)) break;
    for (int pq = 0; pq < 3; ++pq) {
      const int pi = pq == 2 ? 1 : 0;
      const int qi = pq == 0 ? 1 : 2;
      const P apq = a.m[pi][qi];
      const Mask rotate = active & (apq.v != 0);
      if (no_lane(rotate)) continue;
      const P theta = (a.m[qi][qi] - a.m[pi][pi]) / (P(2) * apq);
      const P at = select_lanes(theta.v < 0, -theta, theta);
      P t = P(1) / (at + sqrt_lanes(theta * theta + P(1)));
      const Mask large = at.v > 1e15;
      if (!no_lane(large)) t = select_lanes(large, P(0.5) / at, t);
      t = select_lanes(theta.v < 0, -t, t);
      const P c = P(1) / sqrt_lanes(t * t + P(1));
      const P sn = t * c;
      a.m[pi][pi] = select_lanes(rotate, a.m[pi][pi] - t * apq, a.m[pi][pi]);
      a.m[qi][qi] = select_lanes(rotate, a.m[qi][qi] + t * apq, a.m[qi][qi]);
      a.m[pi][qi] = select_lanes(rotate, P(0), a.m[pi][qi]);
      a.m[qi][pi] = select_lanes(rotate, P(0), a.m[qi][pi]);
      const int r = 3 - pi - qi;
      const P arp = a.m[r][pi], arq = a.m[r][qi];
      const P rp = c * arp - sn * arq, rq = sn * arp + c * arq;
      a.m[r][pi] = select_lanes(rotate, rp, a.m[r][pi]);
      a.m[pi][r] = select_lanes(rotate, rp, a.m[pi][r]);
      a.m[r][qi] = select_lanes(rotate, rq, a.m[r][qi]);
      a.m[qi][r] = select_lanes(rotate, rq, a.m[qi][r]);
      for (int i = 0; i < 3; ++i) {
        const P vip = v.m[i][pi], viq = v.m[i][qi];
        v.m[i][pi] = select_lanes(rotate, c * vip - sn * viq, vip);
        v.m[i][qi] = select_lanes(rotate, sn * vip + c * viq, viq);
      }
    }
  }
  // Descending eigenvalues with their vectors: the scalar bubble sort's swaps, lane by lane.
  P ev[3] = {a.m[0][0], a.m[1][1], a.m[2][2]};
  Vec3<P> vc[3];
  for (int i = 0; i < 3; ++i) vc[i] = Vec3<P>{v.m[0][i], v.m[1][i], v.m[2][i]};
  for (int i = 0; i < 2; ++i)
    for (int j = 0; j < 2 - i; ++j) {
      const Mask swap = ev[j].v < ev[j + 1].v;
      const P e0 = ev[j], e1 = ev[j + 1];
      const Vec3<P> c0 = vc[j], c1 = vc[j + 1];
      ev[j] = select_lanes(swap, e1, e0);
      ev[j + 1] = select_lanes(swap, e0, e1);
      vc[j] = select_lanes(swap, c1, c0);
      vc[j + 1] = select_lanes(swap, c0, c1);
    }
  vc[2] = select_lanes(dot(vc[0], cross(vc[1], vc[2])).v < 0, -vc[2], vc[2]);
  Vec3<P> fv[3];
  for (int i = 0; i < 3; ++i) fv[i] = f * vc[i];
  Vec3<P> uc[3];
  const P n0 = sqrt_lanes(dot(fv[0], fv[0]));
  const Mask n0_positive = n0.v > 0;
  uc[0] = select_lanes(n0_positive, fv[0] / n0, Vec3<P>{P(1), P(0), P(0)});
  Vec3<P> w = fv[1] - dot(uc[0], fv[1]) * uc[0];
  P n1 = sqrt_lanes(dot(w, w));
  const Mask degenerate = ~(n1.v > (P(1e-7) * select_lanes(n0_positive, n0, P(1))).v);
  if (!no_lane(degenerate)) {
    const Mask middle = (uc[0].x.v < 0.5) & (uc[0].x.v > -0.5);
    const Vec3<P> w2 =
        cross(uc[0], select_lanes(middle, Vec3<P>{P(1), P(0), P(0)}, Vec3<P>{P(0), P(1), P(0)}));
    w = select_lanes(degenerate, w2, w);
    n1 = select_lanes(degenerate, sqrt_lanes(dot(w2, w2)), n1);
  }
  uc[1] = w / n1;
  uc[2] = cross(uc[0], uc[1]);
  P sig[3], sh[3], eh[3];
  P tr = P(0);
  for (int i = 0; i < 3; ++i) {
    sig[i] = dot(uc[i], fv[i]);
    sh[i] = select_lanes(sig[i].v > stretch_min.v, sig[i], stretch_min);
    eh[i] = P(0.5) * (sh[i] * sh[i] - P(1));
    tr += eh[i];
  }
  P psi = P(0.5) * lambda * tr * tr;
  Mat3<P> out = Mat3<P>::zero();
  for (int i = 0; i < 3; ++i) {
    const P pi = sh[i] * (lambda * tr + P(2) * mu * eh[i]);
    psi += mu * eh[i] * eh[i] + pi * (sig[i] - sh[i]);
    out = out + pi * outer(uc[i], vc[i]);
  }
  *p = out;
  return psi;
}

// One batch of a clamped pass for batch_clamp: where it is and where its forces go (in), its
// energy term (out).
template <class P>
struct ClampBatch {
  const Model* model;
  const double* u;         // displacements [m], x, y, z per vertex (State::u)
  const double* rows;      // the batch's Model::cpu_tet_batches rows
  const int32_t* offsets;  // its Model::cpu_tet_corner_offsets
  const int32_t* codes;    // its AssemblyPlan::corner_code
  double* blocks;          // AssemblyPlan::blocks
  int64_t t0;              // its first tetrahedron
  int lanes;               // lanes [0, lanes) in the mesh
  TetChunkResult* result;  // the chunk's counts (added to)
  P w;                     // energy term [J] (-4 V psi with kFma)
};

// Scatters a batch's corner forces: all lanes by the pack's own store, or lanes [0, lanes) one
// by one (the last batch of a chunk). Lane by lane in ascending tetrahedron order either way.
template <class L>
[[gnu::always_inline]] inline void store_batch(const Vec3<typename L::Pack> f[4], double* blocks,
                                               const int32_t* code, int lanes) {
  if (lanes == L::kLanes) {
    L::store(f, blocks, code);
    return;
  }
  for (int l = 0; l < lanes; ++l)
    for (int c = 0; c < 4; ++c)
      scatter_corner(blocks, code[8 * c + l],
                     P4(static_cast<double>(f[c].x.v[l]), static_cast<double>(f[c].y.v[l]),
                        static_cast<double>(f[c].z.v[l]), 0.0));
}

// The clamped SVK (InversionHandling::kClampStretch) in a batch whose |H|^2 filter failed: the
// batch's element math again, as the pass forms it, the clamp, and the scatter. (Formed and
// scattered here rather than handed over and back: a pass that keeps its forces for such a call
// keeps them in memory in every batch.) The scalar clamped element (engine/fem/element_eval.h's
// kSvkGradientClamped; the CPU's per-tetrahedron pass until the batched passes took it over)
// clamps where the element is inverted or a stretch is below m.clamp_stretch
// (tet_health_from_strain at that stretch); the same quantities are formed here lane by lane in
// the scalar order, so the decision is the same. Where some lane is clamped the clamped stress
// is formed for the whole batch (batch_svk_first_piola_clamped) and the clamped lanes take its
// forces and energy in place of the pass's (w: the pass's energy term, -4 V psi with kFma); the
// other lanes keep the pass's. Health and clamp counts and first offenders in lane order, as the
// scalar pass counted them.
template <class L, bool kFma>
[[gnu::always_inline]] inline void batch_clamp(ClampBatch<typename L::Pack>& batch) {
  using P = typename L::Pack;
  const Model& m = *batch.model;
  const int64_t t0 = batch.t0;
  Vec3<P> f[4];
  P& w = batch.w;
  TetChunkResult& r = *batch.result;
  TetShape<P> shape;
  P lambda, mu;
  Vec3<P> du[3];
  L::load(batch.rows, batch.u, batch.offsets, shape, lambda, mu, du);
  if constexpr (kFma)
    batch_element_math_fma<true>(shape, lambda, mu, du, f, &w, [](const P&) {});
  else
    batch_element_math<true>(shape, lambda, mu, du, f, &w, [](const P&) {});
  P det_f, m1, m2, det_a;
  // At the collapse stretch the health minors decide the clamp too.
  const bool own_stretch = m.clamp_stretch != kSvkCollapseStretch;
  P clamp_minors[3];
  batch_health_values<true>(shape, du, &det_f, &m1, &m2, &det_a, m.clamp_stretch,
                            own_stretch ? clamp_minors : nullptr);
  if (!own_stretch) {
    clamp_minors[0] = m1;
    clamp_minors[1] = m2;
    clamp_minors[2] = det_a;
  }
  // Health at the collapse stretch and the clamp's check: where no lane fails either, the batch
  // is scattered as the pass formed it.
  if (!L::template healthy<true>(det_f, m1, m2, det_a) ||
      !L::template healthy<true>(det_f, clamp_minors[0], clamp_minors[1], clamp_minors[2])) {
    const auto clamp = ~((det_f.v > 0) & (clamp_minors[0].v > 0) & (clamp_minors[1].v > 0) &
                         (clamp_minors[2].v > 0));
    if (!no_lane(clamp)) {
      // The scalar clamped element, lane by lane: the clamped P, its corner forces and V psi.
      Mat3<P> p;
      const Mat3<P> h = tet_displacement_gradient_from_edges(shape, du);
      const P psi = batch_svk_first_piola_clamped(h, lambda, mu, P(m.clamp_stretch), &p);
      Vec3<P> fc[4];
      tet_forces_from_stress(shape, p, fc);
      const P wc = shape.volume * psi;
      for (int c = 0; c < 4; ++c) f[c] = select_lanes(clamp, fc[c], f[c]);
      // kFma: -4 V psi, exactly (a power of two), as batch_pass scales the sum back by -1/4.
      w = select_lanes(clamp, kFma ? P(-4.0) * wc : wc, w);
    }
    for (int l = 0; l < batch.lanes; ++l) {
      uint32_t bits = det_f.v[l] > 0 ? 0u : uint32_t{kElementInverted};
      if (!(m1.v[l] > 0 && m2.v[l] > 0 && det_a.v[l] > 0)) bits |= kElementCollapsing;
      if (clamp[l]) bits |= kElementClamped;
      if (bits) {
        r.health |= bits;
        if ((bits & kElementInverted) && r.inverted_count++ == 0) r.first_inverted = t0 + l;
        if ((bits & kElementCollapsing) && r.collapsing_count++ == 0) r.first_collapsing = t0 + l;
        if (bits & kElementClamped) ++r.clamped_count;
      }
    }
  }
  store_batch<L>(f, batch.blocks, batch.codes, batch.lanes);
}

// ---------------------------------------------------------------------------------------------
// The batched passes differ only in their pack (four float64 lanes; eight float64 lanes with
// AVX-512; eight float32 lanes), that is in how a batch's inputs are loaded and its corner forces
// stored. Each Lanes type below supplies those steps for one pack; batch_pass does the rest (the
// element math, the last batch, energy, health) for all of them. Batches start at multiples of
// their lane count; kTetChunk is a multiple of eight, so no batch straddles two chunks.

// Edge differences u_{e+1} - u_0 of four lanes, lane by lane in double as
// tet_displacement_gradient forms them; o points at lane 0 of corner 0 in
// Model::cpu_tet_corner_offsets (corner c at o + 8 c).
[[gnu::always_inline]] inline void load_edges4(const double* u, const int32_t* o, Vec3<P4> du[3]) {
  Vec3<P4> uc[4];
  for (int c = 0; c < 4; ++c) {
    const int32_t* oc = o + 8 * c;
    load_xyz_transposed(u + oc[0], u + oc[1], u + oc[2], u + oc[3], uc[c].x, uc[c].y, uc[c].z);
  }
  for (int e = 0; e < 3; ++e) du[e] = uc[e + 1] - uc[0];
}

// True when every lane passed the health checks: det F > 0 and, for SVK, the three leading
// minors of C - s^2 I positive (tet_health_from_strain). A NaN fails, as in the scalar check.
// For packs of at most 256 bits; the 512-bit pack has its own copy (Lanes8d).
template <bool kSvk, class P>
[[gnu::always_inline]] inline bool lanes_healthy(const P& det_f, const P& m1, const P& m2,
                                                 const P& det_a) {
  using Scalar = std::remove_cvref_t<decltype(P{}.v[0])>;
  auto ok = det_f.v > Scalar(0);
  if constexpr (kSvk) ok &= (m1.v > Scalar(0)) & (m2.v > Scalar(0)) & (det_a.v > Scalar(0));
  return all_lanes(ok);
}

// True when every lane of x is below `bound` (a NaN is not).
template <class P>
[[gnu::always_inline]] inline bool lanes_below(const P& x, double bound) {
  using Scalar = std::remove_cvref_t<decltype(P{}.v[0])>;
  return all_lanes(x.v < static_cast<Scalar>(bound));
}

// Where tetrahedron t's lane starts in a batch-of-eight layout with `stride` elements per batch
// (t >= 0: unsigned, a shift and a mask).
inline size_t batch_lane_index(int64_t t, size_t stride) {
  const uint64_t ut = static_cast<uint64_t>(t);
  return static_cast<size_t>(ut / 8) * stride + static_cast<size_t>(ut % 8);
}

// The shape, volume and Lame rows of one batch (Model::cpu_tet_batches layout) through a pack's
// `load` (P4, P8d or P8f from double or float rows). grad[0] is not stored: no element
// function reads it.
template <class P, class T, class Load>
[[gnu::always_inline]] inline void load_batch_shape(const T* b, Load load, TetShape<P>& shape,
                                                    P& lambda, P& mu) {
  shape.grad[0] = Vec3<P>{P(0.0f), P(0.0f), P(0.0f)};
  for (int j = 1; j < 4; ++j)
    for (int i = 0; i < 3; ++i) shape.grad[j][i] = load(b + 8 * (3 * (j - 1) + i));
  shape.volume = load(b + 8 * 9);
  lambda = load(b + 8 * 10);
  mu = load(b + 8 * 11);
}

// Float64, four tetrahedra per P4 (AVX2 or baseline): half a batch of eight.
struct Lanes4d {
  using Pack = P4;
  using Row = double;
  static constexpr int kLanes = 4;
  static const Row* rows(const Model& m) { return m.cpu_tet_batches.data(); }
  static constexpr size_t kRowStride = kCpuTetBatchStride;
  [[gnu::always_inline]] static void load(const Row* b, const double* u, const int32_t* o,
                                          TetShape<P4>& shape, P4& lambda, P4& mu,
                                          Vec3<P4> du[3]) {
    load_batch_shape(b, [](const auto* p) { return load4(p); }, shape, lambda, mu);
    load_edges4(u, o, du);
  }
  [[gnu::always_inline]] static void store(const Vec3<P4> f[4], double* blocks,
                                           const int32_t* code) {
    scatter_corner_forces4(f, blocks, code);
  }
  template <bool kSvk>
  [[gnu::always_inline]] static bool healthy(const P4& det_f, const P4& m1, const P4& m2,
                                             const P4& det_a) {
    return lanes_healthy<kSvk>(det_f, m1, m2, det_a);
  }
  [[gnu::always_inline]] static bool below(const P4& x, double bound) {
    return lanes_below(x, bound);
  }
  [[gnu::always_inline]] static void add_energy4(const P4& w, P4& sum) { sum += w; }
};

// Float32 element math, eight tetrahedra per P8f: edge differences formed in float64 and rounded,
// shapes and Lame coefficients rounded at build (Model::cpu_tet_batches_f32), corner forces
// widened back to float64 (the CUDA kernels' mixed precision).
struct Lanes8f {
  using Pack = P8f;
  using Row = float;
  static constexpr int kLanes = 8;
  static const Row* rows(const Model& m) { return m.cpu_tet_batches_f32.data(); }
  static constexpr size_t kRowStride = kCpuTetBatchStrideF32;
  [[gnu::always_inline]] static void load(const Row* b, const double* u, const int32_t* o,
                                          TetShape<P8f>& shape, P8f& lambda, P8f& mu,
                                          Vec3<P8f> du[3]) {
    load_batch_shape(b, [](const auto* p) { return load8f(p); }, shape, lambda, mu);
    Vec3<P4> lo[3], hi[3];
    load_edges4(u, o, lo);
    load_edges4(u, o + 4, hi);
    for (int e = 0; e < 3; ++e)
      du[e] = Vec3<P8f>{narrow(lo[e].x, hi[e].x), narrow(lo[e].y, hi[e].y),
                        narrow(lo[e].z, hi[e].z)};
  }
  [[gnu::always_inline]] static void store(const Vec3<P8f> f[4], double* blocks,
                                           const int32_t* code) {
    for (int half = 0; half < 2; ++half) {
      Vec3<P4> fd[4];
      for (int c = 0; c < 4; ++c)
        fd[c] = Vec3<P4>{widen(f[c].x, half), widen(f[c].y, half), widen(f[c].z, half)};
      scatter_corner_forces4(fd, blocks, code + 4 * half);
    }
  }
  template <bool kSvk>
  [[gnu::always_inline]] static bool healthy(const P8f& det_f, const P8f& m1, const P8f& m2,
                                             const P8f& det_a) {
    return lanes_healthy<kSvk>(det_f, m1, m2, det_a);
  }
  [[gnu::always_inline]] static bool below(const P8f& x, double bound) {
    return lanes_below(x, bound);
  }
};

// The element pass over chunks [chunk_begin, chunk_end) with batches of L::kLanes tetrahedra:
// lane by lane the fem_element.h functions in their order, so bit-identical to them, or with
// kFma batch_element_math_fma (only in functions built for FMA). With kClampBatch (SVK,
// float64: the inversion-safe SVK) the batches that may hold a clamped lane go through it (a
// batch_clamp built for the pass's instruction set).
template <bool kSvk, class L, bool kFma = false,
          void (*kClampBatch)(ClampBatch<typename L::Pack>&) = nullptr>
[[gnu::always_inline]] inline void batch_pass(void* context, int64_t chunk_begin,
                                              int64_t chunk_end) {
  constexpr bool kClamp = kClampBatch != nullptr;
  static_assert(!kClamp || (kSvk && std::is_same_v<typename L::Row, double>));
  using P = typename L::Pack;
  constexpr int kLanes = L::kLanes;
  const Model& m = *static_cast<PassContext*>(context)->model;
  State& s = *static_cast<PassContext*>(context)->state;
  const int64_t nt = static_cast<int64_t>(m.tet_count());
  const double* ug = &s.u.data()->x;
  // kClamp: below this |H|^2 in every lane no lane is clamped, inverted or collapsing
  // (clamp_check_skip_below_gradient_sq; it is at most kHealthCheckSkipBelowGradientSq).
  const double clamp_bound = kClamp ? clamp_check_skip_below_gradient_sq(m.clamp_stretch) : 0.0;
  double* blocks = s.assembly.blocks.data();
  const int32_t* codes = s.assembly.corner_code.data();
  const typename L::Row* rows = L::rows(m);
  const int32_t* offsets = m.cpu_tet_corner_offsets.data();
  for (int64_t chunk = chunk_begin; chunk < chunk_end; ++chunk) {
    TetChunkResult r;
    double energy = 0;  // r.elastic_energy, in a register
    // kFma: the -4 V psi of full groups of four lanes summed per lane (tetrahedra t, t + 4, ...
    // of the chunk in lane t % 4), and of lanes past the last full group in `energy`; the chunk's
    // energy is -1/4 of ((l0 + l1) + (l2 + l3)) + energy. The eight-lane pass adds its two halves
    // in order, so it sums exactly as the four-lane passes do.
    P4 energy4 = zero4();
    const int64_t begin = chunk * kTetChunk;
    const int64_t end = std::min(nt, begin + kTetChunk);
    // Batches of eight in the model's layouts (begin is a multiple of eight), with pointers
    // carried from batch to batch rather than recomputed from t0: the loop's bookkeeping was ~30
    // scalar instructions per batch of four, a tenth of the batch.
    const size_t first_batch = static_cast<size_t>(begin) / 8;
    const typename L::Row* b8 = rows + first_batch * L::kRowStride;
    const int32_t* o8 = offsets + first_batch * kCpuTetOffsetStride;
    const int32_t* c8 = codes + first_batch * kCpuTetOffsetStride;
    for (int64_t t8 = begin; t8 < end; t8 += 8, b8 += L::kRowStride, o8 += kCpuTetOffsetStride,
                 c8 += kCpuTetOffsetStride)
#pragma GCC unroll 2
    for (int half = 0; half < 8; half += kLanes) {  // four-lane packs: two halves of a batch
      const int64_t t0 = t8 + half;
      if (t0 >= end) break;
      const typename L::Row* b = b8 + half;
      const int32_t* o = o8 + half;
      const int32_t* code = c8 + half;
      // Lanes past the end repeat the last tetrahedron (the model's batches are padded so);
      // their results are dropped.
      const int lanes = static_cast<int>(std::min<int64_t>(kLanes, end - t0));
      TetShape<P> shape;
      P lambda, mu;
      Vec3<P> du[3];
      L::load(b, ug, o, shape, lambda, mu, du);
      Vec3<P> f[4];
      P w;
      P h_sq;
      [[maybe_unused]] bool may_clamp = false;  // kClamp: some lane's |H|^2 reaches clamp_bound
      const auto filter = [&](const P& x) {
        if constexpr (kClamp) may_clamp = !L::below(x, clamp_bound);
        (void)x;
      };
      if constexpr (kFma)
        h_sq = batch_element_math_fma<kSvk>(shape, lambda, mu, du, f, &w, filter);
      else
        h_sq = batch_element_math<kSvk>(shape, lambda, mu, du, f, &w, filter);
      // kClamp: a batch that may hold a clamped lane is formed again, clamped and scattered by
      // kClampBatch, which counts its health too (the check below is then not needed:
      // clamp_bound is at most its bound).
      if (kClamp && may_clamp) [[unlikely]] {
        if constexpr (kClamp) {
          ClampBatch<P> batch{&m, ug, b, o, code, blocks, t0, lanes, &r, P(0.0)};
          kClampBatch(batch);
          w = batch.w;
        }
      } else {
        store_batch<L>(f, blocks, code, lanes);
      }
      if (lanes == kLanes) {
        if constexpr (kFma) {
          L::add_energy4(w, energy4);
        } else {
          // A fixed trip count: the energy stays in a register.
          for (int l = 0; l < kLanes; ++l) energy += static_cast<double>(w.v[l]);
        }
      } else {
        int first_single = 0;  // kFma: lanes below it are a full group of four, in energy4
        if constexpr (kFma && kLanes == 8)
          if (lanes >= 4) {
            energy4 += half_of(w, 0);
            first_single = 4;
          }
        for (int l = first_single; l < lanes; ++l) energy += static_cast<double>(w.v[l]);
      }
      // Health by lane masks (repeated lanes past the end copy a valid lane). Where every lane
      // has |H| <= 0.1 (Frobenius, so spectral too) the checks cannot fail: each singular value
      // of F = I + H is within 0.1 of 1, so det F > 0 (it is 1 at H = 0 and never 0 on the way)
      // and every principal stretch exceeds 0.9 > 1/sqrt(3), with margins (det F >= 0.73, the
      // minors of C - s^2 I >= 0.1) that rounding cannot eat. The exact quantities are only
      // formed where some lane is larger: the same flags as always evaluating them, for 17
      // operations per batch instead of ~45 (of ~300). kClamp: batch_clamp has counted them.
      if (!kClamp && !L::below(h_sq, kHealthCheckSkipBelowGradientSq)) {
        L::load(b, ug, o, shape, lambda, mu, du);
        P det_f, m1(0.0), m2(0.0), det_a(0.0);
        batch_health_values<kSvk>(shape, du, &det_f, &m1, &m2, &det_a);
        if (!L::template healthy<kSvk>(det_f, m1, m2, det_a))
          batch_health_slow<kSvk>(det_f, m1, m2, det_a, t0, lanes, r);
      }
    }
    if constexpr (kFma)
      r.elastic_energy =
          -0.25 * (((energy4.v[0] + energy4.v[1]) + (energy4.v[2] + energy4.v[3])) + energy);
    else
      r.elastic_energy = energy;
    s.tet_chunks[static_cast<size_t>(chunk)] = r;
  }
}

// The corner means of State::vertex_pressure's pressure and energy density for each lane of a
// batch (corner offsets o: 3 v, lane l of corner c at o[8 c + l]).
template <class L>
[[gnu::always_inline]] inline void nodal_means(const double* pe, const int32_t* o,
                                               typename L::Pack* pressure,
                                               typename L::Pack* density) {
  for (int l = 0; l < L::kLanes; ++l) {
    const double* a = pe + o[l];
    const double* b = pe + o[8 + l];
    const double* c = pe + o[16 + l];
    const double* d = pe + o[24 + l];
    pressure->v[l] = 0.25 * ((a[0] + b[0]) + (c[0] + d[0]));
    density->v[l] = 0.25 * ((a[1] + b[1]) + (c[1] + d[1]));
  }
}

// The stable neo-Hookean element pass, batches of L::kLanes tetrahedra: tet_snh_forces lane by
// lane (H, cof, J - 1 and P of fem_element.h on packs, no FMA), so bit-identical to the scalar
// element (tests check it), with batch_pass's layouts, scatter and energy order. The law's one
// health flag is informational: J <= 0 (or NaN) is counted as inverted and the law stays
// defined there (fem_element.h); the lanes are looked at one by one only where some fails.
// kNodal (Model::nodal_pressure): the element part of snh_first_piola_nodal (lambda_s = mu +
// beta lambda with Model::nodal_stabilisation) with each lane's
// corner mean of State::vertex_pressure, and that mean's energy density, which sums to the
// nodal term's energy (sum_e V_e mean_e = sum_v V_v e_v).
template <class L, bool kNodal>
[[gnu::always_inline]] inline void batch_pass_snh(void* context, int64_t chunk_begin,
                                                  int64_t chunk_end) {
  using P = typename L::Pack;
  constexpr int kLanes = L::kLanes;
  const Model& m = *static_cast<PassContext*>(context)->model;
  State& s = *static_cast<PassContext*>(context)->state;
  const int64_t nt = static_cast<int64_t>(m.tet_count());
  const double* ug = &s.u.data()->x;
  double* blocks = s.assembly.blocks.data();
  const int32_t* codes = s.assembly.corner_code.data();
  const typename L::Row* rows = L::rows(m);
  const int32_t* offsets = m.cpu_tet_corner_offsets.data();
  const double beta = m.nodal_stabilisation;
  for (int64_t chunk = chunk_begin; chunk < chunk_end; ++chunk) {
    TetChunkResult r;
    double energy = 0;
    const int64_t begin = chunk * kTetChunk;
    const int64_t end = std::min(nt, begin + kTetChunk);
    const size_t first_batch = static_cast<size_t>(begin) / 8;
    const typename L::Row* b8 = rows + first_batch * L::kRowStride;
    const int32_t* o8 = offsets + first_batch * kCpuTetOffsetStride;
    const int32_t* c8 = codes + first_batch * kCpuTetOffsetStride;
    for (int64_t t8 = begin; t8 < end; t8 += 8, b8 += L::kRowStride, o8 += kCpuTetOffsetStride,
                 c8 += kCpuTetOffsetStride)
      for (int half = 0; half < 8; half += kLanes) {
        const int64_t t0 = t8 + half;
        if (t0 >= end) break;
        const int lanes = static_cast<int>(std::min<int64_t>(kLanes, end - t0));
        TetShape<P> shape;
        P lambda, mu;
        Vec3<P> du[3];
        L::load(b8 + half, ug, o8 + half, shape, lambda, mu, du);
        Mat3<P> p;
        P jm1;
        P w;
        const Mat3<P> h = tet_displacement_gradient_from_edges(shape, du);
        if constexpr (kNodal) {
          P pressure, density;
          nodal_means<L>(s.vertex_pressure.data(), o8 + half, &pressure, &density);
          // lambda_s = mu + beta lambda (Model::nodal_stabilisation; beta 0: mu exactly).
          const P psi = snh_first_piola_with(h, mu, snh_lambda(P(beta) * lambda, mu), pressure,
                                             &p, &jm1);
          w = shape.volume * (psi + density);
        } else {
          w = shape.volume * snh_first_piola(h, lambda, mu, &p, &jm1);
        }
        Vec3<P> f[4];
        tet_forces_from_stress(shape, p, f);
        store_batch<L>(f, blocks, c8 + half, lanes);
        for (int l = 0; l < lanes; ++l) energy += static_cast<double>(w.v[l]);
        // J > 0 in every lane is -(J - 1) < 1 (a NaN fails it, as tet_snh_forces counts it).
        if (!L::below(P(0.0) - jm1, 1.0)) [[unlikely]] {
          for (int l = 0; l < lanes; ++l)
            if (!(jm1.v[l] > -1.0)) {
              r.health |= kElementInverted;
              if (r.inverted_count++ == 0) r.first_inverted = t0 + l;
            }
        }
      }
    r.elastic_energy = energy;
    s.tet_chunks[static_cast<size_t>(chunk)] = r;
  }
}

template <bool kNodal>
ZONA_SIMD_CLONES void tet_pass_chunks_snh_f64(void* context, int64_t chunk_begin,
                                              int64_t chunk_end) {
  batch_pass_snh<Lanes4d, kNodal>(context, chunk_begin, chunk_end);
}

// Nodal pressure, stage 1 over tetrahedron chunks: V_e / 4 (J_e - 1) into
// State::tet_volume_change (each element its own slot: no conflicts, any thread count).
template <class L>
[[gnu::always_inline]] inline void batch_volume_change(void* context, int64_t chunk_begin,
                                                       int64_t chunk_end) {
  using P = typename L::Pack;
  constexpr int kLanes = L::kLanes;
  const Model& m = *static_cast<PassContext*>(context)->model;
  State& s = *static_cast<PassContext*>(context)->state;
  const int64_t nt = static_cast<int64_t>(m.tet_count());
  const double* ug = &s.u.data()->x;
  double* out = s.tet_volume_change.data();
  const int64_t begin = chunk_begin * kTetChunk;
  const int64_t end = std::min(nt, chunk_end * kTetChunk);
  for (int64_t t0 = begin; t0 < end; t0 += kLanes) {
    const size_t batch = static_cast<size_t>(t0) / 8, half = static_cast<size_t>(t0) % 8;
    TetShape<P> shape;
    P lambda, mu;
    Vec3<P> du[3];
    L::load(L::rows(m) + batch * L::kRowStride + half, ug,
            m.cpu_tet_corner_offsets.data() + batch * kCpuTetOffsetStride + half, shape, lambda,
            mu, du);
    const P q = (shape.volume * P(0.25)) *
                snh_volume_change(tet_displacement_gradient_from_edges(shape, du));
    const int lanes = static_cast<int>(std::min<int64_t>(kLanes, end - t0));
    for (int l = 0; l < lanes; ++l) out[t0 + l] = static_cast<double>(q.v[l]);
  }
}

ZONA_SIMD_CLONES void volume_change_chunks(void* context, int64_t chunk_begin, int64_t chunk_end) {
  batch_volume_change<Lanes4d>(context, chunk_begin, chunk_end);
}

// Nodal pressure, stage 2 over vertex chunks: Jbar_v - 1 = (sum over the vertex's elements of
// V_e / 4 (J_e - 1)) / V_v in adjacency order (ascending elements: the same sum for every
// thread count), then lambda_v (Jbar_v - 1) and lambda_v / 2 (Jbar_v - 1)^2.
void nodal_pressure_chunks(void* context, int64_t chunk_begin, int64_t chunk_end) {
  const Model& m = *static_cast<PassContext*>(context)->model;
  State& s = *static_cast<PassContext*>(context)->state;
  const int64_t nv = static_cast<int64_t>(m.vertex_count());
  const int64_t end = std::min(nv, chunk_end * kVertexChunk);
  const double* q = s.tet_volume_change.data();
  const int32_t* offsets = m.adjacency.offsets.data();
  const int32_t* tets = m.adjacency.tets.data();
  for (int64_t v = chunk_begin * kVertexChunk; v < end; ++v) {
    double sum = 0;
    for (int32_t k = offsets[v]; k < offsets[v + 1]; ++k) sum += q[tets[k]];
    const double jm1 = sum * m.vertex_inverse_volume[static_cast<size_t>(v)];
    const double lambda = m.vertex_lambda[static_cast<size_t>(v)];
    double* out = s.vertex_pressure.data() + 3 * v;
    out[0] = lambda * jm1;
    out[1] = 0.5 * lambda * jm1 * jm1;
  }
}

// The batches of the clamped passes that may hold a clamped lane, one function per pass, built
// for its instruction set and called, not inlined, and handed no packs: with the ~1000
// instructions of batch_clamp inlined, every batch of the clamped pass was 27 % slower than in
// the unclamped pass, none clamped (the hot loop's registers and layout; 12 % with a scalar
// call per clamped lane); called with the batch's forces handed over and back, 8-15 %
// (they were kept in memory); as here, as fast (one thread, 20k-vertex mouse_oocyte at rest).
// They run for a few % of the batches.
__attribute__((noinline)) ZONA_SIMD_CLONES void clamp_batch_f64(ClampBatch<P4>& batch) {
  batch_clamp<Lanes4d, false>(batch);
}

// GCC builds an AVX2 clone and a baseline clone of these two and picks one at load time; FMA is
// left out on purpose, because contracting a*b+c would change the bits between the clones. The
// float64 one runs where the fused pass below does not (CPU without FMA, or ZONA_CPU_FMA=0).
template <bool kSvk, bool kClamp = false>
ZONA_SIMD_CLONES void tet_pass_chunks_f64(void* context, int64_t chunk_begin, int64_t chunk_end) {
  batch_pass<kSvk, Lanes4d, false, kClamp ? &clamp_batch_f64 : nullptr>(context, chunk_begin,
                                                                        chunk_end);
}

template <bool kSvk>
ZONA_SIMD_CLONES void tet_pass_chunks_f32(void* context, int64_t chunk_begin, int64_t chunk_end) {
  batch_pass<kSvk, Lanes8f>(context, chunk_begin, chunk_end);
}

#if defined(__GNUC__) && !defined(__clang__) && defined(__x86_64__) && \
    !defined(__SANITIZE_THREAD__)
#define ZONA_HAVE_AVX512_PASS 1
// The four-lane packs of the FMA passes (AVX2 and FMA at least): the health filter's compare
// reduced by one movemask (vcmppd, vmovmskpd, cmp) instead of all_lanes' two permutes and ands.
struct Lanes4dFma : Lanes4d {
  // Built for the passes' instruction set; `flatten` inlines it into them (as Lanes8d's).
  __attribute__((target("avx2,fma"))) static bool below(const P4& x, double bound) {
    return _mm256_movemask_pd(_mm256_cmp_pd(x.v, _mm256_set1_pd(bound), _CMP_LT_OQ)) == 0xF;
  }
};

// The four-lane FMA pack where AVX-512VL gives one-instruction two-source permutes (vpermt2pd):
// a corner's (x, y, z) packs become its four lanes' blocks in six shuffles instead of the
// 4 x 4 transpose's eight. The blocks' fourth lane, which nothing reads (take_vertex_force's
// consumers use x, y, z), receives a second copy of z rather than 0.
struct Lanes4dVl : Lanes4dFma {
  // The corners' displacements by zero-masked 32-byte loads of (x, y, z) (the fourth lane is
  // neither read from memory nor used: nothing past a vertex is touched) and a transpose of
  // seven shuffles: 4 loads per corner instead of 4 x (x, y) + 4 z loads, 2 of them with a
  // shuffle, and the same bits.
  [[gnu::always_inline]] static void load(const Row* b, const double* u, const int32_t* o,
                                          TetShape<P4>& shape, P4& lambda, P4& mu,
                                          Vec3<P4> du[3]) {
    load_batch_shape(b, [](const auto* p) { return load4(p); }, shape, lambda, mu);
    Vec3<P4> uc[4];
    for (int c = 0; c < 4; ++c) load_xyz_masked(u, o + 8 * c, uc[c]);
    for (int e = 0; e < 3; ++e) du[e] = uc[e + 1] - uc[0];
  }
  __attribute__((target("avx2,fma,avx512f,avx512vl"))) static void load_xyz_masked(
      const double* u, const int32_t* oc, Vec3<P4>& r) {
    const __m256d l0 = _mm256_maskz_loadu_pd(0x7, u + oc[0]);  // x0 y0 z0 0
    const __m256d l1 = _mm256_maskz_loadu_pd(0x7, u + oc[1]);
    const __m256d l2 = _mm256_maskz_loadu_pd(0x7, u + oc[2]);
    const __m256d l3 = _mm256_maskz_loadu_pd(0x7, u + oc[3]);
    const __m256d xz01 = _mm256_unpacklo_pd(l0, l1);  // x0 x1 z0 z1
    const __m256d y01 = _mm256_unpackhi_pd(l0, l1);   // y0 y1 0 0
    const __m256d xz23 = _mm256_unpacklo_pd(l2, l3);  // x2 x3 z2 z3
    const __m256d y23 = _mm256_unpackhi_pd(l2, l3);   // y2 y3 0 0
    r.x.v = _mm256_permute2f128_pd(xz01, xz23, 0x20);
    r.y.v = _mm256_permute2f128_pd(y01, y23, 0x20);
    r.z.v = _mm256_permute2f128_pd(xz01, xz23, 0x31);
  }
  [[gnu::always_inline]] static void store(const Vec3<P4> f[4], double* blocks,
                                           const int32_t* code) {
    P4 corner[4][4];  // [corner][lane]
    for (int c = 0; c < 4; ++c) {
      const V4 xy_even = __builtin_shufflevector(f[c].x.v, f[c].y.v, 0, 4, 2, 6);  // x0 y0 x2 y2
      const V4 xy_odd = __builtin_shufflevector(f[c].x.v, f[c].y.v, 1, 5, 3, 7);   // x1 y1 x3 y3
      corner[c][0].v = __builtin_shufflevector(xy_even, f[c].z.v, 0, 1, 4, 4);
      corner[c][1].v = __builtin_shufflevector(xy_odd, f[c].z.v, 0, 1, 5, 5);
      corner[c][2].v = __builtin_shufflevector(xy_even, f[c].z.v, 2, 3, 6, 6);
      corner[c][3].v = __builtin_shufflevector(xy_odd, f[c].z.v, 2, 3, 7, 7);
    }
    for (int l = 0; l < 4; ++l)
      for (int c = 0; c < 4; ++c) scatter_corner(blocks, code[8 * c + l], corner[c][l]);
  }
};

// Float64 with eight tetrahedra per AVX-512 pack, chosen at run time on CPUs that have AVX-512F
// (cpu_simd_bits() == 512): the same lane operations, so the same bits as the four-lane pass.
// Corners are loaded as by the four-lane pass, one half at a time: hardware gathers
// (vgatherdpd, three per corner) measured 2x slower for the whole pass on the Ice Lake host of
// docs/performance.md.
struct Lanes8d {
  using Pack = P8d;
  using Row = double;
  static constexpr int kLanes = 8;
  static const Row* rows(const Model& m) { return m.cpu_tet_batches.data(); }
  static constexpr size_t kRowStride = kCpuTetBatchStride;
  [[gnu::always_inline]] static void load(const Row* b, const double* u, const int32_t* o,
                                          TetShape<P8d>& shape, P8d& lambda, P8d& mu,
                                          Vec3<P8d> du[3]) {
    load_batch_shape(b, [](const auto* p) { return load8d(p); }, shape, lambda, mu);
    Vec3<P4> lo[3], hi[3];
    load_edges4(u, o, lo);
    load_edges4(u, o + 4, hi);
    for (int e = 0; e < 3; ++e)
      du[e] = Vec3<P8d>{concat(lo[e].x, hi[e].x), concat(lo[e].y, hi[e].y),
                        concat(lo[e].z, hi[e].z)};
  }
  [[gnu::always_inline]] static void store(const Vec3<P8d> f[4], double* blocks,
                                           const int32_t* code) {
    for (int half = 0; half < 2; ++half) {
      Vec3<P4> fd[4];
      for (int c = 0; c < 4; ++c)
        fd[c] = Vec3<P4>{half_of(f[c].x, half), half_of(f[c].y, half), half_of(f[c].z, half)};
      scatter_corner_forces4(fd, blocks, code + 4 * half);
    }
  }
  // lanes_healthy's and lanes_below's comparisons, written out here: in a function without the
  // AVX-512 target GCC lowers 512-bit comparisons lane by lane before they are inlined into the
  // pass (2x slower).
  template <bool kSvk>
  __attribute__((target("avx512f"))) static bool healthy(const P8d& det_f, const P8d& m1,
                                                         const P8d& m2, const P8d& det_a) {
    M8d ok = det_f.v > 0.0;
    if constexpr (kSvk) ok &= (m1.v > 0.0) & (m2.v > 0.0) & (det_a.v > 0.0);
    return all_lanes(ok);
  }
  __attribute__((target("avx512f"))) static bool below(const P8d& x, double bound) {
    return all_lanes(x.v < bound);
  }
  // Lanes 0-3, then 4-7: the four-lane passes' two batches in their order.
  [[gnu::always_inline]] static void add_energy4(const P8d& w, P4& sum) {
    sum += half_of(w, 0);
    sum += half_of(w, 1);
  }
};

// AVX-512F brings FMA for 512-bit vectors: contraction is switched off here, so that a * b + c
// fuses exactly where batch_element_math_fma says (kFma) and nowhere else (the health checks;
// without kFma the bits of the other passes).
template <bool kFma>
__attribute__((target("avx512f"), optimize("fp-contract=off"), flatten, noinline)) void
clamp_batch_avx512(ClampBatch<P8d>& batch) {
  batch_clamp<Lanes8d, kFma>(batch);
}

template <bool kSvk, bool kFma, bool kClamp = false>
__attribute__((target("avx512f"), optimize("fp-contract=off"), flatten)) void
tet_pass_chunks_f64_avx512(void* context, int64_t chunk_begin, int64_t chunk_end) {
  batch_pass<kSvk, Lanes8d, kFma, kClamp ? &clamp_batch_avx512<kFma> : nullptr>(
      context, chunk_begin, chunk_end);
}

// The stable neo-Hookean pass with eight lanes (no FMA: the same bits as the four-lane one).
__attribute__((target("avx512f"), optimize("fp-contract=off"), flatten)) void
tet_pass_chunks_snh_avx512(void* context, int64_t chunk_begin, int64_t chunk_end) {
  batch_pass_snh<Lanes8d, false>(context, chunk_begin, chunk_end);
}

// Four float64 lanes with AVX2 and FMA: the same fused operations in the same order as the
// AVX-512 FMA pass, so the same bits. Chosen at run time (cpu_element_fma()); CPUs without FMA
// run tet_pass_chunks_f64 (bit-identical to fem_element.h).
__attribute__((target("avx2,fma"), optimize("fp-contract=off"), flatten, noinline)) void
clamp_batch_fma(ClampBatch<P4>& batch) {
  batch_clamp<Lanes4dFma, true>(batch);
}

template <bool kSvk, bool kClamp = false>
__attribute__((target("avx2,fma"), optimize("fp-contract=off"), flatten)) void
tet_pass_chunks_f64_fma(void* context, int64_t chunk_begin, int64_t chunk_end) {
  batch_pass<kSvk, Lanes4dFma, true, kClamp ? &clamp_batch_fma : nullptr>(context, chunk_begin,
                                                                          chunk_end);
}

// The same four-lane fused pass encoded with AVX-512VL, on CPUs that have it (cpu_simd_registers()
// == 32): still 256-bit vectors (no 512-bit frequency licence), but 32 vector registers instead of
// 16, so the batch's ~40 live packs stop spilling (~50 fewer loads and stores per batch of four;
// docs/performance.md, "CPU fused SIMD element pass"). The same operations in the same order:
// the same bits.
__attribute__((target("avx2,fma,avx512f,avx512vl"), optimize("fp-contract=off"), flatten,
               noinline)) void
clamp_batch_fma32(ClampBatch<P4>& batch) {
  batch_clamp<Lanes4dVl, true>(batch);
}

template <bool kSvk, bool kClamp = false>
__attribute__((target("avx2,fma,avx512f,avx512vl"), optimize("fp-contract=off"), flatten)) void
tet_pass_chunks_f64_fma32(void* context, int64_t chunk_begin, int64_t chunk_end) {
  batch_pass<kSvk, Lanes4dVl, true, kClamp ? &clamp_batch_fma32 : nullptr>(context, chunk_begin,
                                                                           chunk_end);
}
#endif

// The element pass over chunks [chunk_begin, chunk_end) for one element kind.
template <class Kernel>
void tet_pass_chunks(void* context, int64_t chunk_begin, int64_t chunk_end) {
  const Model& m = *static_cast<PassContext*>(context)->model;
  State& s = *static_cast<PassContext*>(context)->state;
  const int64_t nt = static_cast<int64_t>(m.tet_count());
  const Vec3d* ug = s.u.data();
  double* blocks = s.assembly.blocks.data();
  const int32_t* codes = s.assembly.corner_code.data();
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
      for (int c = 0; c < 4; ++c)
        scatter_corner(blocks, codes[batch_lane_index(ti, kCpuTetOffsetStride) + 8 * c],
                       P4(f[c].x, f[c].y, f[c].z, 0.0));
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

// The float64 gradient-form pass for this CPU and the settings (cpu_element_fma(),
// cpu_simd_bits(), cpu_simd_registers()).
template <bool kSvk, bool kClamp>
ThreadPool::ChunkFn select_f64_pass() {
#ifdef ZONA_HAVE_AVX512_PASS
  if (cpu_element_fma()) {
    if (cpu_simd_bits() >= 512) return &tet_pass_chunks_f64_avx512<kSvk, true, kClamp>;
    if (cpu_simd_registers() >= 32) return &tet_pass_chunks_f64_fma32<kSvk, kClamp>;
    return &tet_pass_chunks_f64_fma<kSvk, kClamp>;
  }
  if (cpu_simd_bits() >= 512) return &tet_pass_chunks_f64_avx512<kSvk, false, kClamp>;
#endif
  return &tet_pass_chunks_f64<kSvk, kClamp>;
}

ThreadPool::ChunkFn select_tet_pass(const Model& m) {
  // Stable neo-Hookean: gradient form only (build_model), float64, the batched pass.
  // Nodal pressure: four lanes (the corner means are gathered lane by lane).
  if (m.constitutive == ConstitutiveModel::kStableNeoHookean) {
    if (m.nodal_pressure) return &tet_pass_chunks_snh_f64<true>;
#ifdef ZONA_HAVE_AVX512_PASS
    if (cpu_simd_bits() >= 512) return &tet_pass_chunks_snh_avx512;
#endif
    return &tet_pass_chunks_snh_f64<false>;
  }
  const bool svk = m.constitutive == ConstitutiveModel::kSvk;
  switch (m.formulation) {
    case Formulation::kGradient:
      if (m.element_precision == ElementPrecision::kFloat32)  // build_model: no clamp then
        return svk ? &tet_pass_chunks_f32<true> : &tet_pass_chunks_f32<false>;
      if (!svk) return select_f64_pass<false, false>();
      if (m.inversion == InversionHandling::kClampStretch) return select_f64_pass<true, true>();
      return select_f64_pass<true, false>();
    case Formulation::kTensorStored:
      return svk ? &tet_pass_chunks<SvkTensorStored> : &tet_pass_chunks<LinearTensorStored>;
    case Formulation::kTensorRebuilt:
      return svk ? &tet_pass_chunks<SvkTensorRebuilt> : &tet_pass_chunks<LinearTensorRebuilt>;
  }
  return &tet_pass_chunks_f64<true>;
}

// Vertex forces from the blocks, which it puts back at their start values.
void gather_chunks(void* context, int64_t chunk_begin, int64_t chunk_end) {
  const Model& m = *static_cast<PassContext*>(context)->model;
  State& s = *static_cast<PassContext*>(context)->state;
  const int64_t nv = static_cast<int64_t>(m.vertex_count());
  const int64_t end = std::min(nv, chunk_end * kVertexChunk);
  double* b = s.assembly.blocks.data();
  const int32_t* late = s.assembly.late_offsets.data();
  for (int64_t v = chunk_begin * kVertexChunk; v < end; ++v)
    store_xyz(take_vertex_force(b, late, static_cast<size_t>(v)), s.force[static_cast<size_t>(v)]);
}

// The element pass over segments [segment_begin, segment_end) of State::assembly: each segment's
// chunks in order on this thread (AssemblyPlan's ownership rule needs it).
struct SegmentContext {
  PassContext pass;
  ThreadPool::ChunkFn chunks;
};

void run_segments(void* context, int64_t segment_begin, int64_t segment_end) {
  SegmentContext& c = *static_cast<SegmentContext*>(context);
  const std::vector<int64_t>& first = c.pass.state->assembly.segment_chunk;
  c.chunks(&c.pass, first[static_cast<size_t>(segment_begin)],
           first[static_cast<size_t>(segment_end)]);
}

}  // namespace

namespace {

// True when the CPU has AVX2 and FMA (every AVX-512F CPU has both) and ZONA_CPU_FMA is not 0.
bool detect_element_fma() {
#ifdef ZONA_HAVE_AVX512_PASS
  if (const char* env = std::getenv("ZONA_CPU_FMA"); env && std::atoi(env) == 0) return false;
  __builtin_cpu_init();
  return __builtin_cpu_supports("avx2") && __builtin_cpu_supports("fma");
#else
  return false;
#endif
}

// True when the CPU has AVX-512F and ZONA_CPU_SIMD_BITS does not say 256.
bool avx512_allowed() {
#ifdef ZONA_HAVE_AVX512_PASS
  if (const char* env = std::getenv("ZONA_CPU_SIMD_BITS"); env && std::atoi(env) == 256)
    return false;
  __builtin_cpu_init();
  return __builtin_cpu_supports("avx512f");
#else
  return false;
#endif
}

// True when the CPU has AVX-512VL and ZONA_CPU_SIMD_REGISTERS does not say 16.
bool avx512vl_allowed() {
#ifdef ZONA_HAVE_AVX512_PASS
  if (const char* env = std::getenv("ZONA_CPU_SIMD_REGISTERS"); env && std::atoi(env) == 16)
    return false;
  __builtin_cpu_init();
  return __builtin_cpu_supports("avx512f") && __builtin_cpu_supports("avx512vl");
#else
  return false;
#endif
}

std::atomic<int>& simd_registers_setting() {
  static std::atomic<int> registers{avx512vl_allowed() ? 32 : 16};
  return registers;
}

// The default width, read once: 512 where allowed, except with FMA. The fused 256-bit pass gives
// the same bits as the 512-bit one and an element pass as fast, and the whole step ran 4-9 %
// faster with it (same-process A/B on the Xeon of docs/performance.md: the 512-bit pass slows
// the vertex pass after it). ZONA_CPU_SIMD_BITS=512 asks for the 512-bit one anyway.
int detect_simd_bits() {
  if (!avx512_allowed()) return 256;
  if (const char* env = std::getenv("ZONA_CPU_SIMD_BITS"); env && std::atoi(env) == 512)
    return 512;
  return detect_element_fma() ? 256 : 512;
}

std::atomic<int>& simd_bits_setting() {
  static std::atomic<int> bits{detect_simd_bits()};
  return bits;
}

std::atomic<bool>& element_fma_setting() {
  static std::atomic<bool> on{detect_element_fma()};
  return on;
}

}  // namespace

bool cpu_element_fma() { return element_fma_setting().load(std::memory_order_relaxed); }

void set_cpu_element_fma(bool on) {
  element_fma_setting().store(on && detect_element_fma(), std::memory_order_relaxed);
}

int cpu_simd_bits() { return simd_bits_setting().load(std::memory_order_relaxed); }

void set_cpu_simd_bits(int bits) {
  simd_bits_setting().store(bits >= 512 && avx512_allowed() ? 512 : 256,
                            std::memory_order_relaxed);
}

int cpu_simd_registers() { return simd_registers_setting().load(std::memory_order_relaxed); }

void set_cpu_simd_registers(int registers) {
  simd_registers_setting().store(registers >= 32 && avx512vl_allowed() ? 32 : 16,
                                 std::memory_order_relaxed);
}

void compute_tet_forces(const Model& model, State& state) {
  if (model.nodal_pressure) {
    PassContext context{&model, &state};
    state.pool->run(static_cast<int64_t>(state.tet_chunks.size()), &volume_change_chunks,
                    &context);
    state.pool->run(static_cast<int64_t>(state.vertex_chunks.size()), &nodal_pressure_chunks,
                    &context);
  }
  if (state.assembly.dirty) reset_assembly_blocks(state);
  SegmentContext context{{&model, &state}, select_tet_pass(model)};
  state.pool->run(state.assembly.segment_count(), &run_segments, &context);
  state.assembly.dirty = true;
}

Vec3d corner_force(const State& state, size_t t, int c) {
  ZONA_ASSERT(state.assembly.all_late());
  const double* b =
      state.assembly.blocks.data() + 4 * static_cast<size_t>(state.assembly.corner_block[4 * t +
                                                                  static_cast<size_t>(c)]);
  return Vec3d{b[0], b[1], b[2]};
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
  state.assembly.dirty = false;
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
    const Vec3d ue[4] = {u[e[0]], u[e[1]], u[e[2]], u[e[3]]};
    if (model.constitutive == ConstitutiveModel::kSvk) {
      tet_svk_stiffness(model.tet_shape[t], l.lambda, l.mu, ue, k);
    } else if (model.constitutive == ConstitutiveModel::kStableNeoHookean) {
      tet_snh_stiffness(model.tet_shape[t], l.lambda, l.mu, ue, k);
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
    // y = M^-1/2 K M^-1/2 x, with K x from the linear element forces (f = -K x): the tangent
    // at rest of every law here (SVK and stable neo-Hookean linearise to it).
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
