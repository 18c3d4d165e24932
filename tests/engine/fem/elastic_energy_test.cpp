// The elastic energy term: its gradient is the explicit step's elastic force (the same laws),
// its gradient and Hessian-vector product agree with central differences of its energy and
// gradient, the Hessian is symmetric, its diagonal blocks are the product's, and the element
// product is the assembled element stiffness's; for each law, nodal pressure included.
#include "engine/fem/elastic_energy.h"

#include <gtest/gtest.h>

#include <Eigen/Eigenvalues>
#include <algorithm>
#include <cmath>
#include <vector>

#include "engine/fem/forces_cpu.h"
#include "tests/engine/physics_test_meshes.h"

namespace zona {
namespace {

using testing::box_mesh;

constexpr double kL = 10e-6;  // box edge [m]

struct LawCase {
  const char* name;
  ConstitutiveModel law;
  bool nodal;
  double stabilisation = 0;  ///< ModelDesc::nodal_stabilisation
};

const LawCase kLaws[] = {{"linear", ConstitutiveModel::kLinear, false},
                         {"svk", ConstitutiveModel::kSvk, false},
                         {"neohookean", ConstitutiveModel::kStableNeoHookean, false},
                         {"neohookean_nodal", ConstitutiveModel::kStableNeoHookean, true},
                         {"neohookean_nodal_stabilised", ConstitutiveModel::kStableNeoHookean, true,
                          0.3}};

Model build(const Mesh& mesh, const LawCase& c) {
  ModelDesc d;
  d.constitutive = c.law;
  d.material.young = 13.4e3;
  d.material.poisson = 0.45;
  d.nodal_pressure = c.nodal;
  d.nodal_stabilisation = c.stabilisation;
  Result<Model> m = build_model(mesh, d);
  EXPECT_TRUE(m.ok()) << (m.ok() ? "" : m.error().message);
  return std::move(m).value();
}

// A smooth non-affine field with strains of order `strain` (volume change varying by element).
std::vector<Vec3d> wavy(const Mesh& mesh, double strain, double phase) {
  std::vector<Vec3d> u(mesh.vertex_count());
  for (size_t v = 0; v < u.size(); ++v) {
    const Vec3d x = mesh.rest_positions[v] / kL;
    u[v] = strain * kL *
           Vec3d{std::sin(2.0 * x.y + phase) * x.x, 0.5 * std::cos(1.5 * x.z + phase) * x.y + x.x * x.x,
                 -0.4 * x.z * x.x + 0.3 * std::sin(x.y + 2 * phase)};
  }
  return u;
}

double dot_all(const std::vector<Vec3d>& a, const std::vector<Vec3d>& b) {
  double s = 0;
  for (size_t i = 0; i < a.size(); ++i) s += dot(a[i], b[i]);
  return s;
}

double largest(const std::vector<Vec3d>& f) {
  double m = 0;
  for (const Vec3d& v : f) m = std::max(m, norm(v));
  return m;
}

std::vector<Vec3d> axpy(const std::vector<Vec3d>& u, double h, const std::vector<Vec3d>& v) {
  std::vector<Vec3d> out(u.size());
  for (size_t i = 0; i < u.size(); ++i) out[i] = u[i] + h * v[i];
  return out;
}

class ElasticEnergyTest : public ::testing::TestWithParam<LawCase> {
 protected:
  Mesh mesh_ = box_mesh({0, 0, 0}, {kL, 0.75 * kL, 0.75 * kL}, 4, 3, 3);
};

TEST_P(ElasticEnergyTest, GradientIsTheExplicitStepsElasticForce) {
  const Model model = build(mesh_, GetParam());
  Result<ElasticEnergy> term = ElasticEnergy::create(model);
  ASSERT_TRUE(term.ok());
  const std::vector<Vec3d> u = wavy(mesh_, 0.15, 0.3);
  std::vector<Vec3d> g(u.size(), Vec3d{0, 0, 0});
  const double w = term->add_gradient_energy(u, g);
  State s = make_state(model, 2);
  set_displacement(s, u);
  compute_elastic_forces(model, s);
  const double scale = largest(s.force);
  ASSERT_GT(scale, 0);
  for (size_t v = 0; v < u.size(); ++v)
    EXPECT_LE(norm(g[v] + s.force[v]), 1e-10 * scale) << "vertex " << v;
  EXPECT_NEAR(w, s.diag.elastic_energy, 1e-11 * std::abs(w));
  EXPECT_NEAR(term->energy(u), w, 1e-12 * std::abs(w));
}

TEST_P(ElasticEnergyTest, GradientAndHessianMatchCentralDifferences) {
  const Model model = build(mesh_, GetParam());
  ElasticEnergy term = ElasticEnergy::create(model).value();
  const std::vector<Vec3d> u = wavy(mesh_, 0.15, 0.3);
  const std::vector<Vec3d> dir = wavy(mesh_, 1.0, 1.7);  // a direction of size ~kL
  const double h = 1e-5;                                   // step along it: strains ~1e-5
  // Energy: dW/dh = g . dir.
  std::vector<Vec3d> g(u.size(), Vec3d{0, 0, 0});
  term.add_gradient(u, g);
  const double slope = (term.energy(axpy(u, h, dir)) - term.energy(axpy(u, -h, dir))) / (2 * h);
  EXPECT_NEAR(dot_all(g, dir), slope, 1e-6 * std::abs(slope));
  // Gradient: d g / dh = H dir.
  std::vector<Vec3d> gp(u.size(), Vec3d{0, 0, 0}), gm(u.size(), Vec3d{0, 0, 0});
  term.add_gradient(axpy(u, h, dir), gp);
  term.add_gradient(axpy(u, -h, dir), gm);
  std::vector<Vec3d> hv(u.size(), Vec3d{0, 0, 0});
  term.add_hessian_product(u, dir, hv);
  const double scale = largest(hv);
  ASSERT_GT(scale, 0);
  for (size_t v = 0; v < u.size(); ++v)
    EXPECT_LE(norm((1.0 / (2 * h)) * (gp[v] - gm[v]) - hv[v]), 1e-6 * scale) << "vertex " << v;
}

TEST_P(ElasticEnergyTest, HessianIsSymmetricAndItsDiagonalIsTheProducts) {
  const Model model = build(mesh_, GetParam());
  ElasticEnergy term = ElasticEnergy::create(model).value();
  const std::vector<Vec3d> u = wavy(mesh_, 0.15, 0.3);
  const std::vector<Vec3d> a = wavy(mesh_, 1.0, 1.7), b = wavy(mesh_, 1.0, -0.9);
  std::vector<Vec3d> ha(u.size(), Vec3d{0, 0, 0}), hb(u.size(), Vec3d{0, 0, 0});
  term.add_hessian_product(u, a, ha);
  term.add_hessian_product(u, b, hb);
  EXPECT_NEAR(dot_all(b, ha), dot_all(a, hb), 1e-10 * std::abs(dot_all(a, ha)));
  std::vector<Mat3d> d(u.size(), Mat3d::zero());
  term.add_hessian_diagonal(u, d);
  // Column i of vertex v's block is (H e_vi) at v, for a few vertices (an interior one too).
  for (size_t v : {size_t{0}, u.size() / 2, u.size() - 1}) {
    for (int i = 0; i < 3; ++i) {
      std::vector<Vec3d> e(u.size(), Vec3d{0, 0, 0}), he(u.size(), Vec3d{0, 0, 0});
      e[v][i] = 1;
      term.add_hessian_product(u, e, he);
      for (int r = 0; r < 3; ++r)
        EXPECT_NEAR(d[v].m[r][i], he[v][r], 1e-10 * std::abs(d[v].m[i][i])) << v << " " << r << i;
    }
  }
}

// The assembled Hessian: exact, it is the Hessian-vector product's operator; projected (the
// projected Newton's matrix), it is positive semi-definite and above the exact one
// (v^T H_p v >= v^T H v: the projection only raises negative eigenvalues), at small strains and
// at large.
TEST_P(ElasticEnergyTest, AssembledHessianIsTheProductAndItsProjectionPositive) {
  const Model model = build(mesh_, GetParam());
  ElasticEnergy term = ElasticEnergy::create(model).value();
  for (double strain : {0.002, 0.4}) {
    const std::vector<Vec3d> u = wavy(mesh_, strain, 0.3);
    BlockSparseMatrix exact = ElasticEnergy::hessian_pattern(model), projected = exact;
    term.add_hessian(u, exact, false);
    term.add_hessian(u, projected, true);
    for (double phase : {1.7, -0.9, 0.4}) {
      const std::vector<Vec3d> a = wavy(mesh_, 1.0, phase);
      std::vector<Vec3d> ea(u.size()), qa(u.size()), pa(u.size(), Vec3d{0, 0, 0});
      exact.multiply(a, ea);
      projected.multiply(a, qa);
      term.add_hessian_product(u, a, pa);
      const double scale = largest(pa);
      for (size_t v = 0; v < u.size(); ++v)
        EXPECT_LE(norm(ea[v] - pa[v]), 1e-9 * scale) << "vertex " << v << " strain " << strain;
      const double aqa = dot_all(a, qa), apa = dot_all(a, pa);
      EXPECT_GE(aqa, 0.0) << "strain " << strain;
      EXPECT_GE(aqa, apa - 1e-12 * std::abs(apa)) << "strain " << strain;
    }
  }
}

INSTANTIATE_TEST_SUITE_P(Laws, ElasticEnergyTest, ::testing::ValuesIn(kLaws),
                         [](const ::testing::TestParamInfo<LawCase>& param_info) {
                           return std::string(param_info.param.name);
                         });

// The element product is the 12 x 12 element stiffness (fem_element.h) times the direction.
TEST(ElasticTerm, ElementProductIsTheElementStiffnessTimesTheDirection) {
  const TetShape<double> s = tet_shape_from_rest(Vec3d{0, 0, 0}, Vec3d{1e-6, 0, 0},
                                                 Vec3d{0.2e-6, 1.1e-6, 0},
                                                 Vec3d{0.3e-6, 0.2e-6, 0.9e-6});
  const Vec3d u[4] = {{0, 0, 0}, {0.1e-6, 0.02e-6, 0}, {-0.05e-6, 0.15e-6, 0.01e-6},
                      {0.02e-6, -0.03e-6, -0.2e-6}};
  const Vec3d v[4] = {{1, 2, 3}, {-1, 0.5, 0}, {0.3, -2, 1}, {0, 0, -1}};
  const double lambda = 2e4, mu = 5e3;
  for (ConstitutiveModel model :
       {ConstitutiveModel::kLinear, ConstitutiveModel::kSvk, ConstitutiveModel::kStableNeoHookean}) {
    double k[144];
    if (model == ConstitutiveModel::kLinear) tet_linear_stiffness(s, lambda, mu, k);
    if (model == ConstitutiveModel::kSvk) tet_svk_stiffness(s, lambda, mu, u, k);
    if (model == ConstitutiveModel::kStableNeoHookean) tet_snh_stiffness(s, lambda, mu, u, k);
    ElementLaw<double> law;
    law.model = model;
    law.lambda = lambda;
    law.mu = mu;
    Vec3d y[4];
    tet_hessian_product(s, law, u, v, y);
    for (int r = 0; r < 12; ++r) {
      double expect = 0;
      for (int c = 0; c < 12; ++c) expect += k[r * 12 + c] * v[c / 3][c % 3];
      EXPECT_NEAR(y[r / 3][r % 3], expect, 1e-9 * std::abs(k[0])) << static_cast<int>(model) << " " << r;
    }
  }
}

// A stable neo-Hookean element law (lambda 400 kPa, mu 6 kPa), with nodal pressure p held or not,
// the volume barrier from `barrier` (0: off).
ElementLaw<double> snh_law(bool nodal, double pressure, double barrier) {
  ElementLaw<double> law;
  law.lambda = 4e5;
  law.mu = 6e3;
  law.nodal = nodal;
  law.pressure = nodal ? pressure : 0.0;
  law.barrier_volume = barrier;
  law.barrier_stiffness = barrier > 0 ? law.mu : 0.0;
  return law;
}

// The stable neo-Hookean tangent in closed form is the stress differential's columns, with and
// without nodal pressure, the volume barrier active (J below its threshold) or not.
TEST(ElasticTerm, ClosedFormNeoHookeanTangentIsTheStressDifferential) {
  const Mat3d stretched{{{0.3, 0.1, -0.05}, {0.02, -0.2, 0.15}, {0.1, 0.04, 0.25}}};
  const Mat3d crushed{{{-0.93, 0.1, 0.02}, {0.05, 0.02, -0.1}, {0.01, 0.03, 0.04}}};
  for (const Mat3d& h : {stretched, crushed})
    for (bool nodal : {false, true})
      for (double barrier : {0.0, 0.1}) {
        const ElementLaw<double> law = snh_law(nodal, 2.5e3, barrier);
        double q[9][9];
        snh_stress_tangent(law, h, q);
        double scale = 0;
        for (auto& row : q)
          for (double x : row) scale = std::max(scale, std::abs(x));
        for (int k = 0; k < 9; ++k) {
          Mat3d df = Mat3d::zero();
          df.m[k / 3][k % 3] = 1;
          const Mat3d dp = element_stress_differential(law, h, df);
          for (int r = 0; r < 9; ++r)
            EXPECT_NEAR(q[r][k], dp.m[r / 3][r % 3], 1e-12 * scale)
                << "nodal " << nodal << " barrier " << barrier << " J - 1 "
                << snh_volume_change(h) << " entry " << r << "," << k;
        }
      }
}

// The closed-form projection of the stable neo-Hookean tangent (its analytic eigensystem) is the
// numeric one: Q with its negative eigenvalues clamped by a 9 x 9 eigendecomposition, on states
// where Q is indefinite (an inverted element, a crushed one, a twisted one under nodal pressure)
// and where it is not (then nothing changes).
TEST(ElasticTerm, ClosedFormProjectionIsTheClampedEigendecomposition) {
  const Mat3d states[] = {
      Mat3d{{{0.3, 0.1, -0.05}, {0.02, -0.2, 0.15}, {0.1, 0.04, 0.25}}},    // stretched
      Mat3d{{{-0.93, 0.1, 0.02}, {0.05, 0.02, -0.1}, {0.01, 0.03, 0.04}}},  // crushed
      Mat3d{{{-1.4, 0.2, 0.0}, {0.1, -0.1, 0.05}, {0.0, 0.1, 0.1}}},        // inverted (J < 0)
      Mat3d{{{0.0, 0.6, 0.0}, {-0.6, 0.0, 0.0}, {0.0, 0.0, 0.0}}},          // twisted
      Mat3d{{{0.2, 0.0, 0.0}, {0.0, 0.2, 0.0}, {0.0, 0.0, 0.2}}},           // repeated stretches
  };
  int indefinite = 0;
  for (const Mat3d& h : states)
    for (bool nodal : {false, true})
      for (double barrier : {0.0, 0.1}) {
        const ElementLaw<double> law = snh_law(nodal, 8e4, barrier);
        double q[9][9];
        snh_stress_tangent(law, h, q);
        Eigen::Matrix<double, 9, 9> m;
        for (int r = 0; r < 9; ++r)
          for (int c = 0; c < 9; ++c) m(r, c) = q[r][c];
        Eigen::SelfAdjointEigenSolver<Eigen::Matrix<double, 9, 9>> eig(m);
        indefinite += eig.eigenvalues().minCoeff() < 0 ? 1 : 0;
        const Eigen::Matrix<double, 9, 9> clamped = eig.eigenvectors() *
                                                    eig.eigenvalues().cwiseMax(0.0).asDiagonal() *
                                                    eig.eigenvectors().transpose();
        snh_project_tangent(law, h, q);
        const double scale = m.cwiseAbs().maxCoeff();
        for (int r = 0; r < 9; ++r)
          for (int c = 0; c < 9; ++c)
            EXPECT_NEAR(q[r][c], clamped(r, c), 1e-9 * scale)
                << "nodal " << nodal << " barrier " << barrier << " J - 1 " << snh_volume_change(h)
                << " entry " << r << "," << c;
      }
  EXPECT_GE(indefinite, 4);  // the states do reach the projection
}

TEST(ElasticTerm, TheClampedSvkLawHasNoEnergyTerm) {
  const Mesh mesh = box_mesh({0, 0, 0}, {kL, kL, kL}, 1, 1, 1);
  ModelDesc d;
  d.constitutive = ConstitutiveModel::kSvk;
  d.inversion = InversionHandling::kClampStretch;
  const Model model = build_model(mesh, d).value();
  const Result<ElasticEnergy> term = ElasticEnergy::create(model);
  ASSERT_FALSE(term.ok());
  EXPECT_NE(term.error().message.find("clamped"), std::string::npos);
}

}  // namespace
}  // namespace zona
