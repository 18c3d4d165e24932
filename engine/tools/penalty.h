// The penalty contact law of a point against a tool, as pure functions: the normal pressure's
// energy, gradient and Hessian, the Coulomb friction's stick spring as a potential, and where the
// friction anchor moves once a step is accepted (the commit). Host and device.
//
// Normal: a point at signed distance phi < 0 inside a tool, over its area A, carries the energy
//   E_n = k phi^2 / 2,   k = kappa A,
// so its force -dE/dx = k (-phi) n (n = grad phi, out of the tool) and its Hessian
// k (n n^T + phi hess phi), the second part the tool's curvature (tool_sdf.h).
//
// Friction: a stick spring from the point's anchor on the tool, on the tangential part of
// d = rel - anchor (rel: the point relative to the tool's reference point; P = I - n n^T with n
// held, the normal of the step's start or the current evaluation's), capped at the Coulomb force
// c = mu f_n. Its stiffness k_t is the contact's own k, or c / l where that is softer
// (friction_stiffness): a sticking point carries its tangential load elastically over at least
// the stick length l of slip before it slides (the tool's stick_length). As a potential this is the
// Huber function of s = |P d|:
//   E_t = k_t s^2 / 2                (k_t s <= c: sticking)
//   E_t = c s - c^2 / (2 k_t)        (k_t s > c: sliding),
// continuously differentiable, with gradient k_t P d or c P d / s. The explicit step evaluates
// it at its own state (n and c of the current evaluation: today's force), a static solver with n
// and c lagged from the last accepted step (an incremental potential). Once a step is accepted,
// a sliding point's anchor follows it so that the spring stays at the cap: anchor = rel - g / k_t
// (g the friction gradient) - penalty_anchor_after. Evaluating forces never moves an anchor.
#pragma once

#include <cstdint>

#include "engine/core/base.h"
#include "engine/core/vec.h"
#include "engine/tools/tool_sdf.h"

namespace zona {

/// Where a contact point stuck to its tool, for the friction's stick spring: its position
/// relative to the tool's reference point (the needle's tip, the rim's mouth) that the spring
/// pulls it back to [m], and the step of its last contact + 2 (`mark`). An anchor is live only
/// if the point touched the tool in the previous step (mark == step + 1); a point that left the
/// tool starts afresh where it touches again. Zero bytes are a void anchor (device memory is
/// cleared, not constructed).
struct StickAnchor {
  Vec3d at{0, 0, 0};
  int64_t mark = 0;
};

/// The anchor a point at `rel` [m] is pulled to in step `step`: the stored one while it is live,
/// else the point itself (a fresh contact sticks where it touched).
ZONA_HOST_DEVICE ZONA_INLINE Vec3d stick_anchor_in_step(const StickAnchor& a, int64_t step,
                                                        Vec3d rel) {
  return a.mark == step + 1 ? a.at : rel;
}

/// The anchor committed for a point in contact during step `step`, stuck at `at` [m].
ZONA_HOST_DEVICE ZONA_INLINE StickAnchor stick_anchor_commit(Vec3d at, int64_t step) {
  return StickAnchor{at, step + 2};
}

/// The normal penalty's energy k phi^2 / 2 [J] (0 outside the tool); k [N/m], phi [m].
ZONA_HOST_DEVICE ZONA_INLINE double penalty_energy(double k, double phi) {
  return phi < 0 ? 0.5 * k * phi * phi : 0.0;
}

/// The normal penalty's gradient k phi n [N] (minus its force; 0 outside).
ZONA_HOST_DEVICE ZONA_INLINE Vec3d penalty_gradient(double k, const ToolSdf& sdf) {
  return sdf.distance < 0 ? (k * sdf.distance) * sdf.normal : Vec3d{0, 0, 0};
}

/// The normal penalty's Hessian k (n n^T + phi hess phi) [N/m] (0 outside); `hess_phi` the
/// distance's Hessian [1/m].
ZONA_HOST_DEVICE ZONA_INLINE Mat3d penalty_hessian(double k, const ToolSdf& sdf,
                                                   const Mat3d& hess_phi) {
  if (!(sdf.distance < 0)) return Mat3d::zero();
  return k * (outer(sdf.normal, sdf.normal) + sdf.distance * hess_phi);
}

/// The friction spring's stiffness k_t [N/m] for a contact of normal stiffness k [N/m] and
/// Coulomb cap `cap` [N]: k, or cap / stick_length where that is softer, so that the stick zone
/// (cap / k_t of tangential offset) is at least `stick_length` [m] wide; 0 keeps k. With the
/// contact's own k alone the zone is mu times the penetration, nanometres on the default cell,
/// and a static solver's Newton iterations cross it back and forth (docs/static.md, "Cost").
ZONA_HOST_DEVICE ZONA_INLINE double friction_stiffness(double k, double cap, double stick_length) {
  return stick_length > 0 && cap < k * stick_length ? cap / stick_length : k;
}

/// The friction spring's gradient [N] on d = rel - anchor [m]: k P d, scaled down to length
/// `cap` [N] where longer (sliding; *slid set). n the held unit normal, k [N/m].
ZONA_HOST_DEVICE ZONA_INLINE Vec3d friction_spring(double k, double cap, Vec3d n, Vec3d d,
                                                   bool* slid) {
  Vec3d g = k * (d - dot(d, n) * n);
  const double len = norm(g);
  *slid = len > cap;
  if (*slid) g = (len > 0 ? cap / len : 0.0) * g;
  return g;
}

/// friction_spring's gradient alone.
ZONA_HOST_DEVICE ZONA_INLINE Vec3d friction_gradient(double k, double cap, Vec3d n, Vec3d d) {
  bool slid;
  return friction_spring(k, cap, n, d, &slid);
}

/// The friction spring's energy [J] (the Huber function of the file comment).
ZONA_HOST_DEVICE ZONA_INLINE double friction_energy(double k, double cap, Vec3d n, Vec3d d) {
  const Vec3d t = d - dot(d, n) * n;
  const double s = norm(t);
  if (k * s <= cap) return 0.5 * k * s * s;
  return cap * s - 0.5 * cap * cap / k;
}

/// The friction spring's Hessian [N/m]: k P sticking, (c / s)(P - t t^T) sliding (t = P d / s).
ZONA_HOST_DEVICE ZONA_INLINE Mat3d friction_hessian(double k, double cap, Vec3d n, Vec3d d) {
  const Mat3d p = Mat3d::identity() - outer(n, n);
  const Vec3d t = d - dot(d, n) * n;
  const double s = norm(t);
  if (k * s <= cap) return k * p;
  const Vec3d u = t / s;
  return (cap / s) * (p - outer(u, u));
}

/// Where a contact point's anchor goes when the step is accepted: unchanged while it sticks; a
/// sliding point's follows it, rel - g / k, so that its spring (of stiffness k) stays at the
/// Coulomb limit. rel, anchor [m].
ZONA_HOST_DEVICE ZONA_INLINE Vec3d penalty_anchor_after(double k, double cap, Vec3d n, Vec3d rel,
                                                        Vec3d anchor) {
  bool slid;
  const Vec3d g = friction_spring(k, cap, n, rel - anchor, &slid);
  return slid ? rel + (1.0 / k) * (-1.0 * g) : anchor;
}

// The needle's surface quadrature (its load integrated over the surface triangles, in the
// explicit step and the static solver alike).

/// Subdivisions per edge of the needle's surface quadrature: each triangle is cut into
/// kFaceSubdivisions^2 equal sub-triangles whose centroids are the quadrature points (weights
/// 1 / kFaceSubdivisions^2). With 4, a triangle stretched to twice the tip's radius still has
/// points half a radius apart.
inline constexpr int kFaceSubdivisions = 4;

/// Quadrature points per triangle.
inline constexpr int kFacePoints = kFaceSubdivisions * kFaceSubdivisions;

/// Barycentric weights of corners 1 and 2 of quadrature point q in [0, kFacePoints): the
/// centroids of the sub-triangles, row by row (row i: n - i upward, then n - i - 1 downward).
ZONA_HOST_DEVICE ZONA_INLINE void face_point_weights(int q, double* b1, double* b2) {
  constexpr int n = kFaceSubdivisions;
  int i = 0;
  while (q >= 2 * (n - i) - 1) {
    q -= 2 * (n - i) - 1;
    ++i;
  }
  const bool down = q >= n - i;
  const int j = down ? q - (n - i) : q;
  const double off = down ? 2.0 / 3.0 : 1.0 / 3.0;
  *b1 = (i + off) / n;
  *b2 = (j + off) / n;
}

/// Quadrature point q of a triangle with corners x[3] [m], and its barycentric weights b[3].
ZONA_HOST_DEVICE ZONA_INLINE Vec3d face_point(const Vec3d x[3], int q, double b[3]) {
  face_point_weights(q, &b[1], &b[2]);
  b[0] = 1.0 - b[1] - b[2];
  return b[0] * x[0] + b[1] * x[1] + b[2] * x[2];
}

/// One point's contact in the explicit step: the force [N] the tool puts on it and its anchor
/// after the step [m].
struct PenaltyContact {
  Vec3d force{0, 0, 0};
  Vec3d anchor{0, 0, 0};
};

/// Penalty contact of one point inside a tool (sdf.distance < 0): the normal pressure kappa x
/// penetration over the point's area along sdf.normal, and the friction spring from `anchor`
/// (stick_anchor_in_step) capped at mu times the normal force, its stiffness
/// friction_stiffness(kappa area, cap, stick_length), stick_length [m]. `rel`: the point relative to
/// the tool's reference point [m]. A sticking point carries its tangential load at rest,
/// whatever the step, the speed or the (scaled) mass: a viscous stick force (stop the slip
/// velocity in one step, m v_t / dt) let it creep at a rate set by the mass scaling
/// (docs/injection.md).
///
/// `damper` [kg/s] adds a normal dashpot against `velocity`, the point's velocity relative to
/// the tool [m/s]: it resists the approach and the rebound, and the normal force never turns
/// into a pull (a point leaving the tool faster than its spring relaxes is let go). At rest it
/// carries nothing, so a static answer does not depend on it; it is the explicit step's
/// dissipation, not part of any energy.
ZONA_HOST_DEVICE ZONA_INLINE PenaltyContact penalty_contact(const ToolSdf& sdf, double kappa,
                                                           double mu, double stick_length,
                                                           double area, Vec3d rel, Vec3d anchor,
                                                           double damper = 0,
                                                           Vec3d velocity = Vec3d{0, 0, 0}) {
  const double k = kappa * area;
  double fn = k * (-sdf.distance);  // > 0 inside
  if (damper > 0) {
    fn -= damper * dot(velocity, sdf.normal);
    if (fn < 0) fn = 0;
  }
  const double cap = mu * fn;
  const double kt = friction_stiffness(k, cap, stick_length);
  bool slid;
  const Vec3d g = friction_spring(kt, cap, sdf.normal, rel - anchor, &slid);
  PenaltyContact out;
  out.force = fn * sdf.normal - g;
  // The anchor after the step (penalty_anchor_after, from the same spring).
  out.anchor = slid ? rel + (1.0 / kt) * (-1.0 * g) : anchor;
  return out;
}

/// penalty_contact with the point's stored anchor: reads it for step `step` and writes the
/// committed one back. The explicit step accepts every step, so its tool stage commits the
/// anchors as it goes (each point owns its anchor, and nothing reads it again in the step); a
/// solver that evaluates trial states calls penalty_contact and commits after acceptance.
ZONA_HOST_DEVICE ZONA_INLINE Vec3d penalty_contact_force(const ToolSdf& sdf, double kappa,
                                                       double mu, double stick_length,
                                                       double area, Vec3d rel, int64_t step,
                                                       StickAnchor* anchor, double damper = 0,
                                                       Vec3d velocity = Vec3d{0, 0, 0}) {
  const PenaltyContact c = penalty_contact(sdf, kappa, mu, stick_length, area, rel,
                                           stick_anchor_in_step(*anchor, step, rel), damper,
                                           velocity);
  *anchor = stick_anchor_commit(c.anchor, step);
  return c.force;
}

}  // namespace zona
