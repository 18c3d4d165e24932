// The tools' distance fields: the normal is the distance's gradient and the Hessian is the
// normal's derivative (central differences), in every region of the needle (both tips) and of
// the holding pipette's wall (sharp and rounded), inside and outside.
#include "engine/tools/tool_sdf.h"

#include <gtest/gtest.h>

#include <functional>

namespace zona {
namespace {

using Field = std::function<ToolSdf(Vec3d, Mat3d*)>;

// Checks grad and Hessian at x against central differences of the field with step h.
void expect_derivatives(const Field& field, Vec3d x, double h, const char* where) {
  Mat3d hess;
  const ToolSdf at = field(x, &hess);
  for (int i = 0; i < 3; ++i) {
    Vec3d e{0, 0, 0};
    e[i] = h;
    const ToolSdf p = field(x + e, nullptr), m = field(x - e, nullptr);
    EXPECT_NEAR(at.normal[i], (p.distance - m.distance) / (2 * h), 1e-6) << where << " grad " << i;
    for (int r = 0; r < 3; ++r)
      EXPECT_NEAR(hess.m[r][i], (p.normal[r] - m.normal[r]) / (2 * h), 1e-5)
          << where << " hess " << r << i;
  }
}

TEST(ToolSdf, NeedleNormalAndHessianAreTheDistancesDerivatives) {
  const Vec3d tip{0.3, -0.2, 0.1};
  const Vec3d d = Vec3d{1, 0.5, -0.25} / norm(Vec3d{1, 0.5, -0.25});
  const double r = 1.0;
  for (bool flat : {false, true}) {
    const Field f = [&](Vec3d x, Mat3d* h) { return needle_sdf(tip, d, r, flat, x, h); };
    const Vec3d side = any_perpendicular(d);
    // Ahead of the tip, on the hemisphere's side, beside the shaft, inside near the tip and
    // near the shaft, past the flat tip's edge.
    const Vec3d points[] = {tip + 0.5 * d + 0.3 * side,  tip - 0.3 * d + 0.8 * side,
                            tip - 3.0 * d + 1.7 * side,  tip - 0.4 * d + 0.2 * side,
                            tip - 2.0 * d + 0.7 * side,  tip + 0.4 * d + 1.5 * side};
    int k = 0;
    for (const Vec3d& x : points)
      expect_derivatives(f, x, 1e-6, (std::string(flat ? "flat " : "round ") + std::to_string(k++)).c_str());
  }
}

TEST(ToolSdf, HoldingWallNormalAndHessianAreTheDistancesDerivatives) {
  const Vec3d mouth{1, 2, 3};
  const Vec3d axis = Vec3d{0.2, -1, 0.3} / norm(Vec3d{0.2, -1, 0.3});
  const Vec3d side = any_perpendicular(axis);
  for (double edge : {0.0, 0.4}) {
    const Field f = [&](Vec3d x, Mat3d* h) { return holding_sdf(mouth, axis, 2.0, 5.0, x, edge, h); };
    // Before the mouth over the wall, off a mouth edge (outer and bore), beside the tube inside
    // the bore and outside it, inside the wall near the mouth, the bore and the outer face.
    const Vec3d points[] = {mouth - 0.7 * axis + 3.5 * side, mouth - 0.6 * axis + 5.8 * side,
                            mouth - 0.5 * axis + 1.2 * side, mouth + 4.0 * axis + 1.0 * side,
                            mouth + 4.0 * axis + 6.5 * side, mouth + 0.6 * axis + 3.5 * side,
                            mouth + 3.0 * axis + 2.3 * side, mouth + 3.0 * axis + 4.8 * side};
    int k = 0;
    for (const Vec3d& x : points)
      expect_derivatives(f, x, 1e-6, (std::string(edge > 0 ? "rounded " : "sharp ") + std::to_string(k++)).c_str());
  }
}

}  // namespace
}  // namespace zona
