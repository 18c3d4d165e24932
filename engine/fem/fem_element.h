// Per-tetrahedron elasticity for the CPU loop and the CUDA kernels alike: shape gradients,
// St Venant-Kirchhoff (SVK), stable neo-Hookean (SNH) and linear energy, nodal forces and 12x12
// stiffness in the deformation-gradient form, and Ladjal et al.'s mass-tensor form (SVK and linear,
// stored or rebuilt in registers).
// (Over 800 lines: every law's element math is here so that the CPU passes and the CUDA kernels
// include one header and cannot drift; split by law if it grows further.)
//
// Every function here is ZONA_HOST_DEVICE, templated on the scalar (float or double), takes
// plain data (four shape gradients and the rest volume, four displacements) and never reads a
// thread index, never allocates and never throws: one element function, two backends.
//
// Conventions (docs/physics.md):
//   grad[j]  gradient of the linear shape function N_j on the rest tetrahedron [1/m]
//   m_j      = 6 V grad N_j, the INWARD normal of the face opposite vertex j, of length twice
//            that face's area [m^2]; Ladjal et al.'s "unit outward normal" is wrong.
//   H        = sum_j u_j grad_j^T, displacement gradient; F = I + H
//   E        = (H + H^T + H^T H) / 2, Green strain (written with H, not F^T F - I, so that small
//            strains keep their digits in float32)
//   S        = lambda tr(E) I + 2 mu E, second Piola-Kirchhoff stress; P = F S
//   W        = V (lambda/2 tr(E)^2 + mu tr(E^2)), element energy [J]
//   f_j      = -dW/du_j = -V P grad_j, elastic force on vertex j [N]
//   K        = d^2 W / du^2 (12 x 12, row 3a+i, column 3b+k), so that df = -K du.
#pragma once

#include <cmath>
#include <cstdint>

#include "engine/core/base.h"
#include "engine/core/vec.h"

namespace zona {

/// Constitutive model of the elastic body.
enum class ConstitutiveModel : int32_t {
  kSvk = 0,     ///< St Venant-Kirchhoff: Green strain, exact under rigid rotation
  kLinear = 1,  ///< small-strain linear elasticity: valid below ~10 % strain, not rotation-free
  /// Stable neo-Hookean (Smith, de Goes and Kim 2018), log-free form: rotation-free, keeps
  /// resisting compression down to and through inversion (J <= 0); gradient form only.
  kStableNeoHookean = 2,
};

/// How the internal force is evaluated; all three give the same numbers to rounding.
enum class Formulation : int32_t {
  kGradient = 0,       ///< F, Green strain, S: 13 numbers per tetrahedron, fewest operations
  kTensorStored = 1,   ///< Ladjal et al.'s method: B, C, D (or K) precomputed and stored per tet
  kTensorRebuilt = 2,  ///< Ladjal et al.'s contraction with the tensors rebuilt from m_j and V
};

/// Per-element health bits (OR-ed into step status by the integrator).
enum ElementHealth : uint32_t {
  kElementInverted = 1u,    ///< det F <= 0 (a failure for SVK; informational for SNH)
  kElementCollapsing = 2u,  ///< smallest principal stretch below the SVK limit 1/sqrt(3)
  kElementClamped = 4u,     ///< the inversion-safe SVK clamped a principal stretch
};

/// SVK's stress-stretch curve peaks at stretch 1/sqrt(3) in compression: below it the element
/// resists less the more it is squeezed, and at stretch 0 (flat) it resists not at all.
inline constexpr double kSvkCollapseStretch = 0.57735026918962576451;

/// Rest geometry of one tetrahedron: the four shape-function gradients [1/m] and the rest
/// volume [m^3]. grad[0] = -(grad[1] + grad[2] + grad[3]) (partition of unity).
template <class T>
struct TetShape {
  Vec3<T> grad[4];
  T volume;
};

/// Shape of the tetrahedron with rest corners x0..x3 [m] (positive orientation expected: the
/// volume comes out negative otherwise and every force with it flips sign).
template <class T>
ZONA_HOST_DEVICE ZONA_INLINE TetShape<T> tet_shape_from_rest(Vec3<T> x0, Vec3<T> x1, Vec3<T> x2,
                                                            Vec3<T> x3) {
  const Vec3<T> e1 = x1 - x0, e2 = x2 - x0, e3 = x3 - x0;
  // Rows of the inverse of [e1 e2 e3]: grad N_1 = (e2 x e3) / det, etc.
  const Vec3<T> c1 = cross(e2, e3), c2 = cross(e3, e1), c3 = cross(e1, e2);
  const T det = dot(e1, c1);  // 6 V
  const T inv = T(1) / det;
  TetShape<T> s;
  s.grad[1] = c1 * inv;
  s.grad[2] = c2 * inv;
  s.grad[3] = c3 * inv;
  s.grad[0] = -(s.grad[1] + s.grad[2] + s.grad[3]);
  s.volume = det / T(6);
  return s;
}

/// Shape from its packed form (three gradients and the volume, 10 numbers: what a bandwidth-bound
/// kernel stores); rebuilds grad[0] exactly as tet_shape_from_rest does.
template <class T>
ZONA_HOST_DEVICE ZONA_INLINE TetShape<T> tet_shape_from_packed(Vec3<T> g1, Vec3<T> g2, Vec3<T> g3,
                                                              T volume) {
  TetShape<T> s;
  s.grad[1] = g1;
  s.grad[2] = g2;
  s.grad[3] = g3;
  s.grad[0] = -(g1 + g2 + g3);
  s.volume = volume;
  return s;
}

/// Converts a shape between scalar types (double precompute, float kernel).
template <class To, class From>
ZONA_HOST_DEVICE ZONA_INLINE TetShape<To> tet_shape_cast(const TetShape<From>& s) {
  TetShape<To> r;
  for (int j = 0; j < 4; ++j) r.grad[j] = vec_cast<To>(s.grad[j]);
  r.volume = static_cast<To>(s.volume);
  return r;
}

/// m_j = 6 V grad N_j [m^2]: the inward face normal opposite vertex j, length twice its area.
template <class T>
ZONA_HOST_DEVICE ZONA_INLINE Vec3<T> tet_face_vector(const TetShape<T>& s, int j) {
  return (T(6) * s.volume) * s.grad[j];
}

/// Displacement gradient from the edge displacements du[i] = u_{i+1} - u_0 (i = 0..2) [-]:
/// H = sum_{j>=1} (u_j - u_0) grad_j^T, equal to sum_j u_j grad_j^T because the gradients sum
/// to zero. A mixed-precision kernel forms the differences in float64 and passes them in float32:
/// a rigid offset of the element (tens of um at cell scale) then costs no digits.
template <class T>
ZONA_HOST_DEVICE ZONA_INLINE Mat3<T> tet_displacement_gradient_from_edges(const TetShape<T>& s,
                                                                         const Vec3<T> du[3]) {
  Mat3<T> h;
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c)
      h.m[r][c] = du[0][r] * s.grad[1][c] + du[1][r] * s.grad[2][c] + du[2][r] * s.grad[3][c];
  return h;
}

/// Displacement gradient H = sum_j u_j grad_j^T [-], of the vertex displacements u [m].
/// Evaluated through the edge differences (exactly zero for a rigid translation).
template <class T>
ZONA_HOST_DEVICE ZONA_INLINE Mat3<T> tet_displacement_gradient(const TetShape<T>& s,
                                                              const Vec3<T> u[4]) {
  const Vec3<T> du[3] = {u[1] - u[0], u[2] - u[0], u[3] - u[0]};
  return tet_displacement_gradient_from_edges(s, du);
}

/// Green strain E = (H + H^T + H^T H) / 2 [-].
template <class T>
ZONA_HOST_DEVICE ZONA_INLINE Mat3<T> green_strain(const Mat3<T>& h) {
  Mat3<T> e;
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c) {
      T hth = h.m[0][r] * h.m[0][c] + h.m[1][r] * h.m[1][c] + h.m[2][r] * h.m[2][c];
      e.m[r][c] = T(0.5) * (h.m[r][c] + h.m[c][r] + hth);
    }
  return e;
}

/// Small strain eps = (H + H^T) / 2 [-].
template <class T>
ZONA_HOST_DEVICE ZONA_INLINE Mat3<T> small_strain(const Mat3<T>& h) {
  Mat3<T> e;
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c) e.m[r][c] = T(0.5) * (h.m[r][c] + h.m[c][r]);
  return e;
}

/// Isotropic stress of a symmetric strain: lambda tr(e) I + 2 mu e [Pa]; returns the energy
/// density lambda/2 tr(e)^2 + mu e:e [J/m^3] through `energy_density`.
template <class T>
ZONA_HOST_DEVICE ZONA_INLINE Mat3<T> isotropic_stress(const Mat3<T>& e, T lambda, T mu,
                                                     T* energy_density) {
  const T tr = trace(e);
  T ee = 0;
  Mat3<T> s;
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c) {
      ee += e.m[r][c] * e.m[r][c];
      s.m[r][c] = T(2) * mu * e.m[r][c];
    }
  for (int r = 0; r < 3; ++r) s.m[r][r] += lambda * tr;
  *energy_density = T(0.5) * lambda * tr * tr + mu * ee;
  return s;
}

/// SVK first Piola-Kirchhoff stress P = (I + H) S [Pa]; energy density [J/m^3] returned.
template <class T>
ZONA_HOST_DEVICE ZONA_INLINE T svk_first_piola(const Mat3<T>& h, T lambda, T mu, Mat3<T>* p) {
  T psi;
  const Mat3<T> s = isotropic_stress(green_strain(h), lambda, mu, &psi);
  // P = S + H S: adding S separately keeps small stresses exact in float32.
  *p = s + h * s;
  return psi;
}

/// Linear (small-strain) stress sigma [Pa], used as P; energy density [J/m^3] returned.
template <class T>
ZONA_HOST_DEVICE ZONA_INLINE T linear_first_piola(const Mat3<T>& h, T lambda, T mu, Mat3<T>* p) {
  T psi;
  *p = isotropic_stress(small_strain(h), lambda, mu, &psi);
  return psi;
}

/// Nodal forces of a uniform stress: f_j = -V P grad_j [N].
template <class T>
ZONA_HOST_DEVICE ZONA_INLINE void tet_forces_from_stress(const TetShape<T>& s, const Mat3<T>& p,
                                                        Vec3<T> f[4]) {
  for (int j = 1; j < 4; ++j) f[j] = -s.volume * (p * s.grad[j]);
  // grad_0 = -(grad_1 + grad_2 + grad_3), so f_0 = -(f_1 + f_2 + f_3): the element's forces sum
  // to zero exactly (no spurious net force from rounding).
  f[0] = -(f[1] + f[2] + f[3]);
}

/// Health of an element from its displacement gradient H and Green strain E (already at hand
/// in the SVK loop): kElementInverted when det F <= 0, kElementCollapsing when the smallest
/// principal stretch is below `collapse_stretch`. C - s^2 I = 2E + (1 - s^2) I is positive
/// definite iff every principal stretch exceeds s (Sylvester's criterion: no eigenvalues).
template <class T>
ZONA_HOST_DEVICE ZONA_INLINE uint32_t tet_health_from_strain(
    const Mat3<T>& h, const Mat3<T>& e, T collapse_stretch = T(kSvkCollapseStretch)) {
  Mat3<T> f = h;
  for (int i = 0; i < 3; ++i) f.m[i][i] += T(1);
  uint32_t bits = 0;
  if (!(determinant(f) > T(0))) bits |= kElementInverted;
  Mat3<T> a = T(2) * e;
  const T shift = T(1) - collapse_stretch * collapse_stretch;
  for (int i = 0; i < 3; ++i) a.m[i][i] += shift;
  const T m1 = a.m[0][0];
  const T m2 = a.m[0][0] * a.m[1][1] - a.m[0][1] * a.m[1][0];
  if (!(m1 > T(0) && m2 > T(0) && determinant(a) > T(0))) bits |= kElementCollapsing;
  return bits;
}

/// Health of an element with displacement gradient H (see tet_health_from_strain).
template <class T>
ZONA_HOST_DEVICE ZONA_INLINE uint32_t tet_health(const Mat3<T>& h,
                                                T collapse_stretch = T(kSvkCollapseStretch)) {
  return tet_health_from_strain(h, green_strain(h), collapse_stretch);
}

/// SVK element: energy [J] returned, forces f [N] written (gradient form).
template <class T>
ZONA_HOST_DEVICE ZONA_INLINE T tet_svk_forces(const TetShape<T>& s, T lambda, T mu,
                                             const Vec3<T> u[4], Vec3<T> f[4]) {
  Mat3<T> p;
  const T psi = svk_first_piola(tet_displacement_gradient(s, u), lambda, mu, &p);
  tet_forces_from_stress(s, p, f);
  return s.volume * psi;
}

/// Linear element: energy [J] returned, forces f = -K u [N] written (gradient form).
template <class T>
ZONA_HOST_DEVICE ZONA_INLINE T tet_linear_forces(const TetShape<T>& s, T lambda, T mu,
                                                const Vec3<T> u[4], Vec3<T> f[4]) {
  Mat3<T> p;
  const T psi = linear_first_piola(tet_displacement_gradient(s, u), lambda, mu, &p);
  tet_forces_from_stress(s, p, f);
  return s.volume * psi;
}

/// Linear element stiffness K [N/m], 12 x 12 row-major in k[144] (row 3a+i, column 3b+k):
/// K_ab = V (lambda g_a g_b^T + mu g_b g_a^T + mu (g_a . g_b) I), Ladjal et al. eq. 3.
template <class T>
ZONA_HOST_DEVICE ZONA_INLINE void tet_linear_stiffness(const TetShape<T>& s, T lambda, T mu,
                                                      T k[144]) {
  for (int a = 0; a < 4; ++a)
    for (int b = 0; b < 4; ++b) {
      const Vec3<T> ga = s.grad[a], gb = s.grad[b];
      const T gab = dot(ga, gb);
      for (int i = 0; i < 3; ++i)
        for (int j = 0; j < 3; ++j)
          k[(3 * a + i) * 12 + 3 * b + j] =
              s.volume * (lambda * ga[i] * gb[j] + mu * gb[i] * ga[j] + (i == j ? mu * gab : T(0)));
    }
}

/// SVK tangent stiffness K = d^2W/du^2 [N/m] at displacements u, 12 x 12 row-major in k[144].
/// Column (a, i) is V dP grad_b with dP = dF S + F dS, dF = e_i grad_a^T.
template <class T>
ZONA_HOST_DEVICE ZONA_INLINE void tet_svk_stiffness(const TetShape<T>& s, T lambda, T mu,
                                                   const Vec3<T> u[4], T k[144]) {
  const Mat3<T> h = tet_displacement_gradient(s, u);
  Mat3<T> f = h;
  for (int i = 0; i < 3; ++i) f.m[i][i] += T(1);
  T psi;
  const Mat3<T> stress = isotropic_stress(green_strain(h), lambda, mu, &psi);
  for (int a = 0; a < 4; ++a)
    for (int i = 0; i < 3; ++i) {
      // dF = e_i g_a^T; dE = sym(F^T dF) with (F^T dF)_rc = F_ir g_a,c.
      Mat3<T> de;
      for (int r = 0; r < 3; ++r)
        for (int c = 0; c < 3; ++c)
          de.m[r][c] = T(0.5) * (f.m[i][r] * s.grad[a][c] + f.m[i][c] * s.grad[a][r]);
      T dpsi;
      const Mat3<T> ds = isotropic_stress(de, lambda, mu, &dpsi);
      Mat3<T> dp = f * ds;
      for (int c = 0; c < 3; ++c)
        dp.m[i][c] += dot(s.grad[a], Vec3<T>{stress.m[0][c], stress.m[1][c], stress.m[2][c]});
      for (int b = 0; b < 4; ++b) {
        const Vec3<T> col = s.volume * (dp * s.grad[b]);
        for (int j = 0; j < 3; ++j) k[(3 * b + j) * 12 + 3 * a + i] = col[j];
      }
    }
}

// ---------------------------------------------------------------------------------------------
// Stable neo-Hookean (SNH; Smith, de Goes and Kim, "Stable Neo-Hookean Flesh Simulation", ACM
// TOG 2018), in the log-free form of Kim and Eberle's "Dynamic Deformables" course (2020):
//   Psi = mu_s/2 (I_C - 3) - mu_s (J - 1) + lambda_s/2 (J - 1)^2                   [J/m^3]
// with I_C = |F|^2 and J = det F. It equals the paper's mu_s/2 (I_C - 3) + lambda_s/2 (J - a)^2,
// a = 1 + mu_s / lambda_s, less its rest value mu_s^2 / (2 lambda_s) (a constant: same forces),
// so that the rest state has zero energy. The paper's -mu/2 log(I_C + 1) term is left out, as in
// the course and its code: it was added for the collapse of an element to a point (I_C -> 0), and
// it would cost a log and a division per element.
//
// Constants: this form linearises at F = I to mu_s eps:eps + (lambda_s - mu_s)/2 tr(eps)^2, so
// linear elasticity with the material's (lambda, mu) needs mu_s = mu, lambda_s = lambda + mu
// (snh_lambda). The paper's mu_s = 4/3 mu, lambda_s = lambda + 5/6 mu belong to the form WITH
// the log term (and a = 1 + 3 mu_s / (4 lambda_s)); with this form they would not match.
// The functions below take the material's (lambda, mu) and form lambda_s themselves.
//
// P = mu_s (F - cof F) + lambda_s (J - 1) cof F, cof F = dJ/dF = J F^-T. Everything is formed
// from H = F - I without subtracting numbers of order one, so that small strains keep their
// digits in float32 (as green_strain does for SVK):
//   cof(I + H) = I + tr(H) I - H^T + cof(H)      (cof is quadratic: exact)
//   J - 1      = tr(H) + i2(H) + det(H)          (i2: sum of the principal 2x2 minors of H)
//   F - cof F  = H + H^T - tr(H) I - cof(H)
//   Psi        = mu_s (|H|^2/2 - i2(H) - det H) + lambda_s/2 (J - 1)^2
// Under compression the volumetric term lambda_s (J - 1) cof F keeps pushing back as J -> 0 and
// past it (J < 0: -mu_s (J - 1) and (J - 1)^2 both keep growing), unlike SVK whose resistance
// peaks at stretch 1/sqrt(3) and vanishes when flat: no clamp, no eigen-decomposition.

/// SNH's volumetric constant lambda_s = lambda + mu [Pa] from the material's Lame constants
/// (mu_s = mu): the law then linearises to linear elasticity with (lambda, mu).
template <class T>
ZONA_HOST_DEVICE ZONA_INLINE constexpr T snh_lambda(T lambda, T mu) {
  return lambda + mu;
}

/// Cofactor matrix cof(A) = det(A) A^-T (defined for singular A too): cof(A)_ij =
/// A_{i+1,j+1} A_{i+2,j+2} - A_{i+1,j+2} A_{i+2,j+1}, indices mod 3.
template <class T>
ZONA_HOST_DEVICE ZONA_INLINE Mat3<T> cofactor(const Mat3<T>& a) {
  Mat3<T> c;
  for (int i = 0; i < 3; ++i) {
    const int i1 = (i + 1) % 3, i2 = (i + 2) % 3;
    for (int j = 0; j < 3; ++j) {
      const int j1 = (j + 1) % 3, j2 = (j + 2) % 3;
      c.m[i][j] = a.m[i1][j1] * a.m[i2][j2] - a.m[i1][j2] * a.m[i2][j1];
    }
  }
  return c;
}

/// Differential of the cofactor: d cof(A)[B] = cof(A + B) - cof(A) - cof(B) (cof is quadratic,
/// so this is exact and bilinear in A and B).
template <class T>
ZONA_HOST_DEVICE ZONA_INLINE Mat3<T> cofactor_differential(const Mat3<T>& a, const Mat3<T>& b) {
  Mat3<T> c;
  for (int i = 0; i < 3; ++i) {
    const int i1 = (i + 1) % 3, i2 = (i + 2) % 3;
    for (int j = 0; j < 3; ++j) {
      const int j1 = (j + 1) % 3, j2 = (j + 2) % 3;
      c.m[i][j] = a.m[i1][j1] * b.m[i2][j2] + b.m[i1][j1] * a.m[i2][j2] -
                  a.m[i1][j2] * b.m[i2][j1] - b.m[i1][j2] * a.m[i2][j1];
    }
  }
  return c;
}

/// Frobenius product A : B.
template <class T>
ZONA_HOST_DEVICE ZONA_INLINE T frobenius_dot(const Mat3<T>& a, const Mat3<T>& b) {
  T s = 0;
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c) s += a.m[r][c] * b.m[r][c];
  return s;
}

/// Second principal invariant i2(H): the sum of the principal 2x2 minors of H.
template <class T>
ZONA_HOST_DEVICE ZONA_INLINE T principal_minor_sum(const Mat3<T>& h) {
  return (h.m[0][0] * h.m[1][1] - h.m[0][1] * h.m[1][0]) +
         (h.m[0][0] * h.m[2][2] - h.m[0][2] * h.m[2][0]) +
         (h.m[1][1] * h.m[2][2] - h.m[1][2] * h.m[2][1]);
}

/// J - 1 = det(I + H) - 1 [-] from H, without the cancellation of det(F) - 1 (see above).
template <class T>
ZONA_HOST_DEVICE ZONA_INLINE T snh_volume_change(const Mat3<T>& h) {
  return trace(h) + principal_minor_sum(h) + determinant(h);
}

/// cof(I + H) [-] from H: I + tr(H) I - H^T + cof(H).
template <class T>
ZONA_HOST_DEVICE ZONA_INLINE Mat3<T> snh_cofactor_of_f(const Mat3<T>& h) {
  Mat3<T> c = cofactor(h);
  const T tr = trace(h);
  for (int r = 0; r < 3; ++r) {
    for (int q = 0; q < 3; ++q) c.m[r][q] -= h.m[q][r];
    c.m[r][r] += T(1) + tr;
  }
  return c;
}

/// The SNH stress with the volumetric coefficient and an added pressure given: P = mu (H + H^T -
/// tr(H) I - cof H) + k (I + tr(H) I - H^T + cof H), k = lambda_e (J - 1) + pressure, written to
/// *p; the energy density mu (|H|^2 / 2 - I2 - det H) + lambda_e (J - 1)^2 / 2 [J/m^3]
/// returned (the pressure's energy is its caller's); J - 1 [-] to *j_minus_one.
template <class T>
ZONA_HOST_DEVICE ZONA_INLINE T snh_first_piola_with(const Mat3<T>& h, T mu, T lambda_e,
                                                    T pressure, Mat3<T>* p, T* j_minus_one) {
  const Mat3<T> ch = cofactor(h);
  const T tr = trace(h);
  T hh = 0;
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c) hh += h.m[r][c] * h.m[r][c];
  const T i2 = principal_minor_sum(h);
  const T det_h = determinant(h);
  const T jm1 = tr + i2 + det_h;
  const T k = lambda_e * jm1 + pressure;
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c)
      p->m[r][c] = mu * (h.m[r][c] + h.m[c][r] - ch.m[r][c]) + k * (ch.m[r][c] - h.m[c][r]);
  for (int r = 0; r < 3; ++r) p->m[r][r] += k * (T(1) + tr) - mu * tr;
  *j_minus_one = jm1;
  return mu * (T(0.5) * hh - i2 - det_h) + T(0.5) * lambda_e * jm1 * jm1;
}

/// SNH first Piola-Kirchhoff stress P [Pa] at displacement gradient H, written to *p; energy
/// density Psi [J/m^3] returned; J - 1 [-] to *j_minus_one. lambda, mu: the material's Lame
/// constants [Pa] (the law's lambda_s = snh_lambda(lambda, mu) is formed here). Defined for
/// every H, inverted (J <= 0) included.
template <class T>
ZONA_HOST_DEVICE ZONA_INLINE T snh_first_piola(const Mat3<T>& h, T lambda, T mu, Mat3<T>* p,
                                               T* j_minus_one) {
  return snh_first_piola_with(h, mu, snh_lambda(lambda, mu), T(0.0), p, j_minus_one);
}

/// SNH with its volumetric term taken at the vertices (nodal pressure; ModelDesc::
/// nodal_pressure): the element keeps Psi_e = mu/2 (I_C - 3) - mu (J - 1) + mu/2 (J - 1)^2
/// (the law with lambda_s = mu, which linearises to mu eps:eps: positive semi-definite at rest,
/// so no element mode relies on the nodal term for stability), and the rest of the volumetric
/// energy, lambda/2 (Jbar - 1)^2 per unit volume with Jbar averaged at each vertex, enters
/// through `pressure`, the mean over the element's corners of lambda_v (Jbar_v - 1) [Pa]:
/// P = mu (F - cof F) + (mu (J - 1) + pressure) cof F, written to *p. The element part of the
/// energy density [J/m^3] is returned, J - 1 to *j_minus_one. At a uniform J (Jbar = J) this is
/// snh_first_piola exactly (lambda_s = lambda + mu).
template <class T>
ZONA_HOST_DEVICE ZONA_INLINE T snh_first_piola_nodal(const Mat3<T>& h, T mu, T pressure,
                                                     Mat3<T>* p, T* j_minus_one) {
  return snh_first_piola_with(h, mu, mu, pressure, p, j_minus_one);
}

/// SNH stress differential dP = (d^2 Psi / dF^2) : dF [Pa] at displacement gradient H, for a
/// change dF of the deformation gradient [-]:
///   dP = mu_s (dF - dcof) + lambda_s ((cof F : dF) cof F + (J - 1) dcof),  dcof = d cof(F)[dF].
template <class T>
ZONA_HOST_DEVICE ZONA_INLINE Mat3<T> snh_stress_differential(const Mat3<T>& h, T lambda, T mu,
                                                             const Mat3<T>& df) {
  const T lam = snh_lambda(lambda, mu);
  Mat3<T> f = h;
  for (int i = 0; i < 3; ++i) f.m[i][i] += T(1);
  const Mat3<T> cof = snh_cofactor_of_f(h);
  const Mat3<T> dcof = cofactor_differential(f, df);
  const T jm1 = snh_volume_change(h);
  const T dj = frobenius_dot(cof, df);
  Mat3<T> dp;
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c)
      dp.m[r][c] = mu * (df.m[r][c] - dcof.m[r][c]) + lam * (dj * cof.m[r][c] + jm1 * dcof.m[r][c]);
  return dp;
}

/// SNH element: energy [J] returned, forces f [N] written (gradient form), health in *bits:
/// kElementInverted when J <= 0 (informational: the law stays defined and pushes back).
/// lambda, mu: the material's Lame constants [Pa].
template <class T>
ZONA_HOST_DEVICE ZONA_INLINE T tet_snh_forces(const TetShape<T>& s, T lambda, T mu,
                                              const Vec3<T> u[4], Vec3<T> f[4], uint32_t* bits) {
  Mat3<T> p;
  T jm1;
  const T psi = snh_first_piola(tet_displacement_gradient(s, u), lambda, mu, &p, &jm1);
  *bits = jm1 > T(-1) ? 0u : uint32_t{kElementInverted};  // J > 0; NaN counts as inverted
  tet_forces_from_stress(s, p, f);
  return s.volume * psi;
}

/// SNH tangent stiffness K = d^2W/du^2 [N/m] at displacements u, 12 x 12 row-major in k[144]
/// (row 3a+i, column 3b+k). Column (a, i) is V dP grad_b with dP = snh_stress_differential at
/// dF = e_i grad_a^T. Not projected to positive definite: away from rest it can be indefinite
/// (Smith et al. give its eigenvalues); the explicit step does not need it, an implicit solver
/// would.
template <class T>
ZONA_HOST_DEVICE ZONA_INLINE void tet_snh_stiffness(const TetShape<T>& s, T lambda, T mu,
                                                    const Vec3<T> u[4], T k[144]) {
  const Mat3<T> h = tet_displacement_gradient(s, u);
  for (int a = 0; a < 4; ++a)
    for (int i = 0; i < 3; ++i) {
      Mat3<T> df = Mat3<T>::zero();
      for (int c = 0; c < 3; ++c) df.m[i][c] = s.grad[a][c];
      const Mat3<T> dp = snh_stress_differential(h, lambda, mu, df);
      for (int b = 0; b < 4; ++b) {
        const Vec3<T> col = s.volume * (dp * s.grad[b]);
        for (int j = 0; j < 3; ++j) k[(3 * b + j) * 12 + 3 * a + i] = col[j];
      }
    }
}

// ---------------------------------------------------------------------------------------------
// Stiffening of a deformed element (the dynamic mass scaling's measure)
//
// An explicit step is stable for an element while omega_e dt < 2; at build the step is chosen
// from the rest stiffness (Model::dt_critical). Under a needle tip the elements are flattened
// and stretched together (principal stretches 0.02 / 3 / 6 measured at 10k vertices) and their
// tangent grows two orders of magnitude. tet_stiffening() estimates that growth: the ratio of a
// bound on the element tangent's largest eigenvalue at F = I + H to the same bound at rest,
//   lambda_max(K_e) <= V (lambda_s sum_j |cof(F) g_j|^2 + c(F) sum_j |g_j|^2)    (SNH)
// where the first term is the volumetric rank-one part lambda_s cof(F) (x) cof(F), maximised
// exactly over corner displacements, and c(F) = mu (1 + 2|F|) + 2 lambda_s |J - 1| |F| bounds the
// deviatoric part and the (J - 1) d cof term (|d cof(F)[dF]| <= 2 |F| |dF|). For SVK,
// |dP| <= (|S| + (sqrt(3) lambda + 2 mu) |F|^2) |dF|. The linear law does not stiffen (1).
// Norms are Frobenius. The ratio is 1 at rest and not below 1 (a softened element keeps the
// mass it has). It is an estimate for raising masses with a safety factor, not a proof.

/// The laws tet_stiffening() knows.
enum class StiffeningLaw : int { kLinear = 0, kSvk = 1, kStableNeoHookean = 2 };

/// Growth factor (>= 1) of the element's largest stiffness eigenvalue at displacement gradient
/// h against rest, for the law with the material's Lame constants (lambda, mu) [Pa].
template <class T>
ZONA_HOST_DEVICE ZONA_INLINE T tet_stiffening(const TetShape<T>& s, const Mat3<T>& h, T lambda,
                                              T mu, StiffeningLaw law) {
  if (law == StiffeningLaw::kLinear) return T(1);
  // |F|^2 = 3 + 2 tr H + |H|^2, formed without cancellation.
  const T f_sq = T(3) + T(2) * trace(h) + frobenius_dot(h, h);
  const T f_norm = std::sqrt(f_sq > T(0) ? f_sq : T(0));
  T ratio;
  if (law == StiffeningLaw::kSvk) {
    const Mat3<T> e = green_strain(h);
    const T tr = trace(e);
    Mat3<T> stress = (T(2) * mu) * e;
    for (int i = 0; i < 3; ++i) stress.m[i][i] += lambda * tr;
    const T c = T(1.7320508075688772) * lambda + T(2) * mu;
    ratio = (std::sqrt(frobenius_dot(stress, stress)) / c + f_sq) / T(3);
  } else {
    const T lam = snh_lambda(lambda, mu);
    const Mat3<T> cof = snh_cofactor_of_f(h);
    T cof_g = 0, g_sq = 0;
    for (int j = 0; j < 4; ++j) {
      const Vec3<T> cg = cof * s.grad[j];
      cof_g += dot(cg, cg);
      g_sq += dot(s.grad[j], s.grad[j]);
    }
    const T j_minus_one = snh_volume_change(h);
    const T abs_j = j_minus_one < T(0) ? -j_minus_one : j_minus_one;
    const T deformed = lam * (g_sq > T(0) ? cof_g / g_sq : T(1)) + mu * (T(1) + T(2) * f_norm) +
                       T(2) * lam * abs_j * f_norm;
    const T rest = lam + mu * (T(1) + T(2) * T(1.7320508075688772));
    ratio = deformed / rest;
  }
  return ratio > T(1) ? ratio : T(1);
}

// ---------------------------------------------------------------------------------------------
// Mass-tensor form (Ladjal et al. eqs. 3-6; docs/physics.md section 2). Per tetrahedron:
//   B_jk   = (lambda m_j m_k^T + mu m_k m_j^T + mu (m_j.m_k) I) / (72 V)      (K = 2 B)
//   C_jkl  = (lambda (m_j.m_k) m_l + mu (m_k.m_l) m_j + mu (m_j.m_l) m_k) / (432 V^2)
//   D_jklm = (lambda (m_j.m_k)(m_l.m_m) + 2 mu (m_j.m_l)(m_k.m_m)) / (10368 V^3)
//   W = sum u_j^T B_jk u_k + sum (u_j.u_k)(C_jkl.u_l) + sum D_jklm (u_j.u_k)(u_l.u_m)
// Storage order: B[(4j+k)*9 + 3r+c], C[((4j+k)*4+l)*3 + r], D[((4j+k)*4+l)*4+m].

inline constexpr int kTensorBSize = 16 * 9;    ///< numbers in B (or K) per tetrahedron
inline constexpr int kTensorCSize = 64 * 3;    ///< numbers in C per tetrahedron
inline constexpr int kTensorDSize = 256;       ///< numbers in D per tetrahedron
inline constexpr int kSvkTensorSize = kTensorBSize + kTensorCSize + kTensorDSize;  ///< 592

/// Builds the SVK mass tensors of one tetrahedron into t[kSvkTensorSize] (B, then C, then D).
template <class T>
ZONA_HOST_DEVICE ZONA_INLINE void svk_mass_tensors(const TetShape<T>& s, T lambda, T mu, T* t) {
  Vec3<T> m[4];
  for (int j = 0; j < 4; ++j) m[j] = tet_face_vector(s, j);
  T mm[4][4];
  for (int j = 0; j < 4; ++j)
    for (int k = 0; k < 4; ++k) mm[j][k] = dot(m[j], m[k]);
  const T v = s.volume;
  const T s2 = T(1) / (T(72) * v), s3 = T(1) / (T(432) * v * v),
          s4 = T(1) / (T(10368) * v * v * v);
  T* b = t;
  T* c = t + kTensorBSize;
  T* d = c + kTensorCSize;
  for (int j = 0; j < 4; ++j)
    for (int k = 0; k < 4; ++k) {
      for (int r = 0; r < 3; ++r)
        for (int q = 0; q < 3; ++q)
          b[(4 * j + k) * 9 + 3 * r + q] =
              s2 * (lambda * m[j][r] * m[k][q] + mu * m[k][r] * m[j][q] +
                    (r == q ? mu * mm[j][k] : T(0)));
      for (int l = 0; l < 4; ++l) {
        const Vec3<T> cv = s3 * (lambda * mm[j][k] * m[l] + mu * mm[k][l] * m[j] +
                                 mu * mm[j][l] * m[k]);
        for (int r = 0; r < 3; ++r) c[((4 * j + k) * 4 + l) * 3 + r] = cv[r];
        for (int q = 0; q < 4; ++q)
          d[((4 * j + k) * 4 + l) * 4 + q] =
              s4 * (lambda * mm[j][k] * mm[l][q] + T(2) * mu * mm[j][l] * mm[k][q]);
      }
    }
}

/// Builds the linear mass tensor K_jk = 2 B_jk of one tetrahedron into k[kTensorBSize].
template <class T>
ZONA_HOST_DEVICE ZONA_INLINE void linear_mass_tensor(const TetShape<T>& s, T lambda, T mu, T* k) {
  Vec3<T> m[4];
  for (int j = 0; j < 4; ++j) m[j] = tet_face_vector(s, j);
  const T s1 = T(1) / (T(36) * s.volume);
  for (int j = 0; j < 4; ++j)
    for (int q = 0; q < 4; ++q) {
      const T mjq = dot(m[j], m[q]);
      for (int r = 0; r < 3; ++r)
        for (int c = 0; c < 3; ++c)
          k[(4 * j + q) * 9 + 3 * r + c] =
              s1 * (lambda * m[j][r] * m[q][c] + mu * m[q][r] * m[j][c] +
                    (r == c ? mu * mjq : T(0)));
    }
}

/// Linear mass-tensor force f_j = -sum_k K_jk u_k [N] (Ladjal et al. eq. 4); energy u^T K u / 2 [J].
template <class T>
ZONA_HOST_DEVICE ZONA_INLINE T tet_linear_forces_tensor(const T* k, const Vec3<T> u[4],
                                                       Vec3<T> f[4]) {
  T w = 0;
  for (int j = 0; j < 4; ++j) {
    Vec3<T> ku{0, 0, 0};
    for (int q = 0; q < 4; ++q) {
      const T* kb = k + (4 * j + q) * 9;
      ku += Vec3<T>{kb[0] * u[q].x + kb[1] * u[q].y + kb[2] * u[q].z,
                    kb[3] * u[q].x + kb[4] * u[q].y + kb[5] * u[q].z,
                    kb[6] * u[q].x + kb[7] * u[q].y + kb[8] * u[q].z};
    }
    f[j] = -ku;
    w += T(0.5) * dot(u[j], ku);
  }
  return w;
}

/// The SVK mass-tensor contraction (Ladjal et al. eqs. 3-6; docs/physics.md section 2) with the tensors
/// given by a source: src.b(j, k, &bu, &btu) gives B_jk u_k and B_jk^T u_j, src.c(j, k, l) the
/// vector C_jkl, src.d(j, k, l, m) the number D_jklm. Forces f[4] [N] written, energy [J]
/// returned. The stored tensors (SvkStoredTensors) and the ones rebuilt in registers from the
/// face vectors (SvkRebuiltTensors) share it: one contraction, two sources.
template <class T, class Source>
ZONA_HOST_DEVICE ZONA_INLINE T svk_tensor_contraction(const Source& src, const Vec3<T> u[4],
                                                     Vec3<T> f[4]) {
  T uu[4][4];  // u_j . u_k
  for (int j = 0; j < 4; ++j)
    for (int k = 0; k < 4; ++k) uu[j][k] = dot(u[j], u[k]);
  Vec3<T> g[4] = {{0, 0, 0}, {0, 0, 0}, {0, 0, 0}, {0, 0, 0}};  // dW/du_p
  T w2 = 0, w3 = 0, w4 = 0;
  // Quadratic: d/du_p sum u_j^T B_jk u_k = sum_k B_pk u_k + sum_j B_jp^T u_j.
  for (int j = 0; j < 4; ++j)
    for (int k = 0; k < 4; ++k) {
      Vec3<T> bu{0, 0, 0}, btu{0, 0, 0};
      src.b(j, k, &bu, &btu);
      w2 += dot(u[j], bu);
      g[j] += bu;
      g[k] += btu;
    }
  // Cubic: W3 = sum P_jk c_jk with c_jk = sum_l C_jkl.u_l; dW3/du_p = sum_k (c_pk + c_kp) u_k
  // + sum_jk P_jk C_jkp.
  T cjk[4][4];
  for (int j = 0; j < 4; ++j)
    for (int k = 0; k < 4; ++k) {
      T acc = 0;
      for (int l = 0; l < 4; ++l) {
        const Vec3<T> cv = src.c(j, k, l);
        acc += dot(cv, u[l]);
        g[l] += uu[j][k] * cv;
      }
      cjk[j][k] = acc;
      w3 += uu[j][k] * acc;
    }
  // Quartic: W4 = sum D_jklm P_jk P_lm; with G_jk = sum_lm (D_jklm + D_lmjk) P_lm,
  // dW4/du_p = sum_k (G_pk + G_kp) u_k.
  T gjk[4][4];
  for (int j = 0; j < 4; ++j)
    for (int k = 0; k < 4; ++k) gjk[j][k] = 0;
  for (int j = 0; j < 4; ++j)
    for (int k = 0; k < 4; ++k)
      for (int l = 0; l < 4; ++l)
        for (int m = 0; m < 4; ++m) {
          const T dv = src.d(j, k, l, m);
          w4 += dv * uu[j][k] * uu[l][m];
          gjk[j][k] += dv * uu[l][m];
          gjk[l][m] += dv * uu[j][k];
        }
  for (int p = 0; p < 4; ++p)
    for (int k = 0; k < 4; ++k)
      g[p] += (cjk[p][k] + cjk[k][p] + gjk[p][k] + gjk[k][p]) * u[k];
  for (int p = 0; p < 4; ++p) f[p] = -g[p];
  return w2 + w3 + w4;
}

/// Stored SVK tensors (svk_mass_tensors' layout) as a contraction source.
template <class T>
struct SvkStoredTensors {
  const T* t;           ///< B, then C, then D (kSvkTensorSize numbers)
  const Vec3<T>* u;     ///< the corner displacements (for B u)
  ZONA_HOST_DEVICE void b(int j, int k, Vec3<T>* bu, Vec3<T>* btu) const {
    const T* bb = t + (4 * j + k) * 9;
    *bu = Vec3<T>{bb[0] * u[k].x + bb[1] * u[k].y + bb[2] * u[k].z,
                  bb[3] * u[k].x + bb[4] * u[k].y + bb[5] * u[k].z,
                  bb[6] * u[k].x + bb[7] * u[k].y + bb[8] * u[k].z};
    *btu = Vec3<T>{bb[0] * u[j].x + bb[3] * u[j].y + bb[6] * u[j].z,
                   bb[1] * u[j].x + bb[4] * u[j].y + bb[7] * u[j].z,
                   bb[2] * u[j].x + bb[5] * u[j].y + bb[8] * u[j].z};
  }
  ZONA_HOST_DEVICE Vec3<T> c(int j, int k, int l) const {
    const T* cc = t + kTensorBSize + ((4 * j + k) * 4 + l) * 3;
    return Vec3<T>{cc[0], cc[1], cc[2]};
  }
  ZONA_HOST_DEVICE T d(int j, int k, int l, int m) const {
    return t[kTensorBSize + kTensorCSize + ((4 * j + k) * 4 + l) * 4 + m];
  }
};

/// SVK mass-tensor force f_p = -dW/du_p [N] from stored tensors t[kSvkTensorSize] (Ladjal et al.
/// eqs. 5-6, with the derivative taken of the energy as written, no symmetry assumed); energy
/// [J] returned.
template <class T>
ZONA_HOST_DEVICE ZONA_INLINE T tet_svk_forces_tensor(const T* t, const Vec3<T> u[4],
                                                    Vec3<T> f[4]) {
  return svk_tensor_contraction(SvkStoredTensors<T>{t, u}, u, f);
}

/// Linear mass-tensor force with K rebuilt in registers from m_j and V (no stored tensors).
template <class T>
ZONA_HOST_DEVICE ZONA_INLINE T tet_linear_forces_rebuilt(const TetShape<T>& s, T lambda, T mu,
                                                        const Vec3<T> u[4], Vec3<T> f[4]) {
  Vec3<T> m[4];
  for (int j = 0; j < 4; ++j) m[j] = tet_face_vector(s, j);
  const T s1 = T(1) / (T(36) * s.volume);
  T w = 0;
  for (int j = 0; j < 4; ++j) {
    // K_jk u_k = (lambda m_j (m_k.u_k) + mu m_k (m_j.u_k) + mu (m_j.m_k) u_k) / (36 V)
    Vec3<T> ku{0, 0, 0};
    for (int k = 0; k < 4; ++k)
      ku += (lambda * dot(m[k], u[k])) * m[j] + (mu * dot(m[j], u[k])) * m[k] +
            (mu * dot(m[j], m[k])) * u[k];
    ku = s1 * ku;
    f[j] = -ku;
    w += T(0.5) * dot(u[j], ku);
  }
  return w;
}

/// SVK tensors rebuilt in registers from the face vectors m_j and the volume V, as a
/// contraction source (the same numbers svk_mass_tensors stores, formed where they are used).
template <class T>
struct SvkRebuiltTensors {
  Vec3<T> m[4];
  const Vec3<T>* u;
  T lambda, mu, s2, s3, s4;
  T mm[4][4], mu_[4][4];  // m_j.m_k, m_j.u_k
  ZONA_HOST_DEVICE SvkRebuiltTensors(const TetShape<T>& s, T lambda_, T mu_in, const Vec3<T>* u_)
      : u(u_), lambda(lambda_), mu(mu_in) {
    for (int j = 0; j < 4; ++j) m[j] = tet_face_vector(s, j);
    const T v = s.volume;
    s2 = T(1) / (T(72) * v);
    s3 = T(1) / (T(432) * v * v);
    s4 = T(1) / (T(10368) * v * v * v);
    for (int j = 0; j < 4; ++j)
      for (int k = 0; k < 4; ++k) {
        mm[j][k] = dot(m[j], m[k]);
        mu_[j][k] = dot(m[j], u[k]);
      }
  }
  ZONA_HOST_DEVICE void b(int j, int k, Vec3<T>* bu, Vec3<T>* btu) const {
    *bu = s2 * ((lambda * mu_[k][k]) * m[j] + (mu * mu_[j][k]) * m[k] + (mu * mm[j][k]) * u[k]);
    *btu = s2 * ((lambda * mu_[j][j]) * m[k] + (mu * mu_[k][j]) * m[j] + (mu * mm[j][k]) * u[j]);
  }
  ZONA_HOST_DEVICE Vec3<T> c(int j, int k, int l) const {
    return s3 * ((lambda * mm[j][k]) * m[l] + (mu * mm[k][l]) * m[j] + (mu * mm[j][l]) * m[k]);
  }
  ZONA_HOST_DEVICE T d(int j, int k, int l, int q) const {
    return s4 * (lambda * mm[j][k] * mm[l][q] + T(2) * mu * mm[j][l] * mm[k][q]);
  }
};

/// SVK mass-tensor force with B, C, D rebuilt in registers from m_j and V, contracted exactly as
/// tet_svk_forces_tensor contracts the stored ones (svk_tensor_contraction); energy [J] returned.
template <class T>
ZONA_HOST_DEVICE ZONA_INLINE T tet_svk_forces_rebuilt(const TetShape<T>& s, T lambda, T mu,
                                                     const Vec3<T> u[4], Vec3<T> f[4]) {
  return svk_tensor_contraction(SvkRebuiltTensors<T>(s, lambda, mu, u), u, f);
}

// ---------------------------------------------------------------------------------------------
// Inversion remedy: inversion-safe SVK by principal-stretch clamping (Irving, Teran and Fedkiw,
// "Invertible finite elements", 2004). F = U diag(s) V^T with U, V rotations and s_3 signed
// (negative when the element is inverted); each s_i is clamped to at least `stretch_min` and
// the SVK stress evaluated there: P = U diag(P_i(s_hat)) V^T. Where no stretch is clamped the
// result equals svk_first_piola; below the clamp the element keeps SVK's peak resistance instead
// of losing it, and an inverted element is pushed back out.

/// Eigen-decomposition of a symmetric 3x3 matrix by cyclic Jacobi rotations: eigenvalues in
/// `eval`, eigenvectors in the columns of `evec`. Branch-light, bounded work (at most 8 sweeps).
template <class T>
ZONA_HOST_DEVICE ZONA_INLINE void symmetric_eigen3(Mat3<T> a, T eval[3], Mat3<T>* evec) {
  Mat3<T> v = Mat3<T>::identity();
  for (int sweep = 0; sweep < 8; ++sweep) {
    const T off = a.m[0][1] * a.m[0][1] + a.m[0][2] * a.m[0][2] + a.m[1][2] * a.m[1][2];
    const T diag = a.m[0][0] * a.m[0][0] + a.m[1][1] * a.m[1][1] + a.m[2][2] * a.m[2][2];
    if (!(off > T(1e-30) * diag)) break;
    for (int pq = 0; pq < 3; ++pq) {
      const int p = pq == 2 ? 1 : 0;
      const int q = pq == 0 ? 1 : 2;
      const T apq = a.m[p][q];
      if (apq == T(0)) continue;
      const T theta = (a.m[q][q] - a.m[p][p]) / (T(2) * apq);
      const T at = theta < T(0) ? -theta : theta;
      // tan of the rotation angle, the smaller root; the large-theta branch avoids overflow.
      T t = at > T(1e15) ? T(0.5) / at : T(1) / (at + std::sqrt(theta * theta + T(1)));
      if (theta < T(0)) t = -t;
      const T c = T(1) / std::sqrt(t * t + T(1));
      const T sn = t * c;
      a.m[p][p] -= t * apq;
      a.m[q][q] += t * apq;
      a.m[p][q] = a.m[q][p] = T(0);
      const int r = 3 - p - q;
      const T arp = a.m[r][p], arq = a.m[r][q];
      a.m[r][p] = a.m[p][r] = c * arp - sn * arq;
      a.m[r][q] = a.m[q][r] = sn * arp + c * arq;
      for (int i = 0; i < 3; ++i) {
        const T vip = v.m[i][p], viq = v.m[i][q];
        v.m[i][p] = c * vip - sn * viq;
        v.m[i][q] = sn * vip + c * viq;
      }
    }
  }
  for (int i = 0; i < 3; ++i) eval[i] = a.m[i][i];
  *evec = v;
}

/// The rotation-variant SVD of F = I + h: F = U diag(sigma) V^T with U and V rotations (their
/// columns `uc`, `vc`) and sigma_3 signed (negative when the element is inverted), sigma_1 >=
/// sigma_2 >= |sigma_3| up to the sign. V from the eigenvectors of F^T F, U by Gram-Schmidt on
/// F v1, F v2 (robust when a sigma is near zero), sigma_i = u_i . F v_i.
template <class T>
ZONA_HOST_DEVICE ZONA_INLINE void rotation_svd3(const Mat3<T>& h, Vec3<T> uc[3], T sig[3],
                                                Vec3<T> vc[3]) {
  Mat3<T> f = h;
  for (int i = 0; i < 3; ++i) f.m[i][i] += T(1);
  T ev[3];
  Mat3<T> v;
  symmetric_eigen3(transpose(f) * f, ev, &v);
  // Sort descending so that the smallest (possibly negative) stretch is last.
  int o[3] = {0, 1, 2};
  for (int i = 0; i < 2; ++i)
    for (int j = 0; j < 2 - i; ++j)
      if (ev[o[j]] < ev[o[j + 1]]) {
        const int tmp = o[j];
        o[j] = o[j + 1];
        o[j + 1] = tmp;
      }
  for (int i = 0; i < 3; ++i) vc[i] = Vec3<T>{v.m[0][o[i]], v.m[1][o[i]], v.m[2][o[i]]};
  // V must be a rotation; flipping v3 moves the sign of det F onto s3 below.
  if (dot(vc[0], cross(vc[1], vc[2])) < T(0)) vc[2] = -vc[2];
  Vec3<T> fv[3];
  for (int i = 0; i < 3; ++i) fv[i] = f * vc[i];
  // U by Gram-Schmidt on F v1, F v2 (robust when an s_i is near zero); u3 completes a rotation.
  const T n0 = norm(fv[0]);
  uc[0] = n0 > T(0) ? fv[0] / n0 : Vec3<T>{1, 0, 0};
  Vec3<T> w = fv[1] - dot(uc[0], fv[1]) * uc[0];
  T n1 = norm(w);
  if (!(n1 > T(1e-7) * (n0 > T(0) ? n0 : T(1)))) {
    // F v2 vanishes: any unit vector orthogonal to u1 will do.
    w = cross(uc[0], (uc[0].x < T(0.5) && uc[0].x > T(-0.5)) ? Vec3<T>{1, 0, 0}
                                                             : Vec3<T>{0, 1, 0});
    n1 = norm(w);
  }
  uc[1] = w / n1;
  uc[2] = cross(uc[0], uc[1]);
  for (int i = 0; i < 3; ++i) sig[i] = dot(uc[i], fv[i]);
}

/// Inversion-safe SVK first Piola-Kirchhoff stress [Pa] (see above). Returns the energy density
/// [J/m^3] of the clamped state extended linearly below the clamp (continuous, but the clamped
/// force is not exactly its gradient: use it for dynamics, not for energy checks).
template <class T>
ZONA_HOST_DEVICE ZONA_INLINE T svk_first_piola_clamped(const Mat3<T>& h, T lambda, T mu,
                                                       T stretch_min, Mat3<T>* p) {
  Vec3<T> uc[3], vc[3];
  T sig[3];
  rotation_svd3(h, uc, sig, vc);
  T sh[3], eh[3];
  T tr = 0;
  for (int i = 0; i < 3; ++i) {
    sh[i] = sig[i] > stretch_min ? sig[i] : stretch_min;
    eh[i] = T(0.5) * (sh[i] * sh[i] - T(1));
    tr += eh[i];
  }
  T psi = T(0.5) * lambda * tr * tr;
  Mat3<T> out = Mat3<T>::zero();
  for (int i = 0; i < 3; ++i) {
    const T pi = sh[i] * (lambda * tr + T(2) * mu * eh[i]);
    psi += mu * eh[i] * eh[i] + pi * (sig[i] - sh[i]);
    out = out + pi * outer(uc[i], vc[i]);
  }
  *p = out;
  return psi;
}

}  // namespace zona
