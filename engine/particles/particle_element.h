// Per-spring, per-triangle and per-particle math of the particle cell model (Asgari et al.), shared by
// the CPU reference (engine/particles/particle_model.cpp) and the CUDA kernels (kernels/particle_backend.cu)
// so that the two cannot drift apart (STYLE.md habit 5). Plain inline functions of positions and
// velocities; no indexing of global arrays, no threadIdx.
#pragma once

#include <cmath>

#include "engine/core/base.h"
#include "engine/core/vec.h"

namespace zona {

/// Force on particle i from a spring-dashpot to particle j (Asgari et al. eqs. 3-4 plus the dashpot
/// along the spring): [k (L - L0) + c (v_j - v_i).r] r, with r the unit vector from i to j.
/// A stretched spring pulls i towards j. Positions [m], velocities [m/s], k [N/m], c [N*s/m];
/// returns [N]. A zero-length spring (L = 0) has no direction and returns zero.
ZONA_HOST_DEVICE ZONA_INLINE Vec3d particle_spring_force(Vec3d xi, Vec3d xj, Vec3d vi, Vec3d vj,
                                                         double rest_length, double k, double c) {
  const Vec3d d = xj - xi;
  const double length = sqrt(dot(d, d));
  if (!(length > 0)) return Vec3d{0, 0, 0};
  const Vec3d r = d / length;
  const double tension = k * (length - rest_length) + c * dot(vj - vi, r);
  return tension * r;
}

/// Elastic energy of a spring, k (L - L0)^2 / 2 [J].
ZONA_HOST_DEVICE ZONA_INLINE double particle_spring_energy(Vec3d xi, Vec3d xj, double rest_length,
                                                           double k) {
  const Vec3d d = xj - xi;
  const double stretch = sqrt(dot(d, d)) - rest_length;
  return 0.5 * k * stretch * stretch;
}

/// Signed volume of the tetrahedron (origin, a, b, c) [m^3]: summed over a closed, outward
/// counter-clockwise triangulation it is the enclosed volume. Positions relative to the cell
/// centre at rest keep the terms small (float64 throughout: relative volume changes of 1e-6
/// must be resolved).
ZONA_HOST_DEVICE ZONA_INLINE double triangle_volume_term(Vec3d a, Vec3d b, Vec3d c) {
  return dot(a, cross(b, c)) / 6.0;
}

/// Area vector of triangle (a, b, c), (b - a) x (c - a) / 2 [m^2]: outward for a
/// counter-clockwise outward triangle, |.| its area.
ZONA_HOST_DEVICE ZONA_INLINE Vec3d triangle_area_vector(Vec3d a, Vec3d b, Vec3d c) {
  return 0.5 * cross(b - a, c - a);
}

/// Hydraulic pressure of Asgari et al. eq. 6, beta = -(1/V) dV/dP, integrated at constant beta from
/// P = 0 at V0: P = ln(V0 / V) / beta [Pa]. Compression (V < V0) gives P > 0, pushing the
/// membrane out. Volumes [m^3], beta [1/Pa].
ZONA_HOST_DEVICE ZONA_INLINE double hydraulic_pressure(double volume, double rest_volume,
                                                       double beta) {
  return log(rest_volume / volume) / beta;
}

/// Energy stored by the compressed interior, -integral of P dV from V0 to V:
/// (V ln(V / V0) - V + V0) / beta [J] (>= 0, zero at V0).
ZONA_HOST_DEVICE ZONA_INLINE double hydraulic_energy(double volume, double rest_volume,
                                                     double beta) {
  return (volume * log(volume / rest_volume) - volume + rest_volume) / beta;
}

/// Centred-difference update of one component with diagonal (anisotropic) damping b treated
/// centred-implicitly (Asgari et al. eq. 7 with eq. 5's B): (m + b dt/2) u+ = 2 m u - (m - b dt/2) u-
/// + dt^2 f. Mass [kg], damping [N*s/m], dt [s], force [N]; returns u_{n+1} [m].
ZONA_HOST_DEVICE ZONA_INLINE double particle_update(double u, double u_prev, double force,
                                                    double mass, double damping, double dt) {
  const double h = 0.5 * damping * dt;
  return (2.0 * mass * u - (mass - h) * u_prev + dt * dt * force) / (mass + h);
}

}  // namespace zona
