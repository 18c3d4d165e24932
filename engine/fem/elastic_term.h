// The elastic energy as an energy term, element by element: value, stress (the gradient),
// Hessian-vector product and the Hessian's diagonal blocks, for every law the model has
// (linear, SVK, stable neo-Hookean with its volumetric term per element or at the vertices).
//
// These are the element functions a static solver needs beside the explicit step's: the stress
// comes from the same fem_element.h functions the element passes call (one copy of each law),
// and the second derivative is the stress differential dP = (d^2 Psi / dF^2) : dF, so a
// Hessian-vector product never forms a 12 x 12 matrix. ZONA_HOST_DEVICE: the CPU loops here
// (engine/fem/elastic_energy.cpp) and a CUDA kernel can call them alike.
//
// Nodal pressure (Model::nodal_pressure) splits the energy in two: the element part with
// lambda_s = mu and the corner mean of the vertices' pressures, and the vertices' volumetric
// energy sum_v V_v lambda_v / 2 (Jbar_v - 1)^2 with Jbar_v - 1 = (1 / V_v) sum_e V_e / 4 (J_e - 1).
// Its Hessian is the element part with the pressure held (pressure x d^2 J_e) plus, per vertex,
// the rank-one (lambda_v / V_v) g_v g_v^T with g_v = sum_e V_e / 4 dJ_e / du: positive
// semi-definite, kept exact. The element functions give the element part and dJ_e; the
// vertex sums are the host's (two passes, as the force's).
#pragma once

#include <cstdint>

#include "engine/core/base.h"
#include "engine/core/vec.h"
#include "engine/fem/fem_element.h"

namespace zona {

/// The law of one element as the energy term evaluates it. `pressure` is used only with
/// `nodal`: the corner mean of the vertices' lambda_v (Jbar_v - 1) [Pa].
template <class T>
struct ElementLaw {
  ConstitutiveModel model = ConstitutiveModel::kStableNeoHookean;
  T lambda = 0, mu = 0;  ///< the material's Lame constants [Pa]
  bool nodal = false;    ///< stable neo-Hookean with the volumetric term at the vertices
  T pressure = 0;        ///< [Pa]
  /// With nodal pressure: the part of the volumetric stiffness kept per element, beta x lambda
  /// (ModelDesc::nodal_stabilisation) [Pa]; the element law's lambda_s is then mu + this.
  T element_lambda = 0;
  /// The volume barrier (volume_barrier below): active below J = barrier_volume [-], of
  /// stiffness barrier_stiffness [Pa]; 0: none.
  T barrier_volume = 0;
  T barrier_stiffness = 0;
};

/// The volume barrier's energy density [J/m^3] and its first two derivatives in J, at volume
/// ratio j: with s = j / j0 (j0 = barrier_volume), k the stiffness,
///   psi_b = -k (s - 1)^2 ln s   for 0 < s < 1,   0 for s >= 1,   +infinity for j <= 0,
/// which is C^2 at s = 1 (value, slope and curvature vanish there) and grows without bound as
/// an element collapses, so an energy minimiser never inverts an element (docs/physics.md, "The
/// volume barrier"). The stable neo-Hookean law alone is finite at J <= 0.
template <class T>
struct BarrierValue {
  T psi = 0, d1 = 0, d2 = 0;  ///< psi_b [J/m^3], dpsi/dJ [Pa], d^2 psi/dJ^2 [Pa]
};
template <class T>
ZONA_HOST_DEVICE ZONA_INLINE BarrierValue<T> volume_barrier(T j, T j0, T k) {
  BarrierValue<T> b;
  if (!(j0 > T(0)) || j >= j0) return b;
  if (!(j > T(0))) {
    b.psi = T(INFINITY);
    return b;
  }
  const T s = j / j0, sm1 = s - T(1), ls = log(s);
  b.psi = -k * sm1 * sm1 * ls;
  // d/ds and d^2/ds^2, then the chain rule's 1 / j0 and 1 / j0^2.
  const T ds = -k * (T(2) * sm1 * ls + sm1 * sm1 / s);
  const T dss = -k * (T(2) * ls + T(4) * sm1 / s - sm1 * sm1 / (s * s));
  b.d1 = ds / j0;
  b.d2 = dss / (j0 * j0);
  return b;
}

/// First Piola-Kirchhoff stress P [Pa] of the law at displacement gradient h, to *p; the element
/// part of the energy density [J/m^3] returned (with nodal pressure: without the vertices'
/// volumetric energy); J - 1 [-] to *j_minus_one (0 for the linear law).
template <class T>
ZONA_HOST_DEVICE ZONA_INLINE T element_stress(const ElementLaw<T>& law, const Mat3<T>& h,
                                              Mat3<T>* p, T* j_minus_one) {
  switch (law.model) {
    case ConstitutiveModel::kLinear:
      *j_minus_one = T(0);
      return linear_first_piola(h, law.lambda, law.mu, p);
    case ConstitutiveModel::kSvk:
      *j_minus_one = snh_volume_change(h);
      return svk_first_piola(h, law.lambda, law.mu, p);
    default: {
      T psi = law.nodal ? snh_first_piola_with(h, law.mu, snh_lambda(law.element_lambda, law.mu),
                                               law.pressure, p, j_minus_one)
                        : snh_first_piola(h, law.lambda, law.mu, p, j_minus_one);
      if (law.barrier_volume > T(0)) {
        const BarrierValue<T> b =
            volume_barrier(T(1) + *j_minus_one, law.barrier_volume, law.barrier_stiffness);
        if (b.psi != T(0)) {
          psi += b.psi;
          *p = *p + b.d1 * snh_cofactor_of_f(h);
        }
      }
      return psi;
    }
  }
}

/// Stress differential dP = (d^2 Psi / dF^2) : dF [Pa] of the law at displacement gradient h
/// for a change dF [-] (with nodal pressure: of the element part, the pressure held).
template <class T>
ZONA_HOST_DEVICE ZONA_INLINE Mat3<T> element_stress_differential(const ElementLaw<T>& law,
                                                                 const Mat3<T>& h,
                                                                 const Mat3<T>& df) {
  T unused;
  switch (law.model) {
    case ConstitutiveModel::kLinear:
      return isotropic_stress(small_strain(df), law.lambda, law.mu, &unused);
    case ConstitutiveModel::kSvk: {
      // P = F S(E): dP = dF S + F dS, dS = C : dE, dE = sym(F^T dF).
      Mat3<T> f = h;
      for (int i = 0; i < 3; ++i) f.m[i][i] += T(1);
      const Mat3<T> s = isotropic_stress(green_strain(h), law.lambda, law.mu, &unused);
      const Mat3<T> ftdf = transpose(f) * df;
      Mat3<T> de;
      for (int r = 0; r < 3; ++r)
        for (int c = 0; c < 3; ++c) de.m[r][c] = T(0.5) * (ftdf.m[r][c] + ftdf.m[c][r]);
      return df * s + f * isotropic_stress(de, law.lambda, law.mu, &unused);
    }
    default: {
      Mat3<T> f = h;
      for (int i = 0; i < 3; ++i) f.m[i][i] += T(1);
      // With nodal pressure, the element part: the law with lambda_s = mu + element_lambda (a
      // material lambda of element_lambda), plus the held pressure's pressure x d cof(F)[dF].
      Mat3<T> dp = law.nodal ? snh_stress_differential(h, law.element_lambda, law.mu, df) +
                                   law.pressure * cofactor_differential(f, df)
                             : snh_stress_differential(h, law.lambda, law.mu, df);
      if (law.barrier_volume > T(0)) {
        // d (psi_b'(J) cof F) = psi_b''(J) (cof F : dF) cof F + psi_b'(J) d cof(F)[dF].
        const BarrierValue<T> b = volume_barrier(T(1) + snh_volume_change(h), law.barrier_volume,
                                                 law.barrier_stiffness);
        if (b.d1 != T(0) || b.d2 != T(0)) {
          const Mat3<T> cof = snh_cofactor_of_f(h);
          T cdf = T(0);
          for (int r = 0; r < 3; ++r)
            for (int c = 0; c < 3; ++c) cdf += cof.m[r][c] * df.m[r][c];
          dp = dp + (b.d2 * cdf) * cof + b.d1 * cofactor_differential(f, df);
        }
      }
      return dp;
    }
  }
}

/// The coefficients of the stable neo-Hookean tangent Q = mu I + a g g^T + b H_J at J - 1 = jm1
/// (snh_stress_tangent): a = lambda_s + psi_b'', b = lambda_s (J - 1) - mu + p + psi_b'.
template <class T>
ZONA_HOST_DEVICE ZONA_INLINE void snh_tangent_coefficients(const ElementLaw<T>& law, T jm1, T* a,
                                                           T* b) {
  const T lam = snh_lambda(law.nodal ? law.element_lambda : law.lambda, law.mu);
  *a = lam;
  *b = lam * jm1 - law.mu + (law.nodal ? law.pressure : T(0));
  if (law.barrier_volume > T(0)) {
    const BarrierValue<T> bv =
        volume_barrier(T(1) + jm1, law.barrier_volume, law.barrier_stiffness);
    *a += bv.d2;
    *b += bv.d1;
  }
}

/// The stable neo-Hookean law's d^2 Psi / dF^2 in closed form, q[3 r + c][3 s + d] = d P_rc /
/// d F_sd [Pa] at displacement gradient h (the columns of element_stress_differential for the
/// law, at a ninth of its cost):
///   Q = mu I + (lambda_s + psi_b'') g g^T + (lambda_s (J - 1) - mu + p + psi_b') H_J,
/// g = vec(cof F) = dJ/dF, H_J = d^2 J / dF^2 (d cof F_ij / dF_kl = e_ikm e_jln F_mn, i != k,
/// j != l); lambda_s = mu with nodal pressure (the pressure p held), else lambda + mu.
template <class T>
ZONA_HOST_DEVICE ZONA_INLINE void snh_stress_tangent(const ElementLaw<T>& law, const Mat3<T>& h,
                                                     T q[9][9]) {
  Mat3<T> f = h;
  for (int i = 0; i < 3; ++i) f.m[i][i] += T(1);
  const Mat3<T> cof = snh_cofactor_of_f(h);
  const T jm1 = snh_volume_change(h);
  T a, b;
  snh_tangent_coefficients(law, jm1, &a, &b);
  for (int r = 0; r < 9; ++r)
    for (int c = 0; c < 9; ++c)
      q[r][c] = a * cof.m[r / 3][r % 3] * cof.m[c / 3][c % 3] + (r == c ? law.mu : T(0));
  // H_J: entry (i j, k l) for i != k, j != l is the Levi-Civita signs times F_mn, m and n the
  // remaining row and column.
  for (int i = 0; i < 3; ++i)
    for (int k = 0; k < 3; ++k) {
      if (k == i) continue;
      const int m = 3 - i - k;
      const T si = (k == (i + 1) % 3) ? T(1) : T(-1);
      for (int j = 0; j < 3; ++j)
        for (int l = 0; l < 3; ++l) {
          if (l == j) continue;
          const int n = 3 - j - l;
          const T sj = (l == (j + 1) % 3) ? T(1) : T(-1);
          q[3 * i + j][3 * k + l] += b * si * sj * f.m[m][n];
        }
    }
}

/// snh_stress_tangent's Q projected to positive semi-definite in closed form: Q = mu I + a g g^T
/// + b H_J has the eigensystem of d^2 J / dF^2 (Smith, de Goes and Kim, "Analytic eigensystems
/// for isotropic distortion energies", 2019). With F = U diag(sigma) V^T (rotation_svd3), for each
/// axis m and the other two i < k: the twist (u_i v_k^T - u_k v_i^T) / sqrt 2 with eigenvalue
/// mu + b sigma_m and the flip (u_i v_k^T + u_k v_i^T) / sqrt 2 with mu - b sigma_m; the three
/// scalings sum_j d_j u_j v_j^T with d the eigenvectors of the 3 x 3 mu I + a c c^T + b S,
/// c = (sigma_2 sigma_3, sigma_1 sigma_3, sigma_1 sigma_2), S = [[0, s3, s2], [s3, 0, s1],
/// [s2, s1, 0]]. Each negative eigenvalue's pair is taken out of q (which holds Q on entry).
template <class T>
ZONA_HOST_DEVICE ZONA_INLINE void snh_project_tangent(const ElementLaw<T>& law, const Mat3<T>& h,
                                                      T q[9][9]) {
  const T jm1 = snh_volume_change(h);
  T a, b;
  snh_tangent_coefficients(law, jm1, &a, &b);
  Vec3<T> uc[3], vc[3];
  T sig[3];
  rotation_svd3(h, uc, sig, vc);
  // q -= lambda vec(E) vec(E)^T for a negative lambda (E of unit Frobenius norm).
  auto remove = [&](T lambda, const Mat3<T>& e) {
    if (!(lambda < T(0))) return;
    for (int r = 0; r < 9; ++r)
      for (int c = 0; c < 9; ++c) q[r][c] -= lambda * e.m[r / 3][r % 3] * e.m[c / 3][c % 3];
  };
  const T inv_sqrt2 = T(0.70710678118654752440);
  for (int m = 0; m < 3; ++m) {
    const int i = m == 0 ? 1 : 0, k = m == 2 ? 1 : 2;
    const Mat3<T> ik = outer(uc[i], vc[k]), ki = outer(uc[k], vc[i]);
    remove(law.mu + b * sig[m], inv_sqrt2 * (ik - ki));
    remove(law.mu - b * sig[m], inv_sqrt2 * (ik + ki));
  }
  const T c[3] = {sig[1] * sig[2], sig[0] * sig[2], sig[0] * sig[1]};
  Mat3<T> scaling;
  for (int r = 0; r < 3; ++r)
    for (int col = 0; col < 3; ++col)
      scaling.m[r][col] = a * c[r] * c[col] + (r == col ? law.mu : b * sig[3 - r - col]);
  T ev[3];
  Mat3<T> d;
  symmetric_eigen3(scaling, ev, &d);
  for (int e = 0; e < 3; ++e) {
    Mat3<T> mode = Mat3<T>::zero();
    for (int j = 0; j < 3; ++j) mode = mode + d.m[j][e] * outer(uc[j], vc[j]);
    remove(ev[e], mode);
  }
}

/// The element's energy [J] (element part) and its gradient dW/du at the corners [N] (the
/// negated elastic forces of the explicit step), at corner displacements u [m].
template <class T>
ZONA_HOST_DEVICE ZONA_INLINE T tet_energy_gradient(const TetShape<T>& s, const ElementLaw<T>& law,
                                                   const Vec3<T> u[4], Vec3<T> g[4]) {
  Mat3<T> p;
  T jm1;
  const T psi = element_stress(law, tet_displacement_gradient(s, u), &p, &jm1);
  Vec3<T> f[4];
  tet_forces_from_stress(s, p, f);
  for (int c = 0; c < 4; ++c) g[c] = -f[c];
  return s.volume * psi;
}

/// Hessian-vector product of the element: y_b = V dP grad_b with dF = sum_a v_a grad_a^T, at
/// corner displacements u [m], for corner directions v [m]; y [N] (written, not added).
template <class T>
ZONA_HOST_DEVICE ZONA_INLINE void tet_hessian_product(const TetShape<T>& s,
                                                      const ElementLaw<T>& law,
                                                      const Vec3<T> u[4], const Vec3<T> v[4],
                                                      Vec3<T> y[4]) {
  const Mat3<T> h = tet_displacement_gradient(s, u);
  const Mat3<T> dp = element_stress_differential(law, h, tet_displacement_gradient(s, v));
  for (int b = 0; b < 4; ++b) y[b] = s.volume * (dp * s.grad[b]);
}

/// The element Hessian's four diagonal 3 x 3 blocks d[a] = d^2 W / du_a^2 [N/m] at u [m]
/// (written): column i of block a is V dP grad_a at dF = e_i grad_a^T.
template <class T>
ZONA_HOST_DEVICE ZONA_INLINE void tet_hessian_diagonal(const TetShape<T>& s,
                                                       const ElementLaw<T>& law,
                                                       const Vec3<T> u[4], Mat3<T> d[4]) {
  const Mat3<T> h = tet_displacement_gradient(s, u);
  for (int a = 0; a < 4; ++a)
    for (int i = 0; i < 3; ++i) {
      Mat3<T> df = Mat3<T>::zero();
      for (int c = 0; c < 3; ++c) df.m[i][c] = s.grad[a][c];
      const Vec3<T> col = s.volume * (element_stress_differential(law, h, df) * s.grad[a]);
      for (int r = 0; r < 3; ++r) d[a].m[r][i] = col[r];
    }
}

/// dJ_e / du_a = cof(F) grad_a [-/m] at u [m], the four corners (written): the nodal
/// pressure's vertex gradients g_v are sums of V_e / 4 times these.
template <class T>
ZONA_HOST_DEVICE ZONA_INLINE void tet_volume_gradient(const TetShape<T>& s, const Vec3<T> u[4],
                                                      Vec3<T> dj[4]) {
  const Mat3<T> cof = snh_cofactor_of_f(tet_displacement_gradient(s, u));
  for (int a = 0; a < 4; ++a) dj[a] = cof * s.grad[a];
}

}  // namespace zona
