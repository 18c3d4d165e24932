// Tests for engine/sim/recorder_fields.cpp: the frame fields of homogeneous deformations with
// analytic stresses (uniaxial stress for the linear, SVK and stable neo-Hookean laws, with and
// without nodal pressure; a hydrostatic state with no von Mises stress), and the nodal pressure
// at the vertices of a non-uniform state against the force pass's own.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <random>
#include <vector>

#include "engine/fem/fem_element.h"
#include "engine/fem/forces_cpu.h"
#include "engine/mesh/mesh_generate.h"
#include "engine/sim/recorder.h"
#include "tests/engine/physics_test_meshes.h"

namespace zona {
namespace {

constexpr double kYoung = 10e3, kPoisson = 0.3;
constexpr double kEdge = 10e-6;  // box edge [m]

Mesh test_box() { return testing::box_mesh({0, 0, 0}, {kEdge, kEdge, kEdge}, 2, 2, 2); }

Model build(const Mesh& mesh, ConstitutiveModel law, bool nodal = false) {
  ModelDesc d;
  d.constitutive = law;
  d.material.young = kYoung;
  d.material.poisson = kPoisson;
  d.nodal_pressure = nodal;
  Result<Model> m = build_model(mesh, d);
  EXPECT_TRUE(m.ok()) << (m.ok() ? "" : m.error().message);
  return std::move(m).value();
}

// The state u = (F - I) X of a homogeneous deformation gradient F.
State homogeneous_state(const Model& model, const Mat3d& f) {
  State state = make_state(model, 1);
  for (size_t v = 0; v < model.vertex_count(); ++v) {
    const Vec3d x = model.rest_positions[v];
    state.u[v] = f * x - x;
  }
  return state;
}

struct Fields {
  std::vector<VtkField> points, cells;
  const VtkField& point(const std::string& name) const {
    for (const VtkField& f : points)
      if (f.name == name) return f;
    ADD_FAILURE() << "no point field " << name;
    return points.front();
  }
};

Fields fields_of(const Model& model, const State& state) {
  Fields out;
  frame_fields(model, state, &out.points, &out.cells);
  return out;
}

// Every vertex's 9-component tensor equals `want` to `tol` (absolute).
void expect_vertex_tensor(const VtkField& field, const Mat3d& want, double tol) {
  ASSERT_EQ(field.components, 9);
  const size_t nv = field.values.size() / 9;
  for (size_t v = 0; v < nv; ++v)
    for (int r = 0; r < 3; ++r)
      for (int c = 0; c < 3; ++c)
        ASSERT_NEAR(field.values[9 * v + static_cast<size_t>(3 * r + c)], want.m[r][c], tol)
            << field.name << " vertex " << v << " (" << r << ", " << c << ")";
}

Mat3d diag(double a, double b, double c) {
  Mat3d m = Mat3d::zero();
  m.m[0][0] = a;
  m.m[1][1] = b;
  m.m[2][2] = c;
  return m;
}

TEST(RecorderFields, LinearUniaxialStressAtTheVertices) {
  const Mesh box = test_box();
  const Model model = build(box, ConstitutiveModel::kLinear);
  const double eps = 1e-3;
  const State state =
      homogeneous_state(model, diag(1 + eps, 1 - kPoisson * eps, 1 - kPoisson * eps));
  const Fields f = fields_of(model, state);
  // sigma = E eps along x, nothing across; von Mises = E eps.
  expect_vertex_tensor(f.point("stress"), diag(kYoung * eps, 0, 0), 1e-9 * kYoung * eps);
  const double lat = -kPoisson * eps;
  expect_vertex_tensor(f.point("strain"),
                       diag(eps + 0.5 * eps * eps, lat + 0.5 * lat * lat, lat + 0.5 * lat * lat),
                       1e-14);
  for (double m : f.point("von_mises").values) EXPECT_NEAR(m, kYoung * eps, 1e-9 * kYoung * eps);
}

TEST(RecorderFields, SvkUniaxialStressAtTheVertices) {
  const Mesh box = test_box();
  const Model model = build(box, ConstitutiveModel::kSvk);
  const Lame l = lame_from_young_poisson(kYoung, kPoisson);
  // Stretch a along x; the lateral stretch b that leaves S_yy = S_zz = 0:
  // lambda (E_xx + 2 E_yy) + 2 mu E_yy = 0. Then S_xx = E E_xx and sigma_xx = a^2 S_xx / (a b^2).
  const double a = 1.2, exx = 0.5 * (a * a - 1);
  const double eyy = -l.lambda * exx / (2 * (l.lambda + l.mu));
  const double b = std::sqrt(1 + 2 * eyy);
  const State state = homogeneous_state(model, diag(a, b, b));
  const Fields f = fields_of(model, state);
  const double sxx = a * kYoung * exx / (b * b);
  expect_vertex_tensor(f.point("stress"), diag(sxx, 0, 0), 1e-9 * sxx);
  expect_vertex_tensor(f.point("strain"), diag(exx, eyy, eyy), 1e-12);
  for (double m : f.point("von_mises").values) EXPECT_NEAR(m, sxx, 1e-9 * sxx);
}

// The stable neo-Hookean Cauchy stress of a homogeneous F, from its energy in closed form:
// sigma = mu / J F F^T - mu I + (lambda + mu) (J - 1) I.
Mat3d snh_cauchy(const Mat3d& f, const Lame& l) {
  const double j = determinant(f);
  Mat3d s = (l.mu / j) * (f * transpose(f));
  for (int i = 0; i < 3; ++i) s.m[i][i] += -l.mu + (l.lambda + l.mu) * (j - 1);
  return s;
}

TEST(RecorderFields, NeoHookeanStressAtTheVerticesWithAndWithoutNodalPressure) {
  const Mesh box = test_box();
  const Lame l = lame_from_young_poisson(kYoung, kPoisson);
  // A stretch with shear: every component of the tensor is exercised.
  Mat3d f = diag(1.15, 0.95, 0.9);
  f.m[0][1] = 0.08;
  f.m[2][0] = -0.05;
  const Mat3d want = snh_cauchy(f, l);
  const double scale = std::fabs(want.m[0][0]);
  for (bool nodal : {false, true}) {
    SCOPED_TRACE(nodal ? "nodal pressure" : "element pressure");
    const Model model = build(box, ConstitutiveModel::kStableNeoHookean, nodal);
    const Fields f_out = fields_of(model, homogeneous_state(model, f));
    // Under a uniform J the nodal pressure is the element's: the same stress.
    expect_vertex_tensor(f_out.point("stress"), want, 1e-9 * scale);
  }
}

// An inverted element (J < 0) reports its Kirchhoff stress J sigma: symmetric and finite (its
// first Piola stress, which the output once gave there, is not symmetric), and that of the law in
// closed form (SNH: mu F F^T + J (-mu + (lambda + mu) (J - 1)) I; SVK: F S F^T).
TEST(RecorderFields, AnInvertedElementReportsItsSymmetricKirchhoffStress) {
  const Mesh box = test_box();
  const Lame l = lame_from_young_poisson(kYoung, kPoisson);
  Mat3d f = diag(1.1, 0.9, -0.2);  // inverted through z, with shear
  f.m[0][1] = 0.3;
  f.m[1][2] = -0.2;
  const double j = determinant(f);
  ASSERT_LT(j, 0);
  Mat3d snh = l.mu * (f * transpose(f));
  for (int i = 0; i < 3; ++i) snh.m[i][i] += j * (-l.mu + (l.lambda + l.mu) * (j - 1));
  Mat3d h = f;
  for (int i = 0; i < 3; ++i) h.m[i][i] -= 1.0;
  double psi = 0;
  const Mat3d svk = f * isotropic_stress(green_strain(h), l.lambda, l.mu, &psi) * transpose(f);
  for (ConstitutiveModel law : {ConstitutiveModel::kStableNeoHookean, ConstitutiveModel::kSvk}) {
    SCOPED_TRACE(law == ConstitutiveModel::kSvk ? "SVK" : "stable neo-Hookean");
    const Model model = build(box, law);
    const Mat3d& want = law == ConstitutiveModel::kSvk ? svk : snh;
    const Fields out = fields_of(model, homogeneous_state(model, f));
    double scale = 0;
    for (int r = 0; r < 3; ++r)
      for (int c = 0; c < 3; ++c) scale = std::max(scale, std::fabs(want.m[r][c]));
    expect_vertex_tensor(out.point("stress"), want, 1e-9 * scale);
  }
  // Under nodal pressure the element part and the vertex's pressure are both symmetric.
  const Model nodal = build(box, ConstitutiveModel::kStableNeoHookean, true);
  const VtkField& s = fields_of(nodal, homogeneous_state(nodal, f)).point("stress");
  for (size_t v = 0; v < s.values.size() / 9; ++v)
    for (int r = 0; r < 3; ++r)
      for (int c = 0; c < r; ++c) {
        const double a = s.values[9 * v + static_cast<size_t>(3 * r + c)];
        const double b = s.values[9 * v + static_cast<size_t>(3 * c + r)];
        ASSERT_TRUE(std::isfinite(a));
        ASSERT_NEAR(a, b, 1e-12 * std::fabs(a) + 1e-9) << "vertex " << v;
      }
}

TEST(RecorderFields, HydrostaticStateHasNoVonMisesStress) {
  const Mesh box = test_box();
  const double s = 1.02;  // uniform dilation
  for (auto [law, nodal] : {std::pair{ConstitutiveModel::kLinear, false},
                            std::pair{ConstitutiveModel::kSvk, false},
                            std::pair{ConstitutiveModel::kStableNeoHookean, false},
                            std::pair{ConstitutiveModel::kStableNeoHookean, true}}) {
    SCOPED_TRACE(static_cast<int>(law) * 10 + (nodal ? 1 : 0));
    const Model model = build(box, law, nodal);
    const Fields f = fields_of(model, homogeneous_state(model, diag(s, s, s)));
    const VtkField& stress = f.point("stress");
    const VtkField& mises = f.point("von_mises");
    for (size_t v = 0; v < model.vertex_count(); ++v) {
      const double p = stress.values[9 * v];
      EXPECT_GT(p, 100.0);  // a real tension, tens of kPa here
      EXPECT_NEAR(stress.values[9 * v + 4], p, 1e-9 * p);
      EXPECT_NEAR(stress.values[9 * v + 8], p, 1e-9 * p);
      EXPECT_NEAR(stress.values[9 * v + 1], 0.0, 1e-9 * p);
      EXPECT_LT(mises.values[v], 1e-9 * p);
    }
    for (double m : f.cells[1].values) EXPECT_LT(m, 1e-6);
  }
}

TEST(RecorderFields, NodalPressureIsTheVertexPressureOverTheAveragedElementPart) {
  const Mesh box = testing::box_mesh({0, 0, 0}, {kEdge, kEdge, kEdge}, 3, 3, 3);
  const Model model = build(box, ConstitutiveModel::kStableNeoHookean, true);
  const Lame l = lame_from_young_poisson(kYoung, kPoisson);
  // A non-uniform state: each element has its own J.
  State state = make_state(model, 1);
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> jitter(-0.03 * kEdge, 0.03 * kEdge);
  std::vector<Vec3d> u(model.vertex_count());
  for (Vec3d& x : u) x = Vec3d{jitter(rng), jitter(rng), jitter(rng)};
  set_displacement(state, u);
  compute_elastic_forces(model, state);  // the force pass's lambda_v (Jbar_v - 1)
  const Fields f = fields_of(model, state);
  const VtkField& stress = f.point("stress");
  // The element part in closed form: mu / J F F^T - mu I + mu (J - 1) I, volume-weighted.
  std::vector<Mat3d> sum(model.vertex_count(), Mat3d::zero());
  std::vector<double> weight(model.vertex_count(), 0.0);
  for (size_t t = 0; t < model.tet_count(); ++t) {
    const Tet& e = model.tets[t];
    const Vec3d ue[4] = {u[e[0]], u[e[1]], u[e[2]], u[e[3]]};
    Mat3d fe = tet_displacement_gradient(model.tet_shape[t], ue);
    for (int i = 0; i < 3; ++i) fe.m[i][i] += 1.0;
    const double j = determinant(fe);
    Mat3d part = (l.mu / j) * (fe * transpose(fe));
    for (int i = 0; i < 3; ++i) part.m[i][i] += -l.mu + l.mu * (j - 1);
    const double w = std::fabs(model.tet_shape[t].volume);
    for (int32_t v : e) {
      sum[v] = sum[v] + w * part;
      weight[v] += w;
    }
  }
  for (size_t v = 0; v < model.vertex_count(); ++v) {
    Mat3d want = (1.0 / weight[v]) * sum[v];
    const double p = state.vertex_pressure[3 * v];
    for (int i = 0; i < 3; ++i) want.m[i][i] += p;
    for (int r = 0; r < 3; ++r)
      for (int c = 0; c < 3; ++c)
        ASSERT_NEAR(stress.values[9 * v + static_cast<size_t>(3 * r + c)], want.m[r][c],
                    1e-9 * kYoung)
            << "vertex " << v;
  }
  // The pressures differ from vertex to vertex: the test saw a non-uniform state.
  double p_min = 1e300, p_max = -1e300;
  for (size_t v = 0; v < model.vertex_count(); ++v) {
    p_min = std::min(p_min, state.vertex_pressure[3 * v]);
    p_max = std::max(p_max, state.vertex_pressure[3 * v]);
  }
  EXPECT_GT(p_max - p_min, 0.01 * kYoung);
}

TEST(RecorderFields, FrameFieldsOfAUniformStretch) {
  const Mesh box = generate_box_mesh(Vec3d{0, 0, 0}, Vec3d{1, 1, 1}, 2, 2, 2);
  ModelDesc desc;
  desc.material.young = 1e3;
  desc.material.poisson = 0.25;
  Result<Model> model = build_model(box, desc);
  ASSERT_TRUE(model.ok());
  State state = make_state(*model, 1);
  const double s = 1.1;  // stretch along x
  for (size_t v = 0; v < box.vertex_count(); ++v)
    state.u[v] = Vec3d{(s - 1) * box.rest_positions[v].x, 0, 0};
  std::vector<VtkField> points, cells;
  frame_fields(*model, state, &points, &cells);
  ASSERT_EQ(points.size(), 5u);
  EXPECT_EQ(points[0].name, "displacement");
  EXPECT_EQ(points[1].name, "contact");
  for (double c : points[1].values) EXPECT_EQ(c, 0.0);
  EXPECT_EQ(points[2].name, "stress");
  EXPECT_EQ(points[3].name, "strain");
  EXPECT_EQ(points[4].name, "von_mises");
  ASSERT_EQ(cells.size(), 2u);
  EXPECT_EQ(cells[0].name, "green_strain");
  EXPECT_EQ(cells[1].name, "von_mises_stress");
  // E_xx = (s^2 - 1) / 2; Cauchy stress of SVK: sigma = F S F^T / J with S = lambda tr E I +
  // 2 mu E: sigma_xx = s (lambda + 2 mu) E_xx, sigma_yy = sigma_zz = lambda E_xx / s.
  const Lame l = lame_from_young_poisson(1e3, 0.25);
  const double exx = 0.5 * (s * s - 1);
  const double mises = std::fabs(s * (l.lambda + 2 * l.mu) * exx - l.lambda * exx / s);
  for (size_t t = 0; t < model->tet_count(); ++t) {
    EXPECT_NEAR(cells[0].values[6 * t], exx, 1e-12);
    EXPECT_NEAR(cells[0].values[6 * t + 1], 0.0, 1e-12);
    EXPECT_NEAR(cells[1].values[t], mises, 1e-9 * mises);
  }
  for (double m : points[4].values) EXPECT_NEAR(m, mises, 1e-9 * mises);
}

}  // namespace
}  // namespace zona
