// The tools' signed distance fields: the needle (hemispherical or flat tip on a cylinder) and the
// holding pipette's wall (a tube with rounded mouth edges), with their exact gradient (the
// normal) and, on request, their Hessian (the curvature a contact energy's second derivative
// needs). Host and device: the injection step's tool stage and the energy terms call these.
//
// Both tools are bodies of revolution, so each distance is a function D(s, rho) of the axial
// coordinate s and the distance rho from the axis: the distance to a point, a line s = c or a
// line rho = c of that half-plane. With a the axis and r the radial unit vector,
//   grad D = D_s a + D_rho r,
//   hess D = [a r] H2 [a r]^T + D_rho (I - a a^T - r r^T) / rho,
// where H2 is the half-plane Hessian: (I2 - n2 n2^T) / D for the distance to a point, 0 for a
// line; the second term is the curvature of the circles of revolution. On the axis (rho = 0)
// the field is not twice differentiable; the second term is left out there.
#pragma once

#include <cmath>

#include "engine/core/base.h"
#include "engine/core/vec.h"

namespace zona {

/// Signed distance of a point from a tool surface and the tool's outward normal there.
struct ToolSdf {
  double distance = 0;    ///< [m], negative inside the tool
  Vec3d normal{0, 0, 0};  ///< unit normal pointing out of the tool (into the cell) [-]
};

/// The Hessian of an axisymmetric distance (see the file comment): the half-plane Hessian
/// (h_ss, h_sr, h_rr) [1/m], the radial derivative d_rho [-], the axis, the radial unit vector
/// and rho [m].
ZONA_HOST_DEVICE ZONA_INLINE Mat3d axisymmetric_hessian(double h_ss, double h_sr, double h_rr,
                                                        double d_rho, Vec3d axis, Vec3d radial,
                                                        double rho) {
  Mat3d h = h_ss * outer(axis, axis) + h_sr * (outer(axis, radial) + outer(radial, axis)) +
            h_rr * outer(radial, radial);
  if (rho > 0 && d_rho != 0) {
    const double c = d_rho / rho;
    h = h + c * (Mat3d::identity() - outer(axis, axis) - outer(radial, radial));
  }
  return h;
}

/// The half-plane Hessian of the distance to a point at offset (ds, dr) from the point, distance
/// len > 0: (I2 - n2 n2^T) / len, into the Hessian with the radial derivative dr / len.
ZONA_HOST_DEVICE ZONA_INLINE Mat3d point_distance_hessian(double ds, double dr, double len,
                                                          Vec3d axis, Vec3d radial, double rho) {
  if (!(len > 0)) return Mat3d::zero();
  const double ns = ds / len, nr = dr / len;
  return axisymmetric_hessian((1 - ns * ns) / len, -ns * nr / len, (1 - nr * nr) / len, nr, axis,
                              radial, rho);
}

/// A unit vector perpendicular to d (the radial direction on the axis, where any will do).
ZONA_HOST_DEVICE ZONA_INLINE Vec3d any_perpendicular(Vec3d d) {
  const Vec3d a = (d.x < 0.9 && d.x > -0.9) ? Vec3d{1, 0, 0} : Vec3d{0, 1, 0};
  const Vec3d c = cross(d, a);
  return c / norm(c);
}

/// The needle: a cylinder of radius r along -d behind its tip, ended by a hemisphere whose apex
/// is `tip` (`flat` = false) or by a flat disk at `tip` (`flat` = true). x, tip [m], d unit.
/// `hessian` (optional): the distance's Hessian at x [1/m].
ZONA_HOST_DEVICE ZONA_INLINE ToolSdf needle_sdf(Vec3d tip, Vec3d d, double r, bool flat, Vec3d x,
                                                Mat3d* hessian = nullptr) {
  ToolSdf out;
  // Axial coordinate s (ahead of the reference point positive) and the radial unit vector.
  const Vec3d ref = flat ? tip : tip - r * d;
  const Vec3d w = x - ref;
  const double s = dot(w, d);
  const Vec3d radial_vec = w - s * d;
  const double rho = norm(radial_vec);
  Vec3d radial = rho > 0 ? radial_vec / rho : Vec3d{0, 0, 0};
  if (!(rho > 0)) radial = any_perpendicular(d);  // on the axis: any direction perpendicular to d
  Mat3d h = Mat3d::zero();
  if (!flat) {
    if (s > 0) {
      // The hemisphere: distance to the point (s, rho) = (0, 0).
      const double len = norm(w);
      out.distance = len - r;
      out.normal = len > 0 ? w / len : d;
      if (hessian) h = point_distance_hessian(s, rho, len, d, radial, rho);
    } else {
      // The shaft: rho - r.
      out.distance = rho - r;
      out.normal = radial;
      if (hessian) h = axisymmetric_hessian(0, 0, 0, 1, d, radial, rho);
    }
    if (hessian) *hessian = h;
    return out;
  }
  if (s > 0) {
    if (rho <= r) {
      // Ahead of the end face: s.
      out.distance = s;
      out.normal = d;
    } else {
      // Ahead of and outside the edge circle: distance to the point (0, r).
      const Vec3d e = s * d + (rho - r) * radial;
      out.distance = norm(e);
      out.normal = e / out.distance;
      if (hessian) h = point_distance_hessian(s, rho - r, out.distance, d, radial, rho);
    }
  } else if (rho >= r) {
    out.distance = rho - r;
    out.normal = radial;
    if (hessian) h = axisymmetric_hessian(0, 0, 0, 1, d, radial, rho);
  } else if (-s < r - rho) {
    out.distance = s;  // closer to the end face
    out.normal = d;
  } else {
    out.distance = rho - r;
    out.normal = radial;
    if (hessian) h = axisymmetric_hessian(0, 0, 0, 1, d, radial, rho);
  }
  if (hessian) *hessian = h;
  return out;
}

/// The sharp-edged wall of holding_sdf; `hessian` as needle_sdf's.
ZONA_HOST_DEVICE ZONA_INLINE ToolSdf holding_sdf_sharp(Vec3d mouth, Vec3d axis, double a,
                                                      double b, Vec3d x,
                                                      Mat3d* hessian = nullptr) {
  const Vec3d w = x - mouth;
  const double s = dot(w, axis);
  const Vec3d rv = w - s * axis;
  const double rho = norm(rv);
  Vec3d radial = rho > 0 ? rv / rho : Vec3d{0, 0, 0};
  if (!(rho > 0)) radial = any_perpendicular(axis);
  ToolSdf out;
  const bool inside = s > 0 && rho > a && rho < b;
  if (!inside) {
    // Closest point of the strip in the (s, rho) half-plane, mapped back to 3D.
    const double qs = s > 0 ? s : 0.0;
    const double qr = rho < a ? a : (rho > b ? b : rho);
    const double ds = s - qs, dr = rho - qr;
    out.distance = sqrt(ds * ds + dr * dr);
    out.normal = out.distance > 0 ? (ds / out.distance) * axis + (dr / out.distance) * radial
                                  : -1.0 * axis;
    if (hessian) {
      if (ds != 0 && dr != 0)  // nearest to a mouth edge: a point
        *hessian = point_distance_hessian(ds, dr, out.distance, axis, radial, rho);
      else if (dr != 0)  // beside the tube: |rho - qr|
        *hessian = axisymmetric_hessian(0, 0, 0, dr > 0 ? 1.0 : -1.0, axis, radial, rho);
      else  // before the mouth: -s
        *hessian = Mat3d::zero();
    }
    return out;
  }
  // Inside the wall: leave through the nearest face.
  const double to_mouth = s, to_bore = rho - a, to_outer = b - rho;
  if (to_mouth <= to_bore && to_mouth <= to_outer) {
    out.distance = -to_mouth;
    out.normal = -1.0 * axis;
    if (hessian) *hessian = Mat3d::zero();
  } else if (to_bore <= to_outer) {
    out.distance = -to_bore;
    out.normal = -1.0 * radial;
    if (hessian) *hessian = axisymmetric_hessian(0, 0, 0, -1, axis, radial, rho);
  } else {
    out.distance = -to_outer;
    out.normal = radial;
    if (hessian) *hessian = axisymmetric_hessian(0, 0, 0, 1, axis, radial, rho);
  }
  return out;
}

/// The holding pipette's wall: the tube s >= 0, a <= rho <= b, where s is the distance past the
/// mouth plane along `axis` (unit, from the cell into the pipette) and rho the distance from
/// the axis, the mouth's two edges rounded with radius `edge` (0: sharp; below (b - a) / 2: a
/// fire-polished rim). The rounded wall is the sharp one eroded by `edge` and grown back by it;
/// its section is convex, so its distance is the eroded wall's minus `edge`, exact inside and
/// out, with the eroded wall's normal (and Hessian). mouth, x [m]; a, b, edge [m].
ZONA_HOST_DEVICE ZONA_INLINE ToolSdf holding_sdf(Vec3d mouth, Vec3d axis, double a, double b,
                                                Vec3d x, double edge = 0,
                                                Mat3d* hessian = nullptr) {
  ToolSdf out = holding_sdf_sharp(mouth + edge * axis, axis, a + edge, b - edge, x, hessian);
  out.distance -= edge;
  return out;
}

}  // namespace zona
