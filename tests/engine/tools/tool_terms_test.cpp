// The tools' energy terms: gradient and Hessian agree with central differences (needle with its
// curvature, rim with friction sticking and sliding, suction), the diagonal blocks are the
// product's, and at the lagged state the gradient is minus the explicit step's contact force.
#include "engine/tools/tool_terms.h"

#include <gtest/gtest.h>

#include <cmath>
#include <vector>

namespace zona {
namespace {

// Points on a patch of sphere (radius 5) facing +x, displaced inwards and sideways so that some
// are inside a needle coming along -x at the patch's pole.
struct Patch {
  std::vector<Vec3d> rest;
  std::vector<int32_t> vertex;
  std::vector<double> area;
  std::vector<Vec3d> u;
};

Patch patch() {
  Patch p;
  for (int i = -3; i <= 3; ++i)
    for (int j = -3; j <= 3; ++j) {
      const double a = 0.12 * i, b = 0.12 * j;
      p.rest.push_back(5.0 * Vec3d{std::cos(a) * std::cos(b), std::sin(a), std::cos(a) * std::sin(b)});
      p.vertex.push_back(static_cast<int32_t>(p.rest.size() - 1));
      p.area.push_back(0.3 + 0.01 * (i + j + 6));
      p.u.push_back(Vec3d{-0.3 + 0.05 * std::sin(1.3 * i + j), 0.07 * std::cos(i - 0.5 * j), 0.04 * i});
    }
  return p;
}

ToolField needle() {
  ToolField f;
  f.kind = ToolField::Kind::kNeedle;
  f.origin = Vec3d{4.5, 0.1, -0.05};
  f.axis = Vec3d{-1, 0, 0};
  f.radius = 1.3;
  return f;
}

std::vector<Vec3d> axpy(const std::vector<Vec3d>& u, double h, const std::vector<Vec3d>& v) {
  std::vector<Vec3d> out(u.size());
  for (size_t i = 0; i < u.size(); ++i) out[i] = u[i] + h * v[i];
  return out;
}

void expect_consistent(EnergyTerm& term, const std::vector<Vec3d>& u) {
  std::vector<Vec3d> dir(u.size());
  for (size_t i = 0; i < u.size(); ++i) {
    const double t = static_cast<double>(i);
    dir[i] = Vec3d{std::sin(3.0 * t), std::cos(2.0 * t + 1), std::sin(0.7 * t + 2)};
  }
  const double h = 1e-7;
  std::vector<Vec3d> g(u.size(), Vec3d{0, 0, 0});
  term.add_gradient(u, g);
  double gd = 0;
  for (size_t i = 0; i < u.size(); ++i) gd += dot(g[i], dir[i]);
  const double slope = (term.energy(axpy(u, h, dir)) - term.energy(axpy(u, -h, dir))) / (2 * h);
  EXPECT_NEAR(gd, slope, 1e-6 * (std::abs(slope) + 1e-3)) << term.name();
  std::vector<Vec3d> gp(u.size(), Vec3d{0, 0, 0}), gm(u.size(), Vec3d{0, 0, 0}),
      hv(u.size(), Vec3d{0, 0, 0});
  term.add_gradient(axpy(u, h, dir), gp);
  term.add_gradient(axpy(u, -h, dir), gm);
  term.add_hessian_product(u, dir, hv);
  std::vector<Mat3d> d(u.size(), Mat3d::zero());
  term.add_hessian_diagonal(u, d);
  for (size_t i = 0; i < u.size(); ++i) {
    EXPECT_LE(norm((1.0 / (2 * h)) * (gp[i] - gm[i]) - hv[i]), 1e-5 * (1 + norm(hv[i])))
        << term.name() << " point " << i;
    // Every term here is per point: its Hessian is block diagonal.
    EXPECT_LE(norm(d[i] * dir[i] - hv[i]), 1e-12 * (1 + norm(hv[i]))) << term.name() << " " << i;
  }
}

TEST(ToolTerms, NeedleContactMatchesCentralDifferencesWithItsCurvature) {
  Patch p = patch();
  PenaltyContactTerm term("needle contact", needle(), p.rest, p.vertex, p.area, 50.0, 0.0);
  // Some points are inside, some outside.
  int inside = 0;
  for (size_t i = 0; i < p.vertex.size(); ++i) inside += needle().eval(p.rest[i] + p.u[i]).distance < 0;
  ASSERT_GT(inside, 2);
  ASSERT_LT(inside, static_cast<int>(p.vertex.size()));
  expect_consistent(term, p.u);
}

TEST(ToolTerms, RimFrictionIsAPotentialWithItsNormalAndCapHeld) {
  Patch p = patch();
  ToolField rim;
  rim.kind = ToolField::Kind::kRim;
  rim.origin = Vec3d{4.6, 0, 0};
  rim.axis = Vec3d{1, 0, 0};
  rim.radius = 0.2;
  rim.outer_radius = 0.7;
  rim.edge_radius = 0.1;
  PenaltyContactTerm term("rim contact", rim, p.rest, p.vertex, p.area, 40.0, 0.4, 0.002);
  // Lagged at a state shifted sideways: at u the points have moved from their anchors, some
  // little (sticking), some far (sliding).
  std::vector<Vec3d> lag_state = p.u;
  for (size_t i = 0; i < lag_state.size(); ++i)
    lag_state[i] += Vec3d{0.02, 0.004 * static_cast<double>(i % 7), -0.003 * static_cast<double>(i % 5)};
  term.lag(lag_state, 0);
  ASSERT_GT(term.lagged_contacts(), 3);
  term.commit(lag_state);  // the anchors of step 0
  term.lag(lag_state, 1);
  expect_consistent(term, p.u);
  // Both regimes were checked: at u some lagged points slide past their stick zone, some stick.
  const int64_t slid = term.commit(p.u);
  EXPECT_GT(slid, 0);
  EXPECT_LT(slid, term.lagged_contacts());
}

TEST(ToolTerms, AtTheLaggedStateTheGradientIsMinusTheExplicitContactForce) {
  Patch p = patch();
  const double kappa = 50.0, mu = 0.3, stick = 0.004;
  PenaltyContactTerm term("needle contact", needle(), p.rest, p.vertex, p.area, kappa, mu, stick);
  std::vector<StickAnchor> anchors(p.vertex.size());
  std::vector<Vec3d> u = p.u;
  for (int64_t step = 0; step < 4; ++step) {
    term.lag(u, step);
    ASSERT_GT(term.lagged_contacts(), 2);
    std::vector<Vec3d> g(u.size(), Vec3d{0, 0, 0});
    term.add_gradient(u, g);
    for (size_t i = 0; i < u.size(); ++i) {
      const Vec3d x = p.rest[i] + u[i];
      const ToolSdf sdf = needle().eval(x);
      const Vec3d f = sdf.distance < 0 ? penalty_contact_force(sdf, kappa, mu, stick, p.area[i],
                                                               x - needle().origin, step, &anchors[i])
                                       : Vec3d{0, 0, 0};
      EXPECT_LE(norm(g[i] + f), 1e-12 * (1 + norm(f))) << "step " << step << " point " << i;
    }
    term.commit(u);
    // The points drift sideways along the tool between steps.
    for (size_t i = 0; i < u.size(); ++i) u[i] += Vec3d{0, 0.01 * static_cast<double>(step + 1), 0.002};
  }
}

TEST(ToolTerms, SuctionIsADeadLoad) {
  Patch p = patch();
  std::vector<Vec3d> load(p.vertex.size(), Vec3d{0.5, -0.1, 0});
  SuctionTerm term(p.vertex, load);
  term.set_ramp(0.5);
  std::vector<Vec3d> g(p.u.size(), Vec3d{0, 0, 0});
  term.add_gradient(p.u, g);
  EXPECT_EQ(norm(g[3] + 0.5 * load[3]), 0);
  expect_consistent(term, p.u);
}

}  // namespace
}  // namespace zona

namespace zona {
namespace {

// The patch's grid as triangles (7 x 7 points, counter-clockwise seen from +x).
std::vector<std::array<int32_t, 3>> patch_faces(std::vector<double>* area) {
  std::vector<std::array<int32_t, 3>> faces;
  for (int i = 0; i < 6; ++i)
    for (int j = 0; j < 6; ++j) {
      const int32_t a = 7 * i + j, b = a + 7, c = a + 1, d = a + 8;
      faces.push_back({a, b, c});
      faces.push_back({c, b, d});
      area->push_back(0.2 + 0.01 * i);
      area->push_back(0.25 - 0.01 * j);
    }
  return faces;
}

// Central differences of the energy and the gradient, for terms whose Hessian couples points.
void expect_fd(EnergyTerm& term, const std::vector<Vec3d>& u) {
  std::vector<Vec3d> dir(u.size());
  for (size_t i = 0; i < u.size(); ++i) {
    const double t = static_cast<double>(i);
    dir[i] = Vec3d{std::sin(3.0 * t), std::cos(2.0 * t + 1), std::sin(0.7 * t + 2)};
  }
  const double h = 1e-7;
  std::vector<Vec3d> g(u.size(), Vec3d{0, 0, 0});
  term.add_gradient(u, g);
  double gd = 0;
  for (size_t i = 0; i < u.size(); ++i) gd += dot(g[i], dir[i]);
  const double slope = (term.energy(axpy(u, h, dir)) - term.energy(axpy(u, -h, dir))) / (2 * h);
  EXPECT_NEAR(gd, slope, 1e-6 * (std::abs(slope) + 1e-3)) << term.name();
  std::vector<Vec3d> gp(u.size(), Vec3d{0, 0, 0}), gm(u.size(), Vec3d{0, 0, 0}),
      hv(u.size(), Vec3d{0, 0, 0});
  term.add_gradient(axpy(u, h, dir), gp);
  term.add_gradient(axpy(u, -h, dir), gm);
  term.add_hessian_product(u, dir, hv);
  for (size_t i = 0; i < u.size(); ++i)
    EXPECT_LE(norm((1.0 / (2 * h)) * (gp[i] - gm[i]) - hv[i]), 1e-5 * (1 + norm(hv[i])))
        << term.name() << " point " << i;
}

TEST(ToolTerms, FaceQuadratureContactMatchesCentralDifferencesAndAssemblesPositive) {
  Patch p = patch();
  std::vector<double> area;
  const std::vector<std::array<int32_t, 3>> faces = patch_faces(&area);
  for (bool flat : {false, true}) {
    ToolField f = needle();
    f.flat = flat;
    PenaltyContactTerm term("needle contact", f, p.rest, face_contact_points(faces, area), 50.0,
                            0.3);
    // Friction lagged at a nearby state, so that some points stick and some slide.
    std::vector<Vec3d> lag_state = p.u;
    for (size_t i = 0; i < lag_state.size(); ++i)
      lag_state[i] += Vec3d{0.01, 0.003 * static_cast<double>(i % 5), 0};
    term.lag(lag_state, 0);
    term.commit(lag_state);
    term.lag(lag_state, 1);
    ASSERT_GT(term.lagged_contacts(), 10);
    const PenaltyContactTerm::Load load = term.load(p.u);
    ASSERT_GT(load.contacts, 10);
    expect_fd(term, p.u);
    // The assembled Hessian: positive semi-definite, and above the exact one (the projection
    // only raises the curvature term's negative eigenvalues to zero): v^T H v >= v^T (H_exact) v.
    std::vector<std::vector<int32_t>> rows(p.rest.size());
    for (const auto& t : faces)
      for (int32_t a : t)
        for (int32_t b : t) rows[static_cast<size_t>(a)].push_back(b);
    BlockSparseMatrix h(rows);
    term.add_hessian(p.u, h, true);
    for (double phase : {0.3, 1.1, 2.9}) {
      std::vector<Vec3d> v(p.u.size()), hv(p.u.size()), pv(p.u.size(), Vec3d{0, 0, 0});
      for (size_t i = 0; i < v.size(); ++i) {
        const double t = static_cast<double>(i);
        v[i] = Vec3d{std::sin(phase * t), std::cos(2 * phase * t), 0.5};
      }
      h.multiply(v, hv);
      term.add_hessian_product(p.u, v, pv);
      double vhv = 0, vpv = 0;
      for (size_t i = 0; i < v.size(); ++i) {
        vhv += dot(v[i], hv[i]);
        vpv += dot(v[i], pv[i]);
      }
      EXPECT_GT(vhv, 0.0);
      EXPECT_GE(vhv, vpv - 1e-12 * std::abs(vhv));
      // The curvature term is a few percent of the normal stiffness here: the two are close.
      EXPECT_NEAR(vhv, vpv, 0.2 * vhv) << "flat " << flat;
    }
  }
}

}  // namespace
}  // namespace zona
