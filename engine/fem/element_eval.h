// The element function: one evaluation per (constitutive law, formulation), composed from
// fem_element.h: forces f[4] written, energy returned, ElementHealth bits in *bits.
// ZONA_HOST_DEVICE and templated on the scalar: the CUDA kernels call it in float32, the CPU's
// scalar passes (engine/fem/forces_cpu.cpp, ElementOf) in float64. The CPU's batched SIMD passes
// of the gradient kinds compose the same fem_element.h functions on packs, bit-identical to
// this function per lane (tests/engine/fem/forces_simd_test.cpp), and an FMA variant that
// rearranges the algebra (same file, tested against it).
#pragma once

#include <cstdint>

#include "engine/core/base.h"
#include "engine/fem/fem_element.h"

namespace zona {

/// The element functions the GPU can run; one kernel instantiation each.
enum class ElementKind : int32_t {
  kSvkGradient = 0,  ///< F, Green strain, S (the default)
  kSvkGradientClamped =
      1,                ///< same with the inversion-safe clamp (InversionHandling::kClampStretch)
  kLinearGradient = 2,  ///< small strain
  kSvkRebuilt = 3,      ///< Ladjal et al.'s contraction, B C D rebuilt in registers
  kLinearRebuilt = 4,   ///< Ladjal et al.'s contraction, K rebuilt in registers
  kSvkStored = 5,       ///< Ladjal et al.'s contraction, B C D read from memory (592 numbers)
  kLinearStored = 6,    ///< Ladjal et al.'s contraction, K read from memory (144 numbers)
  kSnhGradient = 7,     ///< stable neo-Hookean, F and cof F (gradient form only)
};

/// Whether the kind reads stored tensors.
ZONA_HOST_DEVICE constexpr bool element_kind_stored(ElementKind k) {
  return k == ElementKind::kSvkStored || k == ElementKind::kLinearStored;
}

/// Numbers per tetrahedron of the stored tensors of a kind (0 for the others).
ZONA_HOST_DEVICE constexpr int element_kind_tensor_size(ElementKind k) {
  return k == ElementKind::kSvkStored ? kSvkTensorSize
                                      : (k == ElementKind::kLinearStored ? kTensorBSize : 0);
}

/// Health of the tensor forms, which never form H: it is formed here for the checks only.
template <class T>
ZONA_HOST_DEVICE ZONA_INLINE uint32_t tensor_form_health(bool svk, const TetShape<T>& s,
                                                         const Vec3<T> u[4]) {
  const Mat3<T> h = tet_displacement_gradient(s, u);
  if (svk) return tet_health(h);
  return determinant(Mat3<T>::identity() + h) > T(0) ? 0u : uint32_t{kElementInverted};
}

/// Evaluates element kind K. `tensors` is read by the stored kinds only; `clamp_stretch` by
/// the clamped kind only (with `clamp_at_collapse` true when it equals kSvkCollapseStretch).
template <ElementKind K, class T>
ZONA_HOST_DEVICE ZONA_INLINE T eval_element(const TetShape<T>& s, T lambda, T mu, const T* tensors,
                                            T clamp_stretch, bool clamp_at_collapse,
                                            const Vec3<T> u[4], Vec3<T> f[4], uint32_t* bits) {
  // Each kind reads only some of the parameters.
  (void)lambda, (void)mu, (void)tensors, (void)clamp_stretch, (void)clamp_at_collapse;
  if constexpr (K == ElementKind::kSvkGradient) {
    const Mat3<T> h = tet_displacement_gradient(s, u);
    const Mat3<T> e = green_strain(h);
    *bits = tet_health_from_strain(h, e);
    T psi;
    const Mat3<T> stress = isotropic_stress(e, lambda, mu, &psi);
    tet_forces_from_stress(s, stress + h * stress, f);
    return s.volume * psi;
  } else if constexpr (K == ElementKind::kSvkGradientClamped) {
    const Mat3<T> h = tet_displacement_gradient(s, u);
    const Mat3<T> e = green_strain(h);
    *bits = tet_health_from_strain(h, e);
    const bool clamp =
        clamp_at_collapse ? *bits != 0 : tet_health_from_strain(h, e, clamp_stretch) != 0;
    T psi;
    Mat3<T> p;
    if (clamp) {
      psi = svk_first_piola_clamped(h, lambda, mu, clamp_stretch, &p);
      *bits |= kElementClamped;
    } else {
      const Mat3<T> stress = isotropic_stress(e, lambda, mu, &psi);
      p = stress + h * stress;
    }
    tet_forces_from_stress(s, p, f);
    return s.volume * psi;
  } else if constexpr (K == ElementKind::kLinearGradient) {
    const Mat3<T> h = tet_displacement_gradient(s, u);
    *bits = determinant(Mat3<T>::identity() + h) > T(0) ? 0u : uint32_t{kElementInverted};
    T psi;
    tet_forces_from_stress(s, isotropic_stress(small_strain(h), lambda, mu, &psi), f);
    return s.volume * psi;
  } else if constexpr (K == ElementKind::kSnhGradient) {
    return tet_snh_forces(s, lambda, mu, u, f, bits);
  } else if constexpr (K == ElementKind::kSvkRebuilt) {
    *bits = tensor_form_health(true, s, u);
    return tet_svk_forces_rebuilt(s, lambda, mu, u, f);
  } else if constexpr (K == ElementKind::kLinearRebuilt) {
    *bits = tensor_form_health(false, s, u);
    return tet_linear_forces_rebuilt(s, lambda, mu, u, f);
  } else if constexpr (K == ElementKind::kSvkStored) {
    *bits = tensor_form_health(true, s, u);
    return tet_svk_forces_tensor(tensors, u, f);
  } else {
    static_assert(K == ElementKind::kLinearStored);
    *bits = tensor_form_health(false, s, u);
    return tet_linear_forces_tensor(tensors, u, f);
  }
}

}  // namespace zona
