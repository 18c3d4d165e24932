// Four-lane double packs (GCC vector extensions) for the CPU backend's batched loops, and the
// attribute that builds an AVX2 clone beside the baseline one. Each lane performs exactly the
// scalar operations in the scalar order, so packed results are bit-identical to scalar code.
#pragma once

#include <cstring>

#include "engine/vec.h"

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
#define ZONA_P4_OP(op)                                                                   \
  [[gnu::always_inline]] inline P4 operator op(P4 a, P4 b) {                            \
    P4 r;                                                                                \
    r.v = a.v op b.v;                                                                    \
    return r;                                                                            \
  }
ZONA_P4_OP(+)
ZONA_P4_OP(-)
ZONA_P4_OP(*)
ZONA_P4_OP(/)
#undef ZONA_P4_OP
[[gnu::always_inline]] inline P4 operator-(P4 a) {
  P4 r;
  r.v = -a.v;
  return r;
}
[[gnu::always_inline]] inline P4& operator+=(P4& a, P4 b) {
  a.v += b.v;
  return a;
}
[[gnu::always_inline]] inline P4& operator-=(P4& a, P4 b) {
  a.v -= b.v;
  return a;
}

/// (x, y, z, 0) of a Vec3d: a 16-byte and an 8-byte load, never past the vector's end.
[[gnu::always_inline]] inline P4 load_xyz0(const Vec3d& a) { return P4(a.x, a.y, a.z, 0.0); }

/// Stores lanes 0-2 of `a` into a Vec3d (24 bytes, never past its end).
[[gnu::always_inline]] inline void store_xyz(P4 a, Vec3d& out) { std::memcpy(&out, &a.v, 24); }

}  // namespace zona
