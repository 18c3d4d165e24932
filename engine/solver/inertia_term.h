// The static solver's regulariser: one backward-Euler step of the cell's real mass and the
// medium's drag over a load step's time h = travel step / needle speed,
//   E = sum_v m_v / (2 h^2) |u_v - (u_n + h v_n)|^2 + c_v / (2 h) |u_v - u_n|^2,
// which gives the cell's rigid motions on its holder (the rotation about the needle's axis has no
// elastic energy) a small positive stiffness. Both coefficients are physical (the real mass, not
// the explicit step's scaled one, and Stokes drag in the medium), and six orders of magnitude
// below the cell's stiffness on the default scene: the static answer moves by far less than
// 1 % (docs/static.md measures it).
#pragma once

#include <span>
#include <vector>

#include "engine/core/energy_term.h"
#include "engine/core/parallel.h"

namespace zona {

class InertiaTerm final : public EnergyTerm {
 public:
  /// mass [kg] and drag [kg/s] per vertex, (vertex_count).
  InertiaTerm(std::vector<double> mass, std::vector<double> drag)
      : mass_(std::move(mass)), drag_(std::move(drag)), weight_(mass_.size(), 0.0),
        center_(mass_.size(), Vec3d{0, 0, 0}) {}

  const char* name() const override { return "inertia"; }
  /// The step: its time h [s], the accepted displacement u_n [m] and velocity v_n [m/s].
  void set_step(double h, std::span<const Vec3d> u, std::span<const Vec3d> v) {
    for (size_t i = 0; i < mass_.size(); ++i) {
      const double a = mass_[i] / (h * h), b = drag_[i] / h;
      weight_[i] = a + b;
      center_[i] = weight_[i] > 0 ? u[i] + (a * h / weight_[i]) * v[i] : u[i];
    }
  }
  double energy(std::span<const Vec3d> u) override {
    double e = 0;
    for (size_t i = 0; i < u.size(); ++i) {
      const Vec3d d = u[i] - center_[i];
      e += 0.5 * weight_[i] * dot(d, d);
    }
    return e;
  }
  void add_gradient(std::span<const Vec3d> u, std::span<Vec3d> g) override {
    pooled_ranges(u.size(), 4096, [&](size_t, size_t begin, size_t end) {
      for (size_t i = begin; i < end; ++i) g[i] += weight_[i] * (u[i] - center_[i]);
    });
  }
  void add_hessian_product(std::span<const Vec3d>, std::span<const Vec3d> v,
                           std::span<Vec3d> y) override {
    for (size_t i = 0; i < v.size(); ++i) y[i] += weight_[i] * v[i];
  }
  void add_hessian_diagonal(std::span<const Vec3d>, std::span<Mat3d> d) override {
    for (size_t i = 0; i < d.size(); ++i) d[i] = d[i] + weight_[i] * Mat3d::identity();
  }
  void add_hessian(std::span<const Vec3d>, BlockSparseMatrix& h, bool) override {
    pooled_ranges(weight_.size(), 4096, [&](size_t, size_t begin, size_t end) {
      for (size_t i = begin; i < end; ++i) {
        Mat3d& d = h.diagonal_block(i);
        d = d + weight_[i] * Mat3d::identity();
      }
    });
  }

 private:
  std::vector<double> mass_, drag_;
  std::vector<double> weight_;  // m / h^2 + c / h [N/m]
  std::vector<Vec3d> center_;   // [m]
};

}  // namespace zona
