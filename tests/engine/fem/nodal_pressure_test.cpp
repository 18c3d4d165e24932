// The stable neo-Hookean law with its volumetric term at the vertices (ModelDesc::nodal_pressure):
// it is the element law under a uniform volume change, its forces are the gradient of its
// energy, its energy never exceeds the element law's (Jensen: the mean of the squared volume
// changes is at least the square of their mean), and it is refused where it is not built.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <vector>

#include "engine/fem/forces_cpu.h"
#include "engine/sim/integrator.h"
#include "tests/engine/physics_test_meshes.h"

namespace zona {
namespace {

using testing::box_mesh;

constexpr double kL = 10e-6;  // box edge [m]

// 4 x 3 x 3 cubes, nu 0.49: several chunks of vertices, interior vertices with full stars.
Mesh test_box() { return box_mesh({0, 0, 0}, {kL, 0.75 * kL, 0.75 * kL}, 4, 3, 3); }

Model build(const Mesh& mesh, bool nodal, double stabilisation = 0) {
  ModelDesc d;
  d.constitutive = ConstitutiveModel::kStableNeoHookean;
  d.material.young = 13.4e3;
  d.material.poisson = 0.49;
  d.nodal_pressure = nodal;
  d.nodal_stabilisation = stabilisation;
  Result<Model> m = build_model(mesh, d);
  EXPECT_TRUE(m.ok()) << (m.ok() ? "" : m.error().message);
  return std::move(m).value();
}

std::vector<Vec3d> forces_at(const Model& model, const std::vector<Vec3d>& u, double* energy,
                             int threads = 2) {
  State s = make_state(model, threads);
  set_displacement(s, u);
  compute_elastic_forces(model, s);
  *energy = s.diag.elastic_energy;
  return s.force;
}

// A smooth non-affine field with strains of order `strain`: the volume change varies from
// element to element.
std::vector<Vec3d> wavy(const Mesh& mesh, double strain) {
  std::vector<Vec3d> u(mesh.vertex_count());
  for (size_t v = 0; v < u.size(); ++v) {
    const Vec3d x = mesh.rest_positions[v] / kL;
    u[v] = strain * kL *
           Vec3d{std::sin(2.0 * x.y + 0.3) * x.x, 0.5 * std::cos(1.5 * x.z) * x.y + x.x * x.x,
                 -0.4 * x.z * x.x + 0.3 * std::sin(x.y)};
  }
  return u;
}

// An affine compression with shear: the same J in every element, so Jbar = J.
std::vector<Vec3d> affine_compression(const Mesh& mesh) {
  const Mat3d a{{{-0.08, 0.03, 0.0}, {0.01, 0.05, -0.02}, {0.0, 0.02, -0.04}}};
  std::vector<Vec3d> u(mesh.vertex_count());
  for (size_t v = 0; v < u.size(); ++v) u[v] = a * mesh.rest_positions[v];
  return u;
}

double largest(const std::vector<Vec3d>& f) {
  double m = 0;
  for (const Vec3d& v : f) m = std::max(m, norm(v));
  return m;
}

TEST(NodalPressure, UniformVolumeChangeIsTheElementLaw) {
  const Mesh mesh = test_box();
  const Model element = build(mesh, false), nodal = build(mesh, true);
  const std::vector<Vec3d> u = affine_compression(mesh);
  double w_element = 0, w_nodal = 0;
  const std::vector<Vec3d> fe = forces_at(element, u, &w_element);
  const std::vector<Vec3d> fn = forces_at(nodal, u, &w_nodal);
  const double scale = largest(fe);
  ASSERT_GT(scale, 0);
  for (size_t v = 0; v < u.size(); ++v)
    EXPECT_LE(norm(fn[v] - fe[v]), 1e-11 * scale) << "vertex " << v;
  EXPECT_NEAR(w_nodal, w_element, 1e-11 * w_element);
  EXPECT_GT(w_element, 0);
}

// The stabilisation (ModelDesc::nodal_stabilisation) moves a part beta of lambda from the
// vertices back into the elements: under a uniform volume change it is the element law still;
// where the volume change alternates its energy lies between the nodal law's and the element
// law's, beta of the way up (the volumetric energy is linear in where lambda sits).
TEST(NodalPressure, TheStabilisationKeepsBetaOfLambdaPerElement) {
  const Mesh mesh = test_box();
  const Model element = build(mesh, false), nodal = build(mesh, true);
  const Model stabilised = build(mesh, true, 0.25);
  const std::vector<Vec3d> u = affine_compression(mesh);
  double w_element = 0, w_stabilised = 0;
  const std::vector<Vec3d> fe = forces_at(element, u, &w_element);
  const std::vector<Vec3d> fs = forces_at(stabilised, u, &w_stabilised);
  for (size_t v = 0; v < u.size(); ++v)
    EXPECT_LE(norm(fs[v] - fe[v]), 1e-11 * largest(fe)) << "vertex " << v;
  EXPECT_NEAR(w_stabilised, w_element, 1e-11 * w_element);

  const std::vector<Vec3d> w = wavy(mesh, 0.05);
  double e_element = 0, e_nodal = 0, e_stabilised = 0;
  (void)forces_at(element, w, &e_element);
  (void)forces_at(nodal, w, &e_nodal);
  (void)forces_at(stabilised, w, &e_stabilised);
  ASSERT_LT(e_nodal, e_element);
  EXPECT_NEAR(e_stabilised, e_nodal + 0.25 * (e_element - e_nodal), 1e-9 * e_element);

  ModelDesc bad;
  bad.constitutive = ConstitutiveModel::kStableNeoHookean;
  bad.nodal_pressure = true;
  bad.nodal_stabilisation = 1.0;
  EXPECT_FALSE(build_model(mesh, bad).ok());
}

TEST(NodalPressure, ForcesAreTheNegativeEnergyGradient) {
  const Mesh mesh = test_box();
  const Model model = build(mesh, true);
  const std::vector<Vec3d> u = wavy(mesh, 0.05);
  double w = 0;
  const std::vector<Vec3d> f = forces_at(model, u, &w);
  const double scale = largest(f);
  const double h = 1e-6 * kL;
  int checked = 0;
  for (size_t v = 0; v < u.size(); v += 7)
    for (int i = 0; i < 3; ++i) {
      std::vector<Vec3d> up = u, um = u;
      up[v][i] += h;
      um[v][i] -= h;
      double wp = 0, wm = 0;
      forces_at(model, up, &wp);
      forces_at(model, um, &wm);
      EXPECT_NEAR(-(wp - wm) / (2 * h), f[v][i], 1e-6 * scale) << "vertex " << v << " axis " << i;
      ++checked;
    }
  EXPECT_GT(checked, 30);
}

TEST(NodalPressure, EnergyIsBelowTheElementLawsWhereTheVolumeChangeVaries) {
  const Mesh mesh = test_box();
  const Model element = build(mesh, false), nodal = build(mesh, true);
  for (double strain : {0.01, 0.1, 0.3}) {
    const std::vector<Vec3d> u = wavy(mesh, strain);
    double w_element = 0, w_nodal = 0;
    forces_at(element, u, &w_element);
    forces_at(nodal, u, &w_nodal);
    EXPECT_GT(w_nodal, 0) << "strain " << strain;
    EXPECT_LT(w_nodal, w_element) << "strain " << strain;
  }
}

TEST(NodalPressure, ResultsDoNotDependOnTheThreadCount) {
  const Mesh mesh = test_box();
  const Model model = build(mesh, true);
  const std::vector<Vec3d> u = wavy(mesh, 0.2);
  double w1 = 0, w2 = 0;
  const std::vector<Vec3d> f1 = forces_at(model, u, &w1, 1);
  const std::vector<Vec3d> f2 = forces_at(model, u, &w2, 2);
  EXPECT_EQ(w1, w2);
  for (size_t v = 0; v < u.size(); ++v)
    for (int i = 0; i < 3; ++i) EXPECT_EQ(f1[v][i], f2[v][i]) << "vertex " << v << " axis " << i;
}

TEST(NodalPressure, IsRefusedForOtherLaws) {
  const Mesh mesh = test_box();
  ModelDesc d;
  d.constitutive = ConstitutiveModel::kSvk;
  d.nodal_pressure = true;
  Result<Model> m = build_model(mesh, d);
  ASSERT_FALSE(m.ok());
  EXPECT_NE(m.error().message.find("nodal pressure"), std::string::npos) << m.error().message;
}

}  // namespace
}  // namespace zona
