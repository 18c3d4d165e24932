// Four-lane double and eight-lane float packs (GCC vector extensions) for the CPU backend's
// batched loops, and the attribute that builds an AVX2 clone beside the baseline one. Each lane
// performs exactly the scalar operations in the scalar order, so packed results are
// bit-identical to scalar code of the same precision; `fmadd` and `fnmsub` (one rounding) are the
// exception, for the FMA element passes only.
#pragma once

#include <cstring>
#include <type_traits>

#if defined(__GNUC__) && !defined(__clang__) && defined(__x86_64__)
#include <immintrin.h>
#endif

#include "engine/core/vec.h"

namespace zona {

// Not under ThreadSanitizer: its runtime is not up yet when the clones' ifunc resolver runs.
#if defined(__GNUC__) && !defined(__clang__) && defined(__x86_64__) && !defined(__SANITIZE_THREAD__)
#define ZONA_SIMD_CLONES __attribute__((target_clones("avx2", "default"), flatten))
#else
#define ZONA_SIMD_CLONES
#endif

/// Four doubles in one 256-bit register (AVX) or two 128-bit ones (baseline).
typedef double V4 __attribute__((vector_size(32)));

/// Four doubles operated on lane by lane.
struct P4 {
  V4 v;
  P4() = default;
  P4(double x) : v{x, x, x, x} {}  // NOLINT: implicit, as T(0.5) and T x = 0 need
  P4(double a, double b, double c, double d) : v{a, b, c, d} {}
};
// The lane-by-lane operators of a pack type T (a struct with one vector member `v`).
#define ZONA_PACK_BINARY_OP(T, op)                                                       \
  [[gnu::always_inline]] inline T operator op(T a, T b) {                               \
    T r;                                                                                 \
    r.v = a.v op b.v;                                                                    \
    return r;                                                                            \
  }
#define ZONA_PACK_OPS(T)                                                                 \
  ZONA_PACK_BINARY_OP(T, +)                                                              \
  ZONA_PACK_BINARY_OP(T, -)                                                              \
  ZONA_PACK_BINARY_OP(T, *)                                                              \
  ZONA_PACK_BINARY_OP(T, /)                                                              \
  [[gnu::always_inline]] inline T operator-(T a) {                                       \
    T r;                                                                                 \
    r.v = -a.v;                                                                          \
    return r;                                                                            \
  }                                                                                      \
  [[gnu::always_inline]] inline T& operator+=(T& a, T b) {                               \
    a.v += b.v;                                                                          \
    return a;                                                                            \
  }                                                                                      \
  [[gnu::always_inline]] inline T& operator-=(T& a, T b) {                               \
    a.v -= b.v;                                                                          \
    return a;                                                                            \
  }
ZONA_PACK_OPS(P4)

/// All four lanes 0 (a plain vxorpd; P4(0.0) can compile to lane-by-lane inserts).
[[gnu::always_inline]] inline P4 zero4() {
  P4 r;
  r.v = V4{};
  return r;
}

/// Lane masks of a P4 comparison: -1 where it holds, 0 where not.
typedef decltype(V4{} > V4{}) M4;
/// Two doubles (half a pack).
typedef double V2 __attribute__((vector_size(16)));

/// Four doubles from p (any alignment; all four must be readable).
[[gnu::always_inline]] inline P4 load4(const double* p) {
  P4 r;
  std::memcpy(&r.v, p, sizeof r.v);
  return r;
}

/// Stores the four lanes of `a` at p (any alignment).
[[gnu::always_inline]] inline void store4(P4 a, double* p) { std::memcpy(p, &a.v, sizeof a.v); }

/// True when every lane of the mask holds (no lane is 0).
[[gnu::always_inline]] inline bool all_lanes(M4 m) {
  m &= __builtin_shufflevector(m, m, 2, 3, 0, 1);
  m &= __builtin_shufflevector(m, m, 1, 0, 3, 2);
  return m[0] != 0;
}

/// The x, y and z packs of four 3-vectors of doubles starting at a0..a3 (lane l from a_l): a
/// 16-byte load of (x, y) per vector, two unpacks, and the four z gathered. Loads nothing past
/// any vector's end.
[[gnu::always_inline]] inline void load_xyz_transposed(const double* a0, const double* a1,
                                                       const double* a2, const double* a3, P4& x,
                                                       P4& y, P4& z) {
  V2 l0, l1, l2, l3;
  std::memcpy(&l0, a0, sizeof l0);
  std::memcpy(&l1, a1, sizeof l1);
  std::memcpy(&l2, a2, sizeof l2);
  std::memcpy(&l3, a3, sizeof l3);
  const V4 a = __builtin_shufflevector(l0, l2, 0, 1, 2, 3);  // x0 y0 x2 y2
  const V4 b = __builtin_shufflevector(l1, l3, 0, 1, 2, 3);  // x1 y1 x3 y3
  x.v = __builtin_shufflevector(a, b, 0, 4, 2, 6);
  y.v = __builtin_shufflevector(a, b, 1, 5, 3, 7);
  z = P4(a0[2], a1[2], a2[2], a3[2]);
}

/// The x, y and z packs of the four consecutive 3-vectors of doubles at p (twelve doubles, x0
/// y0 z0 x1 ...): three 32-byte loads and two-source shuffles.
[[gnu::always_inline]] inline void load_soa3(const double* p, P4& x, P4& y, P4& z) {
  const V4 a = load4(p).v;      // x0 y0 z0 x1
  const V4 b = load4(p + 4).v;  // y1 z1 x2 y2
  const V4 c = load4(p + 8).v;  // z2 x3 y3 z3
  x.v = __builtin_shufflevector(__builtin_shufflevector(a, b, 0, 3, 6, 6), c, 0, 1, 2, 5);
  y.v = __builtin_shufflevector(__builtin_shufflevector(a, b, 1, 4, 7, 7), c, 0, 1, 2, 6);
  z.v = __builtin_shufflevector(__builtin_shufflevector(a, b, 2, 5, 5, 5), c, 0, 1, 4, 7);
}

/// Stores packs x, y, z as four consecutive 3-vectors of doubles at p (load_soa3's inverse).
[[gnu::always_inline]] inline void store_aos3(P4 x, P4 y, P4 z, double* p) {
  const V4 xy = __builtin_shufflevector(x.v, y.v, 0, 4, 1, 5);  // x0 y0 x1 y1
  const V4 a = __builtin_shufflevector(xy, z.v, 0, 1, 4, 2);  // x0 y0 z0 x1
  const V4 yz = __builtin_shufflevector(y.v, z.v, 1, 5, 2, 6);  // y1 z1 y2 z2
  const V4 b = __builtin_shufflevector(yz, x.v, 0, 1, 6, 2);  // y1 z1 x2 y2
  const V4 zx = __builtin_shufflevector(z.v, x.v, 2, 7, 3, 3);  // z2 x3 z3 z3
  const V4 c = __builtin_shufflevector(zx, y.v, 0, 1, 7, 2);  // z2 x3 y3 z3
  std::memcpy(p, &a, sizeof a);
  std::memcpy(p + 4, &b, sizeof b);
  std::memcpy(p + 8, &c, sizeof c);
}

/// 4 x 4 transpose in place: afterwards r[i] holds lane i of the packs r[0..3] as given.
[[gnu::always_inline]] inline void transpose4(P4 r[4]) {
  const V4 t0 = __builtin_shufflevector(r[0].v, r[1].v, 0, 4, 2, 6);
  const V4 t1 = __builtin_shufflevector(r[0].v, r[1].v, 1, 5, 3, 7);
  const V4 t2 = __builtin_shufflevector(r[2].v, r[3].v, 0, 4, 2, 6);
  const V4 t3 = __builtin_shufflevector(r[2].v, r[3].v, 1, 5, 3, 7);
  r[0].v = __builtin_shufflevector(t0, t2, 0, 1, 4, 5);
  r[1].v = __builtin_shufflevector(t1, t3, 0, 1, 4, 5);
  r[2].v = __builtin_shufflevector(t0, t2, 2, 3, 6, 7);
  r[3].v = __builtin_shufflevector(t1, t3, 2, 3, 6, 7);
}

// ---------------------------------------------------------------------------------------------
// Eight-lane float packs for the float32 element math (ElementPrecision::kFloat32): each lane
// performs the scalar float operations of fem_element.h<float> in their order.

/// Eight floats in one 256-bit register (AVX) or two 128-bit ones (baseline).
typedef float F8 __attribute__((vector_size(32)));
/// Four floats (half an F8).
typedef float F4 __attribute__((vector_size(16)));
/// Lane masks of an F8 comparison.
typedef decltype(F8{} > F8{}) M8;

/// Eight floats operated on lane by lane.
struct P8f {
  F8 v;
  P8f() = default;
  /// Every lane static_cast<float>(x), as T(x) is for T = float.
  template <class S>
    requires std::is_arithmetic_v<S>
  P8f(S x) {  // NOLINT: implicit, as T(0.5) and T x = 0 need
    const float f = static_cast<float>(x);
    v = F8{f, f, f, f, f, f, f, f};
  }
};
ZONA_PACK_OPS(P8f)

/// Eight floats from p (any alignment).
[[gnu::always_inline]] inline P8f load8f(const float* p) {
  P8f r;
  std::memcpy(&r.v, p, sizeof r.v);
  return r;
}

/// Two double packs rounded to float (round to nearest, as static_cast<float>): lanes 0-3 from
/// lo, 4-7 from hi.
[[gnu::always_inline]] inline P8f narrow(P4 lo, P4 hi) {
  const F4 a = __builtin_convertvector(lo.v, F4);
  const F4 b = __builtin_convertvector(hi.v, F4);
  P8f r;
  r.v = __builtin_shufflevector(a, b, 0, 1, 2, 3, 4, 5, 6, 7);
  return r;
}

/// Lanes 0-3 (half 0) or 4-7 (half 1) of a float pack widened to double (exact).
[[gnu::always_inline]] inline P4 widen(P8f a, int half) {
  const F4 q = half == 0 ? __builtin_shufflevector(a.v, a.v, 0, 1, 2, 3)
                         : __builtin_shufflevector(a.v, a.v, 4, 5, 6, 7);
  P4 r;
  r.v = __builtin_convertvector(q, V4);
  return r;
}

/// True when every lane of the mask holds.
[[gnu::always_inline]] inline bool all_lanes(M8 m) {
  m &= __builtin_shufflevector(m, m, 4, 5, 6, 7, 0, 1, 2, 3);
  m &= __builtin_shufflevector(m, m, 2, 3, 0, 1, 6, 7, 4, 5);
  m &= __builtin_shufflevector(m, m, 1, 0, 3, 2, 5, 4, 7, 6);
  return m[0] != 0;
}

// ---------------------------------------------------------------------------------------------
// Eight-lane double packs for the AVX-512 element pass (float64, bit-identical like P4; only
// built into a function compiled with target("avx512f"): elsewhere GCC would split each op).

/// Eight doubles in one 512-bit register.
typedef double V8 __attribute__((vector_size(64)));
/// Lane masks of a P8d comparison.
typedef decltype(V8{} > V8{}) M8d;

/// Eight doubles operated on lane by lane.
struct P8d {
  V8 v;
  P8d() = default;
  P8d(double x) : v{x, x, x, x, x, x, x, x} {}  // NOLINT: implicit, as T(0.5) and T x = 0 need
};
ZONA_PACK_OPS(P8d)
#undef ZONA_PACK_OPS
#undef ZONA_PACK_BINARY_OP

/// Eight doubles from p (any alignment).
[[gnu::always_inline]] inline P8d load8d(const double* p) {
  P8d r;
  std::memcpy(&r.v, p, sizeof r.v);
  return r;
}

/// Lanes 0-3 from lo, 4-7 from hi.
[[gnu::always_inline]] inline P8d concat(P4 lo, P4 hi) {
  P8d r;
  r.v = __builtin_shufflevector(lo.v, hi.v, 0, 1, 2, 3, 4, 5, 6, 7);
  return r;
}

/// Lanes 0-3 (half 0) or 4-7 (half 1).
[[gnu::always_inline]] inline P4 half_of(P8d a, int half) {
  P4 r;
  r.v = half == 0 ? __builtin_shufflevector(a.v, a.v, 0, 1, 2, 3)
                  : __builtin_shufflevector(a.v, a.v, 4, 5, 6, 7);
  return r;
}

/// True when every lane of the mask holds.
[[gnu::always_inline]] inline bool all_lanes(M8d m) {
  m &= __builtin_shufflevector(m, m, 4, 5, 6, 7, 0, 1, 2, 3);
  m &= __builtin_shufflevector(m, m, 2, 3, 0, 1, 6, 7, 4, 5);
  m &= __builtin_shufflevector(m, m, 1, 0, 3, 2, 5, 4, 7, 6);
  return m[0] != 0;
}

#if defined(__GNUC__) && !defined(__clang__) && defined(__x86_64__)
// Fused multiply-adds per pack type: fmadd = a * b + c and fnmsub = -(a * b) - c per lane, each
// rounded once (FMA3 for P4, AVX-512F for P8d). Plain `inline` with the instruction set as
// target: they are inlined only into functions built for it (the FMA element passes of
// forces_cpu.cpp, through `flatten`); a call from anywhere else would not compile to FMA code
// and must not exist.
#define ZONA_FMA_PAIR(T, V, R, isa, fmadd_, fnmsub_)                                       \
  __attribute__((target(isa))) inline T fmadd(T a, T b, T c) {                             \
    T r;                                                                                   \
    r.v = reinterpret_cast<V>(fmadd_(reinterpret_cast<R>(a.v), reinterpret_cast<R>(b.v),   \
                                     reinterpret_cast<R>(c.v)));                           \
    return r;                                                                              \
  }                                                                                        \
  __attribute__((target(isa))) inline T fnmsub(T a, T b, T c) {                            \
    T r;                                                                                   \
    r.v = reinterpret_cast<V>(fnmsub_(reinterpret_cast<R>(a.v), reinterpret_cast<R>(b.v),  \
                                      reinterpret_cast<R>(c.v)));                          \
    return r;                                                                              \
  }

ZONA_FMA_PAIR(P4, V4, __m256d, "fma", _mm256_fmadd_pd, _mm256_fnmsub_pd)        // FMA3
ZONA_FMA_PAIR(P8d, V8, __m512d, "avx512f", _mm512_fmadd_pd, _mm512_fnmsub_pd)  // AVX-512F
#undef ZONA_FMA_PAIR
#endif

/// Stores lanes 0-2 of `a` into a Vec3d (24 bytes, never past its end).
/// From registers (a 16-byte store and an 8-byte one): a memcpy from the pack's own bytes makes
/// GCC keep the pack, and the loop that accumulates it, in memory.
[[gnu::always_inline]] inline void store_xyz(P4 a, Vec3d& out) {
  const V2 lo = __builtin_shufflevector(a.v, a.v, 0, 1);
  std::memcpy(&out, &lo, sizeof lo);
  out.z = a.v[2];
}

}  // namespace zona
