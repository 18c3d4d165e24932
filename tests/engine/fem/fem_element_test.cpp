// Element functions: geometry conventions, finite-difference checks of force and stiffness,
// tensor form == gradient form, small-strain and rotation limits, health, inversion remedy,
// stable neo-Hookean.
#include "engine/fem/fem_element.h"

#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <random>
#include <vector>

#include "engine/fem/material.h"
#include "engine/mesh/mesh.h"

namespace zona {
namespace {

// An irregular tetrahedron of ~1 um and mouse-zona material (Ladjal et al. Table I).
struct Fixture {
  Vec3d x[4] = {{0.1e-6, -0.05e-6, 0.02e-6},
                {1.05e-6, 0.1e-6, -0.03e-6},
                {0.2e-6, 0.9e-6, 0.1e-6},
                {0.15e-6, 0.2e-6, 1.1e-6}};
  TetShape<double> shape = tet_shape_from_rest(x[0], x[1], x[2], x[3]);
  Lame lame = lame_from_young_poisson(17.9e3, 0.49);
};

// A displacement field with strains of order `strain` (non-affine across vertices).
void displacements(double strain, Vec3d u[4]) {
  const double h = 1e-6 * strain;
  u[0] = Vec3d{0.3, -0.2, 0.1} * h;
  u[1] = Vec3d{-0.1, 0.4, 0.25} * h;
  u[2] = Vec3d{0.2, 0.1, -0.35} * h;
  u[3] = Vec3d{-0.3, 0.15, 0.2} * h;
}

double max_norm(const Vec3d f[4]) {
  double m = 0;
  for (int j = 0; j < 4; ++j) m = std::max(m, norm(f[j]));
  return m;
}

TEST(FemElement, ShapeGradientsFollowTheConventions) {
  Fixture fx;
  const TetShape<double>& s = fx.shape;
  EXPECT_NEAR(s.volume, tet_signed_volume(fx.x[0], fx.x[1], fx.x[2], fx.x[3]), 1e-30);
  // grad N_i . (x_j - x_0) = delta_ij - delta_0j: the gradients of linear shape functions.
  for (int i = 1; i < 4; ++i)
    for (int j = 1; j < 4; ++j)
      EXPECT_NEAR(dot(s.grad[i], fx.x[j] - fx.x[0]), i == j ? 1.0 : 0.0, 1e-12);
  // m_j = 6 V grad N_j is the INWARD normal of the face opposite j, length twice its area.
  static constexpr int kFace[4][3] = {{1, 2, 3}, {0, 2, 3}, {0, 1, 3}, {0, 1, 2}};
  for (int j = 0; j < 4; ++j) {
    const Vec3d m = tet_face_vector(s, j);
    const Vec3d a = fx.x[kFace[j][0]], b = fx.x[kFace[j][1]], c = fx.x[kFace[j][2]];
    EXPECT_NEAR(norm(m), norm(cross(b - a, c - a)), 1e-18);
    EXPECT_GT(dot(m, fx.x[j] - a), 0.0) << "m_" << j << " must point towards vertex " << j;
  }
  // Packed form rebuilds the same shape bit for bit.
  const TetShape<double> p = tet_shape_from_packed(s.grad[1], s.grad[2], s.grad[3], s.volume);
  for (int j = 0; j < 4; ++j) EXPECT_EQ(norm(p.grad[j] - s.grad[j]), 0.0);
}

// Central differences of the energy against the force, per component.
template <class ForceFn>
void check_force_against_energy(const ForceFn& fn, const Vec3d u0[4], double rel_tol) {
  Vec3d f[4];
  fn(u0, f);
  const double scale = max_norm(f);
  ASSERT_GT(scale, 0.0);
  const double h = 1e-6 * 1e-6;  // 1e-6 of the element size
  for (int j = 0; j < 4; ++j)
    for (int i = 0; i < 3; ++i) {
      Vec3d up[4], um[4], tmp[4];
      for (int k = 0; k < 4; ++k) up[k] = um[k] = u0[k];
      up[j][i] += h;
      um[j][i] -= h;
      const double fd = -(fn(up, tmp) - fn(um, tmp)) / (2 * h);
      EXPECT_NEAR(f[j][i], fd, rel_tol * scale) << "vertex " << j << " component " << i;
    }
}

TEST(FemElement, SvkForceIsMinusTheEnergyGradient) {
  Fixture fx;
  Vec3d u[4];
  displacements(0.3, u);  // 30 % strains: the cubic and quartic terms matter
  check_force_against_energy(
      [&](const Vec3d* uu, Vec3d* f) {
        return tet_svk_forces(fx.shape, fx.lame.lambda, fx.lame.mu, uu, f);
      },
      u, 1e-7);
}

TEST(FemElement, LinearForceIsMinusTheEnergyGradient) {
  Fixture fx;
  Vec3d u[4];
  displacements(0.3, u);
  check_force_against_energy(
      [&](const Vec3d* uu, Vec3d* f) {
        return tet_linear_forces(fx.shape, fx.lame.lambda, fx.lame.mu, uu, f);
      },
      u, 1e-7);
}

TEST(FemElement, TensorFormsAreMinusTheirEnergyGradient) {
  Fixture fx;
  Vec3d u[4];
  displacements(0.3, u);
  std::vector<double> t(kSvkTensorSize);
  svk_mass_tensors(fx.shape, fx.lame.lambda, fx.lame.mu, t.data());
  check_force_against_energy(
      [&](const Vec3d* uu, Vec3d* f) { return tet_svk_forces_tensor(t.data(), uu, f); }, u, 1e-7);
}

// Central differences of the force (force_fn(u, f)) against the stiffness (stiffness_fn(u, k)),
// column by column, and the stiffness's symmetry.
template <class StiffnessFn, class ForceFn>
void check_stiffness_of(const StiffnessFn& stiffness_fn, const ForceFn& force_fn,
                        const Vec3d u0[4]) {
  double k[144];
  stiffness_fn(u0, k);
  double kmax = 0;
  for (double v : k) kmax = std::max(kmax, std::abs(v));
  const double h = 1e-12;
  for (int b = 0; b < 4; ++b)
    for (int j = 0; j < 3; ++j) {
      Vec3d up[4], um[4], fp[4], fm[4];
      for (int q = 0; q < 4; ++q) up[q] = um[q] = u0[q];
      up[b][j] += h;
      um[b][j] -= h;
      force_fn(up, fp);
      force_fn(um, fm);
      for (int a = 0; a < 4; ++a)
        for (int i = 0; i < 3; ++i) {
          const double fd = -(fp[a][i] - fm[a][i]) / (2 * h);  // df = -K du
          EXPECT_NEAR(k[(3 * a + i) * 12 + 3 * b + j], fd, 1e-6 * kmax);
        }
    }
  for (int r = 0; r < 12; ++r)
    for (int c = 0; c < 12; ++c) EXPECT_NEAR(k[r * 12 + c], k[c * 12 + r], 1e-12 * kmax);
}

void check_stiffness(const Fixture& fx, bool svk, const Vec3d u0[4]) {
  const double lambda = fx.lame.lambda, mu = fx.lame.mu;
  if (svk)
    check_stiffness_of(
        [&](const Vec3d* u, double* k) { tet_svk_stiffness(fx.shape, lambda, mu, u, k); },
        [&](const Vec3d* u, Vec3d* f) { tet_svk_forces(fx.shape, lambda, mu, u, f); }, u0);
  else
    check_stiffness_of(
        [&](const Vec3d*, double* k) { tet_linear_stiffness(fx.shape, lambda, mu, k); },
        [&](const Vec3d* u, Vec3d* f) { tet_linear_forces(fx.shape, lambda, mu, u, f); }, u0);
}

TEST(FemElement, SvkStiffnessMatchesForceDifferences) {
  Fixture fx;
  Vec3d u[4];
  displacements(0.3, u);
  check_stiffness(fx, true, u);
}

TEST(FemElement, LinearStiffnessMatchesForceDifferences) {
  Fixture fx;
  Vec3d u[4];
  displacements(0.3, u);
  check_stiffness(fx, false, u);
}

TEST(FemElement, SvkStiffnessAtRestIsTheLinearStiffness) {
  Fixture fx;
  const Vec3d zero[4] = {};
  double ks[144], kl[144];
  tet_svk_stiffness(fx.shape, fx.lame.lambda, fx.lame.mu, zero, ks);
  tet_linear_stiffness(fx.shape, fx.lame.lambda, fx.lame.mu, kl);
  double kmax = 0;
  for (double v : kl) kmax = std::max(kmax, std::abs(v));
  for (int i = 0; i < 144; ++i) EXPECT_NEAR(ks[i], kl[i], 1e-13 * kmax);
}

TEST(FemElement, SvkTensorFormsEqualTheGradientFormTo1e12) {
  Fixture fx;
  for (double strain : {1e-4, 0.05, 0.5, 1.5}) {
    Vec3d u[4], fg[4], fs[4], fr[4];
    displacements(strain, u);
    std::vector<double> t(kSvkTensorSize);
    svk_mass_tensors(fx.shape, fx.lame.lambda, fx.lame.mu, t.data());
    const double wg = tet_svk_forces(fx.shape, fx.lame.lambda, fx.lame.mu, u, fg);
    const double ws = tet_svk_forces_tensor(t.data(), u, fs);
    const double wr = tet_svk_forces_rebuilt(fx.shape, fx.lame.lambda, fx.lame.mu, u, fr);
    const double scale = max_norm(fg);
    for (int j = 0; j < 4; ++j) {
      EXPECT_LE(norm(fs[j] - fg[j]), 1e-12 * scale) << "strain " << strain << " vertex " << j;
      EXPECT_LE(norm(fr[j] - fg[j]), 1e-12 * scale) << "strain " << strain << " vertex " << j;
    }
    EXPECT_NEAR(ws, wg, 1e-12 * wg);
    EXPECT_NEAR(wr, wg, 1e-12 * wg);
  }
}

TEST(FemElement, LinearTensorFormsEqualTheGradientForm) {
  Fixture fx;
  Vec3d u[4], fg[4], fs[4], fr[4];
  displacements(0.2, u);
  std::vector<double> k(kTensorBSize), t(kSvkTensorSize);
  linear_mass_tensor(fx.shape, fx.lame.lambda, fx.lame.mu, k.data());
  svk_mass_tensors(fx.shape, fx.lame.lambda, fx.lame.mu, t.data());
  const double wg = tet_linear_forces(fx.shape, fx.lame.lambda, fx.lame.mu, u, fg);
  const double ws = tet_linear_forces_tensor(k.data(), u, fs);
  const double wr = tet_linear_forces_rebuilt(fx.shape, fx.lame.lambda, fx.lame.mu, u, fr);
  const double scale = max_norm(fg);
  for (int j = 0; j < 4; ++j) {
    EXPECT_LE(norm(fs[j] - fg[j]), 1e-12 * scale);
    EXPECT_LE(norm(fr[j] - fg[j]), 1e-12 * scale);
  }
  EXPECT_NEAR(ws, wg, 1e-12 * wg);
  EXPECT_NEAR(wr, wg, 1e-12 * wg);
  // K = 2 B, entry by entry (Ladjal et al. eq. 3 against the B of docs/physics.md).
  for (int i = 0; i < kTensorBSize; ++i) EXPECT_NEAR(k[i], 2 * t[i], 1e-14 * std::abs(k[i]) + 1e-30);
}

TEST(FemElement, MassTensorsHaveTheirSymmetries) {
  Fixture fx;
  std::vector<double> t(kSvkTensorSize);
  svk_mass_tensors(fx.shape, fx.lame.lambda, fx.lame.mu, t.data());
  const double* b = t.data();
  const double* c = b + kTensorBSize;
  for (int j = 0; j < 4; ++j)
    for (int k = 0; k < 4; ++k) {
      for (int r = 0; r < 3; ++r)
        for (int q = 0; q < 3; ++q)  // B_jk = B_kj^T
          EXPECT_NEAR(b[(4 * j + k) * 9 + 3 * r + q], b[(4 * k + j) * 9 + 3 * q + r],
                      1e-14 * std::abs(b[(4 * j + k) * 9 + 3 * r + q]));
      for (int l = 0; l < 4; ++l)
        for (int r = 0; r < 3; ++r)  // C_jkl = C_kjl
          EXPECT_NEAR(c[((4 * j + k) * 4 + l) * 3 + r], c[((4 * k + j) * 4 + l) * 3 + r],
                      1e-14 * std::abs(c[((4 * j + k) * 4 + l) * 3 + r]));
    }
  // Sum_k B_jk = 0 because sum_k m_k = 0: a rigid translation costs no energy.
  for (int j = 0; j < 4; ++j)
    for (int e = 0; e < 9; ++e) {
      double sum = 0, mag = 0;
      for (int k = 0; k < 4; ++k) {
        sum += b[(4 * j + k) * 9 + e];
        mag += std::abs(b[(4 * j + k) * 9 + e]);
      }
      EXPECT_LE(std::abs(sum), 1e-13 * mag + 1e-30);
    }
}

// Relative force difference between SVK and linear at strain amplitude `strain`.
double svk_linear_difference(const Fixture& fx, double strain) {
  Vec3d u[4], fs[4], fl[4];
  displacements(strain, u);
  tet_svk_forces(fx.shape, fx.lame.lambda, fx.lame.mu, u, fs);
  tet_linear_forces(fx.shape, fx.lame.lambda, fx.lame.mu, u, fl);
  double diff = 0;
  for (int j = 0; j < 4; ++j) diff = std::max(diff, norm(fs[j] - fl[j]));
  return diff / max_norm(fl);
}

TEST(FemElement, LinearEqualsSvkForTinyStrains) {
  Fixture fx;
  // The models differ by terms quadratic in the strain, amplified by lambda / mu (~50 at
  // nu = 0.49) through tr(E): relative difference ~ (lambda / mu) * strain.
  const double d6 = svk_linear_difference(fx, 1e-6);
  const double d7 = svk_linear_difference(fx, 1e-7);
  EXPECT_LT(d6, 1e-4);
  EXPECT_NEAR(d7 / d6, 0.1, 0.01);  // first order in the strain: the models agree in the limit
  // And at 20 % strain they differ by more than 5 %.
  EXPECT_GT(svk_linear_difference(fx, 0.2), 0.05);
}

TEST(FemElement, RigidRotationGivesNoSvkForceButASpuriousLinearOne) {
  Fixture fx;
  const double theta = 0.5;  // rad, about an oblique axis
  const Vec3d axis = Vec3d{1, 2, 2} / 3.0;
  // Rodrigues: R = I + sin K + (1 - cos) K^2 with K the cross-product matrix of the axis.
  const Mat3d kx{{{0, -axis.z, axis.y}, {axis.z, 0, -axis.x}, {-axis.y, axis.x, 0}}};
  const Mat3d r = Mat3d::identity() + std::sin(theta) * kx + (1 - std::cos(theta)) * (kx * kx);
  Vec3d u[4], fs[4], fl[4], fref[4];
  for (int j = 0; j < 4; ++j) u[j] = r * fx.x[j] - fx.x[j] + Vec3d{3e-6, -1e-6, 2e-6};
  const double ws = tet_svk_forces(fx.shape, fx.lame.lambda, fx.lame.mu, u, fs);
  tet_linear_forces(fx.shape, fx.lame.lambda, fx.lame.mu, u, fl);
  // Force scale: a 10 % stretch of the same element.
  Vec3d us[4];
  for (int j = 0; j < 4; ++j) us[j] = Vec3d{0.1 * fx.x[j].x, 0, 0};
  tet_svk_forces(fx.shape, fx.lame.lambda, fx.lame.mu, us, fref);
  const double scale = max_norm(fref);
  EXPECT_LE(max_norm(fs), 1e-10 * scale);
  EXPECT_LE(std::abs(ws), 1e-18);
  // The linear model sees strain sym(R - I) = (1 - cos theta) (K^2 part): ~12 % here.
  EXPECT_GT(max_norm(fl), 0.5 * scale);
}

TEST(FemElement, HealthFlagsInversionAndCollapse) {
  Mat3d h = Mat3d::zero();
  EXPECT_EQ(tet_health(h), 0u);
  // Uniaxial compression to stretch 0.6 (above 1/sqrt(3) = 0.577): healthy.
  h.m[0][0] = -0.4;
  EXPECT_EQ(tet_health(h), 0u);
  // Stretch 0.55: collapsing, not inverted.
  h.m[0][0] = -0.45;
  EXPECT_EQ(tet_health(h), uint32_t{kElementCollapsing});
  // Stretch -0.2 (a vertex pushed through the opposite face): inverted, and |s| < 1/sqrt(3).
  h.m[0][0] = -1.2;
  EXPECT_EQ(tet_health(h), uint32_t{kElementInverted | kElementCollapsing});
  // A pure reflection: inverted but every stretch is 1 in magnitude.
  h.m[0][0] = -2.0;
  EXPECT_EQ(tet_health(h), uint32_t{kElementInverted});
}

TEST(FemElement, SymmetricEigenDecomposition) {
  const Mat3d a{{{4.0, 1.0, -2.0}, {1.0, 2.0, 0.5}, {-2.0, 0.5, 3.0}}};
  double ev[3];
  Mat3d v;
  symmetric_eigen3(a, ev, &v);
  for (int i = 0; i < 3; ++i) {
    const Vec3d x{v.m[0][i], v.m[1][i], v.m[2][i]};
    EXPECT_NEAR(norm(x), 1.0, 1e-14);
    EXPECT_LE(norm(a * x - ev[i] * x), 1e-13);
  }
  EXPECT_NEAR(ev[0] + ev[1] + ev[2], trace(a), 1e-13);
}

TEST(FemElement, ClampedSvkEqualsSvkWhereNothingIsClamped) {
  Fixture fx;
  Vec3d u[4];
  displacements(0.3, u);
  const Mat3d h = tet_displacement_gradient(fx.shape, u);
  ASSERT_EQ(tet_health(h), 0u);
  Mat3d p, pc;
  const double psi = svk_first_piola(h, fx.lame.lambda, fx.lame.mu, &p);
  const double psic =
      svk_first_piola_clamped(h, fx.lame.lambda, fx.lame.mu, kSvkCollapseStretch, &pc);
  double pmax = 0;
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c) pmax = std::max(pmax, std::abs(p.m[r][c]));
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c) EXPECT_NEAR(pc.m[r][c], p.m[r][c], 1e-10 * pmax);
  EXPECT_NEAR(psic, psi, 1e-10 * psi);
}

TEST(FemElement, ClampedSvkPushesAnInvertedElementBack) {
  // Unit right tetrahedron; vertex 3 pushed from z = 1 to z = -1: F = diag(1, 1, -1), a mirror
  // image, which plain SVK sees as unstrained (E = 0): no force at all.
  const Vec3d x[4] = {{0, 0, 0}, {1, 0, 0}, {0, 1, 0}, {0, 0, 1}};
  const TetShape<double> s = tet_shape_from_rest(x[0], x[1], x[2], x[3]);
  const Lame l = lame_from_young_poisson(1.0, 0.3);
  const Vec3d u[4] = {{0, 0, 0}, {0, 0, 0}, {0, 0, 0}, {0, 0, -2}};
  const Mat3d h = tet_displacement_gradient(s, u);
  EXPECT_TRUE(tet_health(h) & kElementInverted);
  Vec3d f[4];
  tet_svk_forces(s, l.lambda, l.mu, u, f);
  EXPECT_LE(max_norm(f), 1e-14);
  Mat3d p;
  svk_first_piola_clamped(h, l.lambda, l.mu, kSvkCollapseStretch, &p);
  tet_forces_from_stress(s, p, f);
  // The clamped element pushes vertex 3 back up through the base towards its rest side.
  EXPECT_GT(f[3].z, 0.1 * l.mu * s.volume);
  EXPECT_NEAR(f[3].x, 0.0, 1e-12);
  EXPECT_NEAR(f[3].y, 0.0, 1e-12);
}

// Relative force error of the float32 element against float64 at 10 % strain, with the element
// rigidly offset by `offset` [m]; `edges_in_double` forms u_j - u_0 in float64 first.
double float32_element_error(const Fixture& fx, Vec3d offset, bool edges_in_double) {
  Vec3d u[4], fd[4];
  displacements(0.1, u);
  for (int j = 0; j < 4; ++j) u[j] += offset;
  tet_svk_forces(fx.shape, fx.lame.lambda, fx.lame.mu, u, fd);
  const TetShape<float> sf = tet_shape_cast<float>(fx.shape);
  Mat3f h;
  if (edges_in_double) {
    const Vec3f du[3] = {vec_cast<float>(u[1] - u[0]), vec_cast<float>(u[2] - u[0]),
                         vec_cast<float>(u[3] - u[0])};
    h = tet_displacement_gradient_from_edges(sf, du);
  } else {
    Vec3f uf[4];
    for (int j = 0; j < 4; ++j) uf[j] = vec_cast<float>(u[j]);
    h = tet_displacement_gradient(sf, uf);
  }
  Mat3f p;
  svk_first_piola(h, static_cast<float>(fx.lame.lambda), static_cast<float>(fx.lame.mu), &p);
  Vec3f ff[4];
  tet_forces_from_stress(sf, p, ff);
  double err = 0;
  for (int j = 0; j < 4; ++j) err = std::max(err, norm(vec_cast<double>(ff[j]) - fd[j]));
  return err / max_norm(fd);
}

TEST(FemElement, Float32ElementAgreesWithDoubleWhenEdgesAreFormedInDouble) {
  // Precision evidence for a float32 kernel (docs/physics.md).
  Fixture fx;
  const Vec3d offset{20e-6, -15e-6, 5e-6};  // the element sits 25 um from its rest place
  const double at_rest = float32_element_error(fx, Vec3d{0, 0, 0}, false);
  const double offset_float = float32_element_error(fx, offset, false);
  const double offset_double_edges = float32_element_error(fx, offset, true);
  char text[160];
  std::snprintf(text, sizeof text, "at rest %.2e, 25 um offset: float u %.2e, double edges %.2e",
                at_rest, offset_float, offset_double_edges);
  RecordProperty("float32_relative_force_error", text);
  EXPECT_LT(at_rest, 1e-5);
  EXPECT_LT(offset_double_edges, 1e-5);
  // Rounding the 25 um displacements to float32 loses |u| / h * 6e-8 ~ 1.5e-6 of strain, which
  // lambda / mu ~ 50 amplifies: two orders of magnitude worse.
  EXPECT_GT(offset_float, 10 * offset_double_edges);
}

// ---------------------------------------------------------------------------------------------
// Stable neo-Hookean.

// A fixed set of deformation gradients: general, compressed, nearly flat, inverted (J < 0) and
// strongly inverted, each rotated on both sides by seeded random rotations.
std::vector<Mat3d> snh_test_gradients() {
  std::mt19937_64 rng(20180501);
  std::uniform_real_distribution<double> uni(-1.0, 1.0);
  auto rotation = [&] {
    Vec3d axis{uni(rng), uni(rng), uni(rng)};
    axis = axis / norm(axis);
    const double theta = 3.0 * uni(rng);
    const Mat3d kx{{{0, -axis.z, axis.y}, {axis.z, 0, -axis.x}, {-axis.y, axis.x, 0}}};
    return Mat3d::identity() + std::sin(theta) * kx + (1 - std::cos(theta)) * (kx * kx);
  };
  const double stretches[][3] = {{1.2, 0.9, 1.05}, {0.5, 0.7, 0.95},  {0.3, 0.5, 0.9},
                                 {0.1, 0.8, 1.1},  {0.02, 0.9, 1.0},  {0.8, 0.6, -0.3},
                                 {0.5, 0.5, -0.5}, {1.3, 0.4, -0.05}, {0.2, 0.2, -0.7}};
  std::vector<Mat3d> out;
  for (const auto& s : stretches) {
    Mat3d d = Mat3d::zero();
    for (int i = 0; i < 3; ++i) d.m[i][i] = s[i];
    out.push_back(rotation() * d * rotation());
  }
  // And general matrices near the identity (not of the form above by construction).
  for (int k = 0; k < 3; ++k) {
    Mat3d f = Mat3d::identity();
    for (int r = 0; r < 3; ++r)
      for (int c = 0; c < 3; ++c) f.m[r][c] += 0.4 * uni(rng);
    out.push_back(f);
  }
  return out;
}

double snh_energy(const Mat3d& f, const Lame& l) {
  Mat3d p;
  double jm1;
  return snh_first_piola(f - Mat3d::identity(), l.lambda, l.mu, &p, &jm1);
}

Mat3d snh_stress(const Mat3d& f, const Lame& l) {
  Mat3d p;
  double jm1;
  snh_first_piola(f - Mat3d::identity(), l.lambda, l.mu, &p, &jm1);
  return p;
}

double max_abs(const Mat3d& a) {
  double m = 0;
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c) m = std::max(m, std::abs(a.m[r][c]));
  return m;
}

TEST(FemElement, SnhStressAndStiffnessMatchFiniteDifferencesIncludingInverted) {
  const Lame l = lame_from_young_poisson(17.9e3, 0.49);
  std::mt19937_64 rng(7);
  std::uniform_real_distribution<double> uni(-1.0, 1.0);
  int inverted = 0;
  for (const Mat3d& f : snh_test_gradients()) {
    const double j = determinant(f);
    inverted += j < 0 ? 1 : 0;
    const Mat3d p = snh_stress(f, l);
    // The law's own J - 1 and the determinant agree.
    Mat3d pp;
    double jm1;
    snh_first_piola(f - Mat3d::identity(), l.lambda, l.mu, &pp, &jm1);
    EXPECT_NEAR(1.0 + jm1, j, 1e-14);
    // P = dPsi/dF, entry by entry.
    const double h = 1e-6;
    const double pscale = max_abs(p) + l.mu;
    for (int r = 0; r < 3; ++r)
      for (int c = 0; c < 3; ++c) {
        Mat3d fp = f, fm = f;
        fp.m[r][c] += h;
        fm.m[r][c] -= h;
        const double fd = (snh_energy(fp, l) - snh_energy(fm, l)) / (2 * h);
        EXPECT_NEAR(p.m[r][c], fd, 1e-7 * pscale) << "J " << j << " entry " << r << c;
      }
    // dP[dF] = derivative of P along dF, for random directions.
    for (int k = 0; k < 3; ++k) {
      Mat3d df;
      for (int r = 0; r < 3; ++r)
        for (int c = 0; c < 3; ++c) df.m[r][c] = uni(rng);
      const Mat3d dp = snh_stress_differential(f - Mat3d::identity(), l.lambda, l.mu, df);
      const Mat3d fd = (1.0 / (2 * h)) * (snh_stress(f + h * df, l) - snh_stress(f - h * df, l));
      const double scale = max_abs(fd) + l.mu;
      for (int r = 0; r < 3; ++r)
        for (int c = 0; c < 3; ++c)
          EXPECT_NEAR(dp.m[r][c], fd.m[r][c], 1e-7 * scale) << "J " << j << " entry " << r << c;
      // Symmetry of the Hessian: dF2 : dP[dF1] = dF1 : dP[dF2].
      Mat3d df2;
      for (int r = 0; r < 3; ++r)
        for (int c = 0; c < 3; ++c) df2.m[r][c] = uni(rng);
      const Mat3d dp2 = snh_stress_differential(f - Mat3d::identity(), l.lambda, l.mu, df2);
      EXPECT_NEAR(frobenius_dot(df2, dp), frobenius_dot(df, dp2), 1e-12 * scale * 9);
    }
  }
  EXPECT_GE(inverted, 4);  // the set does reach J < 0
}

// The Fixture's tetrahedron with vertex 3 pushed through the opposite face: J < 0.
void inverted_displacements(Vec3d u[4]) {
  displacements(0.2, u);
  u[3] = u[3] + Vec3d{0.1e-6, -0.2e-6, -1.6e-6};
}

TEST(FemElement, SnhForceIsMinusTheEnergyGradient) {
  Fixture fx;
  auto fn = [&](const Vec3d* uu, Vec3d* f) {
    uint32_t bits;
    return tet_snh_forces(fx.shape, fx.lame.lambda, fx.lame.mu, uu, f, &bits);
  };
  Vec3d u[4];
  displacements(0.3, u);
  check_force_against_energy(fn, u, 1e-7);
  inverted_displacements(u);
  ASSERT_LT(determinant(Mat3d::identity() + tet_displacement_gradient(fx.shape, u)), 0.0);
  check_force_against_energy(fn, u, 1e-7);
}

TEST(FemElement, SnhStiffnessMatchesForceDifferencesIncludingInverted) {
  Fixture fx;
  auto kfn = [&](const Vec3d* uu, double* k) {
    tet_snh_stiffness(fx.shape, fx.lame.lambda, fx.lame.mu, uu, k);
  };
  auto ffn = [&](const Vec3d* uu, Vec3d* f) {
    uint32_t bits;
    tet_snh_forces(fx.shape, fx.lame.lambda, fx.lame.mu, uu, f, &bits);
  };
  Vec3d u[4];
  displacements(0.3, u);
  check_stiffness_of(kfn, ffn, u);
  inverted_displacements(u);
  check_stiffness_of(kfn, ffn, u);
}

TEST(FemElement, SnhRestStateHasZeroEnergyAndForce) {
  Fixture fx;
  // At rest and under a rigid translation: exactly zero (H is exactly zero there).
  for (const Vec3d shift : {Vec3d{0, 0, 0}, Vec3d{3e-6, -1e-6, 2e-6}}) {
    const Vec3d u[4] = {shift, shift, shift, shift};
    Vec3d f[4];
    uint32_t bits = 7;
    EXPECT_EQ(tet_snh_forces(fx.shape, fx.lame.lambda, fx.lame.mu, u, f, &bits), 0.0);
    EXPECT_EQ(max_norm(f), 0.0);
    EXPECT_EQ(bits, 0u);
  }
}

TEST(FemElement, SnhIsRotationInvariant) {
  const Lame l = lame_from_young_poisson(17.9e3, 0.49);
  const Vec3d axis = Vec3d{1, 2, 2} / 3.0;
  const Mat3d kx{{{0, -axis.z, axis.y}, {axis.z, 0, -axis.x}, {-axis.y, axis.x, 0}}};
  for (double theta : {0.5, 2.5}) {
    const Mat3d r = Mat3d::identity() + std::sin(theta) * kx + (1 - std::cos(theta)) * (kx * kx);
    for (const Mat3d& f : snh_test_gradients()) {
      // Psi(R F) = Psi(F), P(R F) = R P(F).
      const double psi = snh_energy(f, l);
      EXPECT_NEAR(snh_energy(r * f, l), psi, 1e-12 * (std::abs(psi) + l.mu));
      const Mat3d p = snh_stress(f, l), pr = snh_stress(r * f, l);
      EXPECT_LE(max_abs(pr - r * p), 1e-12 * (max_abs(p) + l.mu));
    }
  }
  // A rigidly rotated and translated element: no force, no energy (as SVK; linear would push).
  Fixture fx;
  const double theta = 0.5;
  const Mat3d r = Mat3d::identity() + std::sin(theta) * kx + (1 - std::cos(theta)) * (kx * kx);
  Vec3d u[4], f[4], us[4], fref[4];
  for (int j = 0; j < 4; ++j) u[j] = r * fx.x[j] - fx.x[j] + Vec3d{3e-6, -1e-6, 2e-6};
  uint32_t bits;
  const double w = tet_snh_forces(fx.shape, fx.lame.lambda, fx.lame.mu, u, f, &bits);
  for (int j = 0; j < 4; ++j) us[j] = Vec3d{0.1 * fx.x[j].x, 0, 0};
  tet_snh_forces(fx.shape, fx.lame.lambda, fx.lame.mu, us, fref, &bits);
  EXPECT_LE(max_norm(f), 1e-10 * max_norm(fref));
  EXPECT_LE(std::abs(w), 1e-18);
}

TEST(FemElement, SnhSmallStrainLimitIsLinearElasticity) {
  Fixture fx;
  // Forces at a 1e-6 strain: the linear model's with the material's (lambda, mu), to 1e-3
  // (the difference is second order: ~ (lambda / mu) 1e-6).
  Vec3d u[4], fs[4], fl[4];
  displacements(1e-6, u);
  uint32_t bits;
  tet_snh_forces(fx.shape, fx.lame.lambda, fx.lame.mu, u, fs, &bits);
  tet_linear_forces(fx.shape, fx.lame.lambda, fx.lame.mu, u, fl);
  double diff = 0;
  for (int j = 0; j < 4; ++j) diff = std::max(diff, norm(fs[j] - fl[j]));
  EXPECT_LT(diff / max_norm(fl), 1e-3);
  EXPECT_LT(diff / max_norm(fl), 1e-4);  // in fact
  // And the tangent at rest is the linear stiffness, entry by entry.
  const Vec3d zero[4] = {};
  double ks[144], kl[144];
  tet_snh_stiffness(fx.shape, fx.lame.lambda, fx.lame.mu, zero, ks);
  tet_linear_stiffness(fx.shape, fx.lame.lambda, fx.lame.mu, kl);
  double kmax = 0;
  for (double v : kl) kmax = std::max(kmax, std::abs(v));
  for (int i = 0; i < 144; ++i) EXPECT_NEAR(ks[i], kl[i], 1e-13 * kmax);
}

TEST(FemElement, SnhResistsCompressionWhereSvkGivesWay) {
  // Uniaxial F = diag(s, 1, 1): SNH's P_11 = (mu + lambda_s)(s - 1) grows in magnitude all the
  // way to s = 0 and through it; SVK's P_11 = s (lambda + 2 mu)(s^2 - 1)/2 peaks at 1/sqrt(3)
  // and is zero when flat.
  const Lame l = lame_from_young_poisson(17.9e3, 0.45);
  double previous = 0;
  for (double s = 0.95; s > -0.5; s -= 0.05) {
    Mat3d h = Mat3d::zero();
    h.m[0][0] = s - 1;
    const double p11 = snh_stress(Mat3d::identity() + h, l).m[0][0];
    EXPECT_NEAR(p11, (l.mu + snh_lambda(l.lambda, l.mu)) * (s - 1), 1e-9 * l.lambda);
    EXPECT_LT(p11, previous) << "stretch " << s;
    previous = p11;
  }
  Mat3d flat = Mat3d::zero();
  flat.m[0][0] = -1;
  Mat3d p_svk;
  svk_first_piola(flat, l.lambda, l.mu, &p_svk);
  EXPECT_EQ(p_svk.m[0][0], 0.0);
  EXPECT_LT(snh_stress(Mat3d::identity() + flat, l).m[0][0], -l.lambda);
}

TEST(FemElement, SnhPushesAnInvertedElementBackAndSaysSo) {
  // The tetrahedron of ClampedSvkPushesAnInvertedElementBack: F = diag(1, 1, -1), where plain
  // SVK feels nothing. SNH pushes vertex 3 back up, with a finite energy, and flags the
  // inversion (informational).
  const Vec3d x[4] = {{0, 0, 0}, {1, 0, 0}, {0, 1, 0}, {0, 0, 1}};
  const TetShape<double> s = tet_shape_from_rest(x[0], x[1], x[2], x[3]);
  const Lame l = lame_from_young_poisson(1.0, 0.3);
  const Vec3d u[4] = {{0, 0, 0}, {0, 0, 0}, {0, 0, 0}, {0, 0, -2}};
  Vec3d f[4];
  uint32_t bits = 0;
  const double w = tet_snh_forces(s, l.lambda, l.mu, u, f, &bits);
  EXPECT_EQ(bits, uint32_t{kElementInverted});
  EXPECT_TRUE(std::isfinite(w));
  EXPECT_GT(w, 0.0);
  EXPECT_GT(f[3].z, 0.1 * l.mu * s.volume);
  EXPECT_NEAR(f[3].x, 0.0, 1e-12);
  EXPECT_NEAR(f[3].y, 0.0, 1e-12);
  // Flat (J = 0): defined, flagged, pushing back.
  const Vec3d flat[4] = {{0, 0, 0}, {0, 0, 0}, {0, 0, 0}, {0, 0, -1}};
  EXPECT_TRUE(std::isfinite(tet_snh_forces(s, l.lambda, l.mu, flat, f, &bits)));
  EXPECT_EQ(bits, uint32_t{kElementInverted});
  EXPECT_GT(f[3].z, 0.1 * l.mu * s.volume);
}

TEST(FemElement, SnhFloat32ElementKeepsSmallStrains) {
  // The stress is formed from H without subtracting numbers of order one, so float32 keeps
  // the digits of small strains (the CUDA kernels run it in float32).
  Fixture fx;
  const TetShape<float> sf = tet_shape_cast<float>(fx.shape);
  char text[200];
  double errors[3];
  const double strains[3] = {1e-6, 1e-3, 0.2};
  for (int k = 0; k < 3; ++k) {
    Vec3d u[4], fd[4];
    displacements(strains[k], u);
    uint32_t bits;
    tet_snh_forces(fx.shape, fx.lame.lambda, fx.lame.mu, u, fd, &bits);
    Vec3f uf[4], ff[4];
    for (int j = 0; j < 4; ++j) uf[j] = vec_cast<float>(u[j]);
    tet_snh_forces(sf, static_cast<float>(fx.lame.lambda), static_cast<float>(fx.lame.mu), uf, ff,
                   &bits);
    double err = 0;
    for (int j = 0; j < 4; ++j) err = std::max(err, norm(vec_cast<double>(ff[j]) - fd[j]));
    errors[k] = err / max_norm(fd);
  }
  // The same stress written with F (P = mu (F - cof F) + lambda_s (det F - 1) cof F, F = I + H
  // rounded to float32 first) at the 1e-6 strain: the order-one terms cancel.
  Vec3d u[4];
  displacements(1e-6, u);
  const Mat3d h = tet_displacement_gradient(fx.shape, u);
  Mat3d p;
  double jm1;
  snh_first_piola(h, fx.lame.lambda, fx.lame.mu, &p, &jm1);
  Mat3f f;
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c) f.m[r][c] = static_cast<float>(h.m[r][c]) + (r == c ? 1.0f : 0.0f);
  const Mat3f cof = cofactor(f);
  const float mu = static_cast<float>(fx.lame.mu);
  const float lam = snh_lambda(static_cast<float>(fx.lame.lambda), mu);
  const float j_minus_one = determinant(f) - 1.0f;
  double naive_error = 0;
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c) {
      const float pf = mu * (f.m[r][c] - cof.m[r][c]) + lam * j_minus_one * cof.m[r][c];
      naive_error = std::max(naive_error, std::abs(static_cast<double>(pf) - p.m[r][c]));
    }
  naive_error /= max_abs(p);
  std::snprintf(text, sizeof text,
                "strain 1e-6: %.2e, 1e-3: %.2e, 0.2: %.2e; F-form stress at 1e-6: %.2e", errors[0],
                errors[1], errors[2], naive_error);
  RecordProperty("snh_float32_relative_force_error", text);
  for (double e : errors) EXPECT_LT(e, 1e-5) << text;
  EXPECT_GT(naive_error, 1e-2) << text;
}

}  // namespace
}  // namespace zona

namespace zona {
namespace {

// Largest eigenvalue magnitude of a symmetric 12 x 12 matrix by power iteration.
double largest_eigenvalue(const double k[144]) {
  double x[12], y[12];
  for (int i = 0; i < 12; ++i) x[i] = 1.0 + 0.1 * i;
  double lambda = 0;
  for (int it = 0; it < 2000; ++it) {
    double n = 0;
    for (int i = 0; i < 12; ++i) {
      y[i] = 0;
      for (int j = 0; j < 12; ++j) y[i] += k[12 * i + j] * x[j];
      n += y[i] * y[i];
    }
    n = std::sqrt(n);
    if (!(n > 0)) return 0;
    lambda = n;
    for (int i = 0; i < 12; ++i) x[i] = y[i] / n;
  }
  return lambda;
}

TEST(FemElement, StiffeningFollowsTheLargestStiffnessEigenvalue) {
  // tet_stiffening (the dynamic mass scaling's measure) against the element's own tangent: the
  // growth of its largest eigenvalue from rest, for SNH and SVK, at rest, rotated, compressed,
  // crushed flat and stretched as under a needle tip (stretches 0.02 / 3 / 6.2, measured on a
  // 10k-vertex cell), and inverted. The estimate is 1 at rest and under a rotation, never more
  // than 2x below the true growth and at most 6x above it.
  const Vec3d x[4] = {{0, 0, 0}, {1, 0.1, 0}, {0.2, 0.9, 0}, {0.1, 0.2, 1.1}};
  const TetShape<double> s = tet_shape_from_rest(x[0], x[1], x[2], x[3]);
  const Lame l = lame_from_young_poisson(17.9e3, 0.49);
  const double c = std::cos(0.7), sn = std::sin(0.7);
  std::vector<Mat3d> fs = {Mat3d::identity(),
                           Mat3d{{{c, -sn, 0}, {sn, c, 0}, {0, 0, 1}}},
                           Mat3d{{{0.5, 0, 0}, {0, 1, 0}, {0, 0, 1}}},
                           Mat3d{{{0.1, 0, 0}, {0, 1.2, 0}, {0, 0, 1.2}}},
                           Mat3d{{{0.02, 0, 0}, {0, 3.0, 0}, {0, 0, 6.2}}},
                           Mat3d{{{0.3, 0.8, 0.1}, {-0.2, 2.0, 0.4}, {0.1, 0.5, 1.5}}},
                           Mat3d{{{1, 0, 0}, {0, 1, 0}, {0, 0, -0.5}}}};
  auto stiffness = [&](const Mat3d& f, bool snh, double k[144]) {
    Vec3d u[4];
    for (int j = 0; j < 4; ++j) u[j] = (f - Mat3d::identity()) * x[j];
    if (snh)
      tet_snh_stiffness(s, l.lambda, l.mu, u, k);
    else
      tet_svk_stiffness(s, l.lambda, l.mu, u, k);
  };
  for (bool snh : {true, false}) {
    double k0[144];
    stiffness(Mat3d::identity(), snh, k0);
    const double rest = largest_eigenvalue(k0);
    for (size_t i = 0; i < fs.size(); ++i) {
      if (!snh && i == fs.size() - 1) continue;  // plain SVK has no tangent worth the name there
      double k[144];
      stiffness(fs[i], snh, k);
      const double truth = largest_eigenvalue(k) / rest;
      const double estimate =
          tet_stiffening(s, fs[i] - Mat3d::identity(), l.lambda, l.mu,
                         snh ? StiffeningLaw::kStableNeoHookean : StiffeningLaw::kSvk);
      SCOPED_TRACE(testing::Message() << (snh ? "snh" : "svk") << " case " << i << ": true growth "
                                      << truth << ", estimate " << estimate);
      if (i < 2) {
        EXPECT_NEAR(estimate, 1.0, 1e-9);
        EXPECT_NEAR(truth, 1.0, 1e-6);
      }
      EXPECT_GE(estimate, 0.5 * truth);
      EXPECT_LE(estimate, 6.0 * std::max(truth, 1.0));
    }
  }
  EXPECT_EQ(tet_stiffening(s, Mat3d{{{-0.9, 0, 0}, {0, 2, 0}, {0, 0, 5}}}, l.lambda, l.mu,
                           StiffeningLaw::kLinear),
            1.0);
}

}  // namespace
}  // namespace zona
