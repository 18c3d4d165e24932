// The static solver's Newton: the iterative (CG) solve agrees with the direct one (the exact
// oracle) to 1e-6 in the displacements, the converged state's force imbalance is below the
// tolerance and its energy is a minimum along random directions; the volume barrier's gradient
// and Hessian match central differences, and it keeps every element's volume positive.
#include "engine/solver/newton.h"

#include <gtest/gtest.h>

#include <cmath>
#include <vector>

#include "engine/fem/elastic_energy.h"
#include "engine/solver/inertia_term.h"
#include "engine/tools/tool_terms.h"
#include "tests/engine/physics_test_meshes.h"

namespace zona {
namespace {

using testing::box_mesh;
using testing::vertices_where;

constexpr double kL = 10e-6;  // box edge [m]

Model clamped_box(const Mesh& mesh) {
  ModelDesc d;
  d.constitutive = ConstitutiveModel::kStableNeoHookean;
  d.material.young = 16.5e3;
  d.material.poisson = 0.49;
  d.nodal_pressure = true;
  d.fixed_vertices = vertices_where(mesh, 2, 0.0, 1e-9 * kL);
  Result<Model> m = build_model(mesh, d);
  EXPECT_TRUE(m.ok()) << (m.ok() ? "" : m.error().message);
  return std::move(m).value();
}

struct Problem {
  Mesh mesh = box_mesh({0, 0, 0}, {kL, kL, kL}, 5, 5, 5);
  Model model = clamped_box(mesh);
  ElasticEnergy elastic = ElasticEnergy::create(model).value();
  std::vector<int32_t> top = vertices_where(mesh, 2, kL, 1e-9 * kL);
  std::vector<double> area = std::vector<double>(top.size(), (kL / 5) * (kL / 5));
  std::unique_ptr<PenaltyContactTerm> needle;
  std::unique_ptr<InertiaTerm> inertia;

  explicit Problem(double depth) {
    ToolField f;
    f.kind = ToolField::Kind::kNeedle;
    f.origin = Vec3d{0.45 * kL, 0.55 * kL, kL - depth};
    f.axis = Vec3d{0, 0, -1};
    f.radius = 0.3 * kL;
    needle = std::make_unique<PenaltyContactTerm>("needle", f, model.rest_positions, top, area,
                                                  1000 * 16.5e3 / f.radius, 0.0);
    const size_t n = model.vertex_count();
    inertia = std::make_unique<InertiaTerm>(std::vector<double>(n, 1e-16),
                                            std::vector<double>(n, 1e-9));
    std::vector<Vec3d> zero(n, Vec3d{0, 0, 0});
    inertia->set_step(1e-2, zero, zero);
  }
  NewtonSolver solver(std::unique_ptr<LinearSolver> linear) {
    elastic.set_barrier(0.1);
    return NewtonSolver({&elastic, needle.get(), inertia.get()},
                        ElasticEnergy::hessian_pattern(model), model.vertex_fixed,
                        std::move(linear));
  }
};

double largest(const std::vector<Vec3d>& f) {
  double m = 0;
  for (const Vec3d& v : f) m = std::max(m, norm(v));
  return m;
}

TEST(Newton, IterativeSolveMatchesTheDirectOracle) {
  Problem a(0.15 * kL), b(0.15 * kL);
  NewtonSolver direct = a.solver(make_direct_solver());
  NewtonSolver cg = b.solver(make_cg_solver(make_block_jacobi(), 100000));
  const double tolerance = 1e-15;  // [N]; the needle carries ~1e-7 N
  std::vector<Vec3d> ud(a.model.vertex_count(), Vec3d{0, 0, 0}), uc = ud;
  const NewtonStats sd = direct.solve(ud, tolerance);
  const NewtonStats sc = cg.solve(uc, tolerance);
  ASSERT_TRUE(sd.converged) << sd.failure;
  ASSERT_TRUE(sc.converged) << sc.failure;
  EXPECT_LE(sd.residual, tolerance);
  EXPECT_LE(sc.residual, tolerance);
  // The direct solver's CG refines on a kept factor: a few iterations where block Jacobi takes
  // hundreds.
  EXPECT_LT(sd.krylov, sc.krylov / 4);
  const PenaltyContactTerm::Load load = a.needle->load(ud);
  ASSERT_GT(load.contacts, 3);
  EXPECT_GT(-load.force.z, 3e-8);  // the needle presses down
  std::vector<Vec3d> diff(ud.size());
  for (size_t i = 0; i < ud.size(); ++i) diff[i] = ud[i] - uc[i];
  EXPECT_LE(largest(diff), 1e-6 * largest(ud));
  // A minimum: the energy rises along any direction (fixed vertices held).
  for (int k = 0; k < 4; ++k) {
    std::vector<Vec3d> v(ud.size()), w(ud.size());
    for (size_t i = 0; i < ud.size(); ++i) {
      const double t = static_cast<double>(i) + 0.37 * k;
      v[i] = a.model.vertex_fixed[i] ? Vec3d{0, 0, 0}
                                     : 1e-3 * kL * Vec3d{std::sin(3 * t), std::cos(5 * t), std::sin(t + 1)};
      w[i] = ud[i] + v[i];
    }
    EXPECT_GT(direct.evaluate(w, {}), sd.energy) << k;
  }
}

// E = u^T A u / 2 - b . u on two vertices, A = [[I, 2I], [2I, I]] (eigenvalues 3 and -1): a
// state with no stable equilibrium near it.
class SaddleTerm final : public EnergyTerm {
 public:
  const char* name() const override { return "saddle"; }
  double energy(std::span<const Vec3d> u) override {
    return 0.5 * (dot(u[0], u[0]) + dot(u[1], u[1])) + 2 * dot(u[0], u[1]) - dot(b_[0], u[0]) -
           dot(b_[1], u[1]);
  }
  void add_gradient(std::span<const Vec3d> u, std::span<Vec3d> g) override {
    g[0] += u[0] + 2.0 * u[1] - b_[0];
    g[1] += u[1] + 2.0 * u[0] - b_[1];
  }
  void add_hessian_product(std::span<const Vec3d>, std::span<const Vec3d> v,
                           std::span<Vec3d> y) override {
    y[0] += v[0] + 2.0 * v[1];
    y[1] += v[1] + 2.0 * v[0];
  }
  void add_hessian_diagonal(std::span<const Vec3d>, std::span<Mat3d> d) override {
    for (Mat3d& m : d) m = m + Mat3d::identity();
  }
  void add_hessian(std::span<const Vec3d>, BlockSparseMatrix& h, bool project) override {
    // Projected: [[I, I], [I, I]] * 1.5 + I / 2 (the eigenvalue -1 raised to 0.5).
    const double diag = project ? 2.0 : 1.0, off = project ? 1.5 : 2.0;
    for (int32_t i = 0; i < 2; ++i) {
      h.add(i, i, diag * Mat3d::identity());
      h.add(i, 1 - i, off * Mat3d::identity());
    }
  }

 private:
  Vec3d b_[2] = {Vec3d{1, 0, 0}, Vec3d{0.1, 0, 0}};
};

TEST(Newton, AFailureOnAnIndefiniteHessianSaysTheEquilibriumMayBeLosingItsStability) {
  SaddleTerm saddle;
  NewtonSolver solver({&saddle},
                      BlockSparseMatrix(std::vector<std::vector<int32_t>>{{0, 1}, {0, 1}}),
                      std::vector<uint8_t>(2, 0), make_cg_solver(make_block_jacobi(), 100));
  solver.options().max_iterations = 3;
  std::vector<Vec3d> u(2, Vec3d{0, 0, 0});
  const NewtonStats s = solver.solve(u, 1e-12);
  ASSERT_FALSE(s.converged);
  EXPECT_EQ(s.iterations, 3);
  EXPECT_GE(s.negative_curvature, 2);
  EXPECT_NE(s.failure.find("losing its stability"), std::string::npos) << s.failure;
  // A convex problem that runs out of iterations says only that.
  Problem p(0.15 * kL);
  NewtonSolver convex = p.solver(make_cg_solver(make_block_jacobi(), 100000));
  convex.options().max_iterations = 1;
  std::vector<Vec3d> w(p.model.vertex_count(), Vec3d{0, 0, 0});
  const NewtonStats c = convex.solve(w, 1e-18);
  ASSERT_FALSE(c.converged);
  EXPECT_EQ(c.negative_curvature, 0);
  EXPECT_NE(c.failure.find("did not converge in 1 iterations"), std::string::npos) << c.failure;
  EXPECT_EQ(c.failure.find("stability"), std::string::npos) << c.failure;
}

TEST(Newton, TheBarrierKeepsEveryElementOpenUnderADeepTip) {
  // A tip pushed half the box deep: the elements under it are crushed towards the barrier.
  Problem p(0.5 * kL);
  NewtonSolver solver = p.solver(make_direct_solver());
  std::vector<Vec3d> u(p.model.vertex_count(), Vec3d{0, 0, 0});
  const NewtonStats s = solver.solve(u, 1e-12);
  ASSERT_TRUE(s.converged) << s.failure;
  EXPECT_GT(p.elastic.min_volume_ratio(u), 0.0);
}

TEST(VolumeBarrier, MatchesCentralDifferencesAndIsInfiniteAtCollapse) {
  const double j0 = 0.8, k = 1e3;
  for (double j : {0.05, 0.3, 0.6, 0.79}) {
    const double h = 1e-7;
    const BarrierValue<double> b = volume_barrier(j, j0, k);
    EXPECT_GT(b.psi, 0.0);
    EXPECT_LT(b.d1, 0.0);  // it pushes the volume up
    const double d1 = (volume_barrier(j + h, j0, k).psi - volume_barrier(j - h, j0, k).psi) / (2 * h);
    const double d2 = (volume_barrier(j + h, j0, k).d1 - volume_barrier(j - h, j0, k).d1) / (2 * h);
    EXPECT_NEAR(b.d1, d1, 1e-6 * std::abs(d1)) << j;
    EXPECT_NEAR(b.d2, d2, 1e-6 * std::abs(d2)) << j;
  }
  // C^2 at j0: value, slope and curvature vanish from below.
  const BarrierValue<double> edge = volume_barrier(j0 * (1 - 1e-9), j0, k);
  EXPECT_NEAR(edge.psi, 0.0, 1e-12);
  EXPECT_NEAR(edge.d1, 0.0, 1e-6);
  EXPECT_NEAR(edge.d2, 0.0, 1e-4 * k);
  EXPECT_EQ(volume_barrier(1.0, j0, k).psi, 0.0);
  EXPECT_TRUE(std::isinf(volume_barrier(0.0, j0, k).psi));
  EXPECT_TRUE(std::isinf(volume_barrier(-0.1, j0, k).psi));
}

TEST(VolumeBarrier, ElasticTermWithTheBarrierMatchesCentralDifferences) {
  const Mesh mesh = box_mesh({0, 0, 0}, {kL, kL, kL}, 3, 3, 3);
  const Model model = clamped_box(mesh);
  ElasticEnergy term = ElasticEnergy::create(model).value();
  term.set_barrier(0.97);  // active at the compressions below
  std::vector<Vec3d> u(mesh.vertex_count()), dir(mesh.vertex_count());
  for (size_t v = 0; v < u.size(); ++v) {
    const Vec3d x = mesh.rest_positions[v] / kL;
    u[v] = kL * Vec3d{-0.06 * x.x + 0.01 * std::sin(3 * x.y), 0.02 * x.x * x.z, -0.08 * x.z};
    dir[v] = kL * Vec3d{std::sin(2 * x.y + 1), std::cos(x.z), 0.5 * x.x};
  }
  ASSERT_LT(term.min_volume_ratio(u), 0.97);
  const double h = 1e-7;
  auto axpy = [&](double s) {
    std::vector<Vec3d> w(u.size());
    for (size_t i = 0; i < u.size(); ++i) w[i] = u[i] + s * dir[i];
    return w;
  };
  std::vector<Vec3d> g(u.size(), Vec3d{0, 0, 0}), gp = g, gm = g, hv = g;
  term.add_gradient(u, g);
  double gd = 0;
  for (size_t i = 0; i < u.size(); ++i) gd += dot(g[i], dir[i]);
  const double slope = (term.energy(axpy(h)) - term.energy(axpy(-h))) / (2 * h);
  EXPECT_NEAR(gd, slope, 1e-6 * std::abs(slope));
  term.add_gradient(axpy(h), gp);
  term.add_gradient(axpy(-h), gm);
  term.add_hessian_product(u, dir, hv);
  const double scale = largest(hv);
  for (size_t i = 0; i < u.size(); ++i)
    EXPECT_LE(norm((1.0 / (2 * h)) * (gp[i] - gm[i]) - hv[i]), 1e-6 * scale) << i;
}

// CG on an indefinite matrix, [[I, 2 I], [2 I, I]] (eigenvalues 3 and -1) with block Jacobi
// (the identity here): for b = (1, 0.1) along x its second direction has negative curvature,
// and CG returns its first iterate, truncated, which descends (b . x > 0); a right-hand side
// along the negative eigenvector meets it at the first iteration, and CG refuses.
TEST(Cg, TruncatesAtADirectionOfNegativeCurvature) {
  BlockSparseMatrix a(std::vector<std::vector<int32_t>>{{0, 1}, {0, 1}});
  a.set_zero();
  a.add(0, 0, Mat3d::identity());
  a.add(1, 1, Mat3d::identity());
  a.add(0, 1, 2.0 * Mat3d::identity());
  a.add(1, 0, 2.0 * Mat3d::identity());
  std::unique_ptr<LinearSolver> cg = make_cg_solver(make_block_jacobi(), 100);
  ASSERT_TRUE(cg->setup(a).ok());
  std::vector<Vec3d> b = {Vec3d{1, 0, 0}, Vec3d{0.1, 0, 0}}, x(2);
  Result<LinearSolveStats> s = cg->solve(b, x, 1e-12);
  ASSERT_TRUE(s.ok()) << s.error().message;
  EXPECT_TRUE(s->truncated);
  EXPECT_EQ(s->iterations, 1);
  EXPECT_GT(dot(b[0], x[0]) + dot(b[1], x[1]), 0.0);
  // The first iterate: alpha b with alpha = |b|^2 / b.Ab = 1.01 / 1.41.
  EXPECT_NEAR(x[0].x, 1.01 / 1.41, 1e-12);
  EXPECT_NEAR(x[1].x, 0.101 / 1.41, 1e-12);
  // Along (1, -1) the curvature is -1 at once.
  b = {Vec3d{0, 1, 0}, Vec3d{0, -1, 0}};
  x.assign(2, Vec3d{0, 0, 0});
  Result<LinearSolveStats> first = cg->solve(b, x, 1e-12);
  ASSERT_FALSE(first.ok());
  EXPECT_NE(first.error().message.find("non-positive curvature"), std::string::npos);
  // A positive definite matrix is solved, not truncated.
  BlockSparseMatrix spd(std::vector<std::vector<int32_t>>{{0, 1}, {0, 1}});
  spd.set_zero();
  spd.add(0, 0, 3.0 * Mat3d::identity());
  spd.add(1, 1, 3.0 * Mat3d::identity());
  spd.add(0, 1, Mat3d::identity());
  spd.add(1, 0, Mat3d::identity());
  ASSERT_TRUE(cg->setup(spd).ok());
  b = {Vec3d{1, 2, 0}, Vec3d{0.1, -1, 3}};
  x.assign(2, Vec3d{0, 0, 0});
  Result<LinearSolveStats> solved = cg->solve(b, x, 1e-12);
  ASSERT_TRUE(solved.ok());
  EXPECT_FALSE(solved->truncated);
  EXPECT_NEAR(3 * x[0].x + x[1].x, 1.0, 1e-10);
  EXPECT_NEAR(x[0].z + 3 * x[1].z, 3.0, 1e-10);
}

}  // namespace
}  // namespace zona
