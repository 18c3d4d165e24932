// The CPU element pass's packed kernels against the scalar element functions: float64 (four
// tetrahedra per AVX2 pack, eight per AVX-512 pack; SVK, linear and stable neo-Hookean) bit for
// bit without FMA and within 1e-13 of
// the element's largest corner force with it (the AVX2 and AVX-512 FMA passes bit for bit
// against each other), float32 (eight per pack, ElementPrecision::kFloat32) bit for bit against
// fem_element.h at T = float and within a stated tolerance of float64, health bits through the
// packed masks, the inversion-safe SVK's clamped lanes against the scalar clamped element, and
// determinism of the float32 step for any thread count.
#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstring>
#include <tuple>
#include <utility>
#include <vector>

#include "engine/fem/forces_cpu.h"
#include "engine/sim/integrator.h"
#include "tests/engine/physics_test_meshes.h"

namespace zona {
namespace {

using testing::box_mesh;
using testing::vertices_where;

constexpr double kL = 10e-6;  // box edge [m]

// 3 x 3 x 3 cubes: 162 tetrahedra, two chunks, the last batch of four and of eight partial.
Mesh test_box() { return box_mesh({0, 0, 0}, {kL, kL, kL}, 3, 3, 3); }

Model build(const Mesh& mesh, ConstitutiveModel law, ElementPrecision precision) {
  ModelDesc d;
  d.constitutive = law;
  d.element_precision = precision;
  Result<Model> m = build_model(mesh, d);
  EXPECT_TRUE(m.ok()) << (m.ok() ? "" : m.error().message);
  return std::move(m).value();
}

// A smooth non-affine displacement with strains of order `strain`, plus a rigid offset much
// larger than the strain displacements (the float32 path forms edge differences in float64).
std::vector<Vec3d> wavy(const Mesh& mesh, double strain) {
  std::vector<Vec3d> u(mesh.vertex_count());
  for (size_t v = 0; v < u.size(); ++v) {
    const Vec3d x = mesh.rest_positions[v] / kL;
    u[v] = strain * kL *
               Vec3d{std::sin(2.0 * x.y + 0.3) * x.x, 0.5 * std::cos(1.5 * x.z) * x.y + x.x * x.x,
                     -0.4 * x.z * x.x + 0.3 * std::sin(x.y)} +
           Vec3d{3 * kL, -2 * kL, kL};
  }
  return u;
}

// With every corner in a slot of its own (an all-late plan), so that corner_force reads them.
State loaded_state(const Model& model, const std::vector<Vec3d>& u, int threads) {
  State s = make_state(model, threads);
  make_assembly_plan(model, s, s.assembly.segment_count(), /*all_late=*/true);
  set_displacement(s, u);
  return s;
}

std::vector<Vec3d> corner_forces(const Model& model, const State& s) {
  std::vector<Vec3d> f;
  for (size_t t = 0; t < model.tet_count(); ++t)
    for (int c = 0; c < 4; ++c) f.push_back(corner_force(s, t, c));
  return f;
}

// Scalar reference of one element in the pass's precision: forces [N], energy [J], health bits.
template <class T>
double scalar_element(const Model& m, size_t t, const std::vector<Vec3d>& u, Vec3d f[4],
                      uint32_t* bits) {
  const Tet& e = m.tets[t];
  Vec3<T> du[3];
  for (int k = 0; k < 3; ++k) du[k] = vec_cast<T>(u[e[k + 1]] - u[e[0]]);  // double, then round
  const TetShape<T> s = tet_shape_cast<T>(m.tet_shape[t]);
  const T lambda = static_cast<T>(m.tet_lame(t).lambda), mu = static_cast<T>(m.tet_lame(t).mu);
  const Mat3<T> h = tet_displacement_gradient_from_edges(s, du);
  Mat3<T> p;
  T psi;
  if (m.constitutive == ConstitutiveModel::kStableNeoHookean) {
    T jm1;
    psi = snh_first_piola(h, lambda, mu, &p, &jm1);
    *bits = jm1 > T(-1) ? 0u : uint32_t{kElementInverted};
  } else if (m.constitutive == ConstitutiveModel::kSvk) {
    const Mat3<T> strain = green_strain(h);
    *bits = tet_health_from_strain(h, strain);
    const Mat3<T> stress = isotropic_stress(strain, lambda, mu, &psi);
    p = stress + h * stress;
  } else {
    *bits = determinant(Mat3<T>::identity() + h) > T(0) ? 0u : uint32_t{kElementInverted};
    p = isotropic_stress(small_strain(h), lambda, mu, &psi);
  }
  Vec3<T> ft[4];
  tet_forces_from_stress(s, p, ft);
  for (int c = 0; c < 4; ++c) f[c] = vec_cast<double>(ft[c]);
  return static_cast<double>(s.volume * psi);
}

// Every corner force of the pass equals the scalar element function's, bit for bit (or, with
// `fused`, within 1e-13 of the element's largest corner force component: the FMA pass rounds
// differently), and the energy the scalar energies' sum.
template <class T>
void expect_pass_equals_scalar(ConstitutiveModel law, ElementPrecision precision,
                               bool fused = false) {
  const Mesh mesh = test_box();
  const Model model = build(mesh, law, precision);
  const std::vector<Vec3d> u = wavy(mesh, 0.2);
  State s = loaded_state(model, u, 2);
  compute_tet_forces(model, s);
  StepDiagnostics d;
  reduce_tet_chunks(s, d);
  double energy = 0;
  for (size_t t = 0; t < model.tet_count(); ++t) {
    Vec3d f[4];
    uint32_t bits = 0;
    energy += scalar_element<T>(model, t, u, f, &bits);
    double scale = 0;
    for (int c = 0; c < 4; ++c)
      for (int i = 0; i < 3; ++i) scale = std::max(scale, std::abs(f[c][i]));
    for (int c = 0; c < 4; ++c) {
      if (fused) {
        for (int i = 0; i < 3; ++i)
          EXPECT_LE(std::abs(corner_force(s, t, c)[i] - f[c][i]), 1e-13 * scale)
              << "tet " << t << " corner " << c << " component " << i;
      } else {
        const Vec3d pass = corner_force(s, t, c);
        EXPECT_EQ(std::memcmp(&pass, &f[c], sizeof(Vec3d)), 0)
            << "tet " << t << " corner " << c;
      }
    }
  }
  EXPECT_NEAR(d.elastic_energy, energy, 1e-13 * energy);
  EXPECT_GT(energy, 0);
  EXPECT_EQ(d.element_health, 0u);
}

// Both float64 passes without FMA: eight tetrahedra per AVX-512 pack (where the CPU has it) and
// four per AVX2 pack.
TEST(SimdElementPass, Float64CornerForcesEqualTheScalarFunctionsBitForBit) {
  set_cpu_element_fma(false);
  for (int bits : {512, 256}) {
    set_cpu_simd_bits(bits);
    SCOPED_TRACE(::testing::Message() << "simd bits " << cpu_simd_bits());
    expect_pass_equals_scalar<double>(ConstitutiveModel::kSvk, ElementPrecision::kFloat64);
    expect_pass_equals_scalar<double>(ConstitutiveModel::kLinear, ElementPrecision::kFloat64);
  }
  set_cpu_simd_bits(512);
  set_cpu_element_fma(true);
}

// The stable neo-Hookean pass (no FMA in any build): bit for bit at both pack widths, and its
// inverted count and first offender through the lane masks, against the scalar element.
TEST(SimdElementPass, StableNeoHookeanCornerForcesAndHealthEqualTheScalarElement) {
  for (int bits : {512, 256}) {
    set_cpu_simd_bits(bits);
    SCOPED_TRACE(::testing::Message() << "simd bits " << cpu_simd_bits());
    expect_pass_equals_scalar<double>(ConstitutiveModel::kStableNeoHookean,
                                      ElementPrecision::kFloat64);
    // Inverted elements around one vertex pushed through its neighbours (the law stays finite).
    const Mesh mesh = test_box();
    std::vector<Vec3d> u(mesh.vertex_count(), Vec3d{0, 0, 0});
    const size_t inner = 1 + 4 * (1 + 4 * 1);  // vertex (1, 1, 1)
    u[inner] = Vec3d{0.45 * kL, 0.5 * kL, 0.48 * kL};
    const Model m = build(mesh, ConstitutiveModel::kStableNeoHookean, ElementPrecision::kFloat64);
    State s = loaded_state(m, u, 2);
    compute_tet_forces(m, s);
    StepDiagnostics d;
    reduce_tet_chunks(s, d);
    int64_t inverted = 0, first_inverted = -1;
    for (size_t t = 0; t < m.tet_count(); ++t) {
      Vec3d f[4];
      uint32_t health = 0;
      scalar_element<double>(m, t, u, f, &health);
      if ((health & kElementInverted) && inverted++ == 0) first_inverted = static_cast<int64_t>(t);
      for (int c = 0; c < 4; ++c) {
        const Vec3d pass = corner_force(s, t, c);
        EXPECT_EQ(std::memcmp(&pass, &f[c], sizeof(Vec3d)), 0) << "tet " << t << " corner " << c;
        EXPECT_TRUE(std::isfinite(pass.x) && std::isfinite(pass.y) && std::isfinite(pass.z));
      }
    }
    ASSERT_GT(inverted, 0);
    EXPECT_EQ(d.inverted_count, inverted);
    EXPECT_EQ(d.first_inverted, first_inverted);
    EXPECT_EQ(d.element_health, uint32_t{kElementInverted});
  }
  set_cpu_simd_bits(512);
}

// The fused (FMA) float64 passes, where the CPU has FMA: within 1e-13 of the scalar functions.
TEST(SimdElementPass, Float64FusedCornerForcesAreWithin1e13OfTheScalarFunctions) {
  set_cpu_element_fma(true);
  if (!cpu_element_fma()) GTEST_SKIP() << "no FMA on this CPU (or ZONA_CPU_FMA=0)";
  // 512-bit packs; 256-bit packs with 16 and with 32 registers (AVX-512VL encoding).
  for (const auto& [bits, registers] : {std::pair{512, 32}, {256, 16}, {256, 32}}) {
    set_cpu_simd_bits(bits);
    set_cpu_simd_registers(registers);
    SCOPED_TRACE(::testing::Message() << "simd bits " << cpu_simd_bits() << ", registers "
                                      << cpu_simd_registers());
    expect_pass_equals_scalar<double>(ConstitutiveModel::kSvk, ElementPrecision::kFloat64, true);
    expect_pass_equals_scalar<double>(ConstitutiveModel::kLinear, ElementPrecision::kFloat64,
                                      true);
  }
  set_cpu_simd_bits(512);
  set_cpu_simd_registers(32);
}

// The fused passes differ from the scalar functions (else FMA would not be in use) but the AVX2
// and AVX-512 ones (and the AVX2 one encoded with AVX-512VL's 32 registers) agree bit for bit:
// the same fused operations in the same order per lane.
// Two boxes: the last chunk's last batch holds 2 lanes (162 tetrahedra) and 6 lanes (270: a full
// group of four and two more, which the eight-lane pass must sum as the four-lane ones do).
TEST(SimdElementPass, Float64FusedPassesAgreeBitForBitAcrossPackWidths) {
  set_cpu_element_fma(true);
  if (!cpu_element_fma()) GTEST_SKIP() << "no FMA on this CPU (or ZONA_CPU_FMA=0)";
  const Mesh boxes[] = {test_box(), box_mesh({0, 0, 0}, {kL, kL, kL}, 5, 3, 3)};
  for (const Mesh& mesh : boxes) {
    for (double strain : {0.2, 0.13, 0.07, 0.03}) {  // a wrong order can round alike
      for (ConstitutiveModel law : {ConstitutiveModel::kSvk, ConstitutiveModel::kLinear}) {
        SCOPED_TRACE(::testing::Message()
                     << mesh.tet_count() << " tetrahedra, strain " << strain);
        const std::vector<Vec3d> u = wavy(mesh, strain);
        const Model model = build(mesh, law, ElementPrecision::kFloat64);
        std::vector<std::vector<Vec3d>> forces;
        std::vector<std::vector<double>> energies;  // per chunk: a sum's order shows there
        for (const auto& [bits, registers] : {std::pair{256, 16}, {256, 32}, {512, 32}}) {
          set_cpu_simd_bits(bits);
          set_cpu_simd_registers(registers);
          State s = loaded_state(model, u, 2);
          compute_tet_forces(model, s);
          forces.push_back(corner_forces(model, s));
          energies.emplace_back();
          for (const TetChunkResult& r : s.tet_chunks)
            energies.back().push_back(r.elastic_energy);
        }
        set_cpu_element_fma(false);
        State plain = loaded_state(model, u, 2);
        compute_tet_forces(model, plain);
        set_cpu_element_fma(true);
        EXPECT_NE(std::memcmp(forces[0].data(), corner_forces(model, plain).data(),
                              forces[0].size() * sizeof(Vec3d)),
                  0);
        for (size_t k = 1; k < forces.size(); ++k) {
          EXPECT_EQ(
              std::memcmp(forces[0].data(), forces[k].data(), forces[0].size() * sizeof(Vec3d)), 0)
              << "configuration " << k;
          EXPECT_EQ(std::memcmp(energies[0].data(), energies[k].data(),
                                energies[0].size() * sizeof(double)),
                    0)
              << "configuration " << k;
        }
      }
    }
  }
  set_cpu_simd_bits(512);
  set_cpu_simd_registers(32);
}

TEST(SimdElementPass, Float32CornerForcesEqualTheScalarFloatFunctionsBitForBit) {
  expect_pass_equals_scalar<float>(ConstitutiveModel::kSvk, ElementPrecision::kFloat32);
  expect_pass_equals_scalar<float>(ConstitutiveModel::kLinear, ElementPrecision::kFloat32);
}

// The stated tolerance of float32 element math (docs/performance.md): vertex forces within
// 2e-6 of the largest force, energy within 1e-6, at strains of 2 % and 20 %.
TEST(SimdElementPass, Float32ForcesAreWithinTheStatedToleranceOfFloat64) {
  const Mesh mesh = test_box();
  for (ConstitutiveModel law : {ConstitutiveModel::kSvk, ConstitutiveModel::kLinear})
    for (double strain : {0.02, 0.2}) {
      const std::vector<Vec3d> u = wavy(mesh, strain);
      const Model m64 = build(mesh, law, ElementPrecision::kFloat64);
      const Model m32 = build(mesh, law, ElementPrecision::kFloat32);
      State s64 = loaded_state(m64, u, 1), s32 = loaded_state(m32, u, 1);
      compute_elastic_forces(m64, s64);
      compute_elastic_forces(m32, s32);
      double scale = 0, err = 0;
      for (size_t v = 0; v < u.size(); ++v) {
        scale = std::max(scale, norm(s64.force[v]));
        err = std::max(err, norm(s32.force[v] - s64.force[v]));
      }
      EXPECT_GT(err, 0) << "float32 must differ from float64 somewhere";
      EXPECT_LE(err, 2e-6 * scale) << "strain " << strain;
      EXPECT_NEAR(s32.diag.elastic_energy, s64.diag.elastic_energy,
                  1e-6 * s64.diag.elastic_energy);
    }
}

// Inverted and collapsing elements around one vertex pushed through its neighbours: the packed
// masks give the scalar functions' counts and first offenders, in both precisions.
TEST(SimdElementPass, HealthBitsMatchTheScalarChecks) {
  const Mesh mesh = test_box();
  std::vector<Vec3d> u(mesh.vertex_count(), Vec3d{0, 0, 0});
  const size_t inner = 1 + 4 * (1 + 4 * 1);  // vertex (1, 1, 1)
  u[inner] = Vec3d{0.45 * kL, 0.5 * kL, 0.48 * kL};
  u[inner + 1] = Vec3d{-0.2 * kL, 0, 0};
  // Bits, precision, vector registers (256-bit fused passes: 32 is the AVX-512VL encoding, whose
  // scatter and filter differ from the AVX2 one's).
  const std::tuple<int, ElementPrecision, int> cases[] = {{512, ElementPrecision::kFloat64, 32},
                                                          {256, ElementPrecision::kFloat64, 32},
                                                          {256, ElementPrecision::kFloat64, 16},
                                                          {256, ElementPrecision::kFloat32, 32}};
  for (const auto& [simd_bits, precision, registers] : cases) {
    set_cpu_simd_bits(simd_bits);
    set_cpu_simd_registers(registers);
    SCOPED_TRACE(::testing::Message() << "simd bits " << cpu_simd_bits() << " registers "
                                      << cpu_simd_registers());
    const Model m = build(mesh, ConstitutiveModel::kSvk, precision);
    State s = loaded_state(m, u, 2);
    compute_tet_forces(m, s);
    StepDiagnostics d;
    reduce_tet_chunks(s, d);
    int64_t inverted = 0, collapsing = 0, first_inverted = -1, first_collapsing = -1;
    for (size_t t = 0; t < m.tet_count(); ++t) {
      Vec3d f[4];
      uint32_t bits = 0;
      if (precision == ElementPrecision::kFloat64)
        scalar_element<double>(m, t, u, f, &bits);
      else
        scalar_element<float>(m, t, u, f, &bits);
      if ((bits & kElementInverted) && inverted++ == 0) first_inverted = static_cast<int64_t>(t);
      if ((bits & kElementCollapsing) && collapsing++ == 0)
        first_collapsing = static_cast<int64_t>(t);
    }
    ASSERT_GT(inverted, 0);
    ASSERT_GT(collapsing, 0);
    EXPECT_EQ(d.inverted_count, inverted);
    EXPECT_EQ(d.collapsing_count, collapsing);
    EXPECT_EQ(d.first_inverted, first_inverted);
    EXPECT_EQ(d.first_collapsing, first_collapsing);
    EXPECT_EQ(d.element_health, uint32_t{kElementInverted | kElementCollapsing});
  }
  set_cpu_simd_bits(512);
  set_cpu_simd_registers(32);
}

// A mirror image of the box (x -> -x: F = diag(-1, 1, 1)) is strain-free for SVK (C = I, E = 0:
// no force, no energy) yet every element is inverted. The fused SVK pass forms the health filter's
// |H|^2 from tr(2E) - 2 tr(H) instead of summing squares: it must still see |H|^2 = 4 and flag
// every element, as must every other pass (a filter on E alone would pass them all).
TEST(SimdElementPass, MirroredMeshIsStrainFreeAndEveryElementInverted) {
  const Mesh mesh = test_box();
  std::vector<Vec3d> u(mesh.vertex_count());
  for (size_t v = 0; v < u.size(); ++v) u[v] = Vec3d{-2.0 * mesh.rest_positions[v].x, 0, 0};
  for (ConstitutiveModel law : {ConstitutiveModel::kSvk, ConstitutiveModel::kLinear}) {
    const std::tuple<bool, int, int> passes[] = {{true, 256, 32}, {true, 256, 16}, {true, 512, 32},
                                                 {false, 256, 32}, {false, 512, 32}};
    for (const auto& [fused, simd_bits, registers] : passes) {
      set_cpu_element_fma(fused);
      set_cpu_simd_bits(simd_bits);
      set_cpu_simd_registers(registers);
      SCOPED_TRACE(::testing::Message() << "law " << static_cast<int>(law) << " fma "
                                        << cpu_element_fma() << " simd bits " << cpu_simd_bits()
                                        << " registers " << cpu_simd_registers());
      const Model m = build(mesh, law, ElementPrecision::kFloat64);
      State s = loaded_state(m, u, 2);
      compute_tet_forces(m, s);
      StepDiagnostics d;
      reduce_tet_chunks(s, d);
      EXPECT_EQ(d.inverted_count, static_cast<int64_t>(m.tet_count()));
      EXPECT_EQ(d.first_inverted, 0);
      EXPECT_TRUE(d.element_health & kElementInverted);
      if (law == ConstitutiveModel::kSvk) {
        // E = 0 up to the rounding of H: forces and energy below 1e-9 of a 1 % stretch's.
        std::vector<Vec3d> stretch(u.size());
        for (size_t v = 0; v < u.size(); ++v)
          stretch[v] = Vec3d{0.01 * mesh.rest_positions[v].x, 0, 0};
        State ref = loaded_state(m, stretch, 2);
        compute_tet_forces(m, ref);
        StepDiagnostics dr;
        reduce_tet_chunks(ref, dr);
        double f_ref = 0;
        for (const Vec3d& f : corner_forces(m, ref)) f_ref = std::max(f_ref, norm(f));
        ASSERT_GT(f_ref, 0);
        EXPECT_LE(std::abs(d.elastic_energy), 1e-9 * dr.elastic_energy);
        for (const Vec3d& f : corner_forces(m, s)) EXPECT_LE(norm(f), 1e-9 * f_ref);
      }
    }
  }
  set_cpu_simd_bits(512);
  set_cpu_simd_registers(32);
  set_cpu_element_fma(true);
}

// The batched passes skip the exact health checks where every lane has |H|^2 below
// kHealthCheckSkipBelowGradientSq: the scalar checks must pass for every such H, in both
// precisions, in the worst directions (uniaxial and uniform compression, shear) and in random
// ones; and a gradient a few times larger must be able to fail them.
TEST(SimdElementPass, HealthChecksCannotFailBelowTheSkipBound) {
  const double r = std::sqrt(kHealthCheckSkipBelowGradientSq);  // largest |H| skipped
  std::vector<Mat3d> gradients;
  Mat3d h{};
  h.m[0][0] = -r;
  gradients.push_back(h);
  gradients.push_back((-r / std::sqrt(3.0)) * Mat3d::identity());
  h = Mat3d{};
  h.m[0][1] = r;
  gradients.push_back(h);
  uint64_t seed = 12345;
  auto next = [&seed] {
    seed = seed * 6364136223846793005ull + 1442695040888963407ull;
    return static_cast<double>(seed >> 11) / 9007199254740992.0 - 0.5;
  };
  for (int i = 0; i < 2000; ++i) {
    Mat3d g{};
    double norm_sq = 0;
    for (auto& row : g.m)
      for (double& x : row) {
        x = next();
        norm_sq += x * x;
      }
    gradients.push_back((r / std::sqrt(norm_sq)) * g);
  }
  for (const Mat3d& hd : gradients) {
    Mat3<float> hf{};
    for (int a = 0; a < 3; ++a)
      for (int b = 0; b < 3; ++b) hf.m[a][b] = static_cast<float>(hd.m[a][b]);
    ASSERT_EQ(tet_health(hd), 0u);
    ASSERT_EQ(tet_health(hf), 0u);
  }
  h = Mat3d{};
  h.m[0][0] = -5 * r;  // stretch 0.5, below 1/sqrt(3)
  EXPECT_EQ(tet_health(h), uint32_t{kElementCollapsing});
}

// The scalar clamped element, as SvkGradientClamped (engine/fem/forces_cpu.cpp) composes it: forces
// [N], energy [J], health bits with kElementClamped where it clamps.
double scalar_clamped_element(const Model& m, size_t t, const std::vector<Vec3d>& u, Vec3d f[4],
                              uint32_t* bits) {
  const Tet& e = m.tets[t];
  const Vec3d ue[4] = {u[e[0]], u[e[1]], u[e[2]], u[e[3]]};
  const TetShape<double>& s = m.tet_shape[t];
  const Lame& l = m.tet_lame(t);
  const Mat3d h = tet_displacement_gradient(s, ue);
  const Mat3d strain = green_strain(h);
  *bits = tet_health_from_strain(h, strain);
  double psi;
  Mat3d p;
  if (tet_health_from_strain(h, strain, m.clamp_stretch) != 0) {
    psi = svk_first_piola_clamped(h, l.lambda, l.mu, m.clamp_stretch, &p);
    *bits |= kElementClamped;
  } else {
    const Mat3d stress = isotropic_stress(strain, l.lambda, l.mu, &psi);
    p = stress + h * stress;
  }
  tet_forces_from_stress(s, p, f);
  return s.volume * psi;
}

// The inversion-safe SVK runs in the batched passes: on a box strained by ~15 % everywhere (every
// batch fails the |H|^2 filter) with one vertex pushed through its neighbours and the next one
// pulled in (inverted, collapsing and merely compressed elements), every corner force of a
// clamped element equals the scalar clamped element's bit for bit, and every other corner force
// the unclamped pass's standard (bit for bit without FMA, within 1e-13 of the element's largest
// corner force with it); counts, first offenders and flags are the scalar ones. For the default
// clamp stretch (the health check decides the clamp) and for 0.85 (its own minors, a filter bound
// below the health check's), on boxes whose last batch holds 2 and 6 lanes.
TEST(SimdElementPass, ClampedSvkLanesEqualTheScalarClampedElement) {
  struct Box {
    int nx, ny, nz;
  };
  for (const Box& box : {Box{3, 3, 3}, Box{5, 3, 3}}) {
    const Mesh mesh = box_mesh({0, 0, 0}, {kL, kL, kL}, box.nx, box.ny, box.nz);
    std::vector<Vec3d> u = wavy(mesh, 0.15);
    const size_t inner = static_cast<size_t>(1 + (box.nx + 1) * (1 + (box.ny + 1) * 1));  // (1,1,1)
    u[inner] += Vec3d{0.45 * kL, 0.5 * kL, 0.48 * kL};
    u[inner + 1] += Vec3d{-0.2 * kL, 0, 0};
    for (double clamp_stretch : {kSvkCollapseStretch, 0.85}) {
      ModelDesc desc;
      desc.inversion = InversionHandling::kClampStretch;
      desc.clamp_stretch = clamp_stretch;
      const Model m = build_model(mesh, desc).value();
      // The reference, element by element.
      const size_t nt = m.tet_count();
      std::vector<std::array<Vec3d, 4>> ref(nt);
      std::vector<uint32_t> ref_bits(nt);
      double ref_energy = 0, energy_scale = 0;
      int64_t clamped = 0, inverted = 0, collapsing = 0, first_inverted = -1, first_collapsing = -1,
              clamped_healthy = 0;
      uint32_t health = 0;
      for (size_t t = 0; t < nt; ++t) {
        const double w = scalar_clamped_element(m, t, u, ref[t].data(), &ref_bits[t]);
        ref_energy += w;
        energy_scale += std::abs(w);
        const uint32_t bits = ref_bits[t];
        health |= bits;
        clamped += (bits & kElementClamped) != 0;
        clamped_healthy += bits == kElementClamped;  // clamped, yet neither inverted nor collapsing
        if ((bits & kElementInverted) && inverted++ == 0) first_inverted = static_cast<int64_t>(t);
        if ((bits & kElementCollapsing) && collapsing++ == 0)
          first_collapsing = static_cast<int64_t>(t);
      }
      // Batches of four with clamped and unclamped lanes: the case the pass must splice.
      int mixed = 0;
      for (size_t t0 = 0; t0 < nt; t0 += 4) {
        int lanes_clamped = 0;
        const size_t end = std::min(nt, t0 + 4);
        for (size_t t = t0; t < end; ++t) lanes_clamped += (ref_bits[t] & kElementClamped) != 0;
        mixed += lanes_clamped > 0 && lanes_clamped < static_cast<int>(end - t0);
      }
      ASSERT_GT(inverted, 0);
      ASSERT_GT(clamped, inverted);
      ASSERT_LT(clamped, static_cast<int64_t>(nt) / 2);
      ASSERT_GT(mixed, 0);
      if (clamp_stretch != kSvkCollapseStretch) {
        ASSERT_GT(clamped_healthy, 0);
      }
      // Every float64 pass: (fused, bits, registers).
      const std::tuple<bool, int, int> passes[] = {
          {false, 512, 32}, {false, 256, 32}, {true, 512, 32}, {true, 256, 16}, {true, 256, 32}};
      for (const auto& [fused, simd_bits, registers] : passes) {
        set_cpu_element_fma(fused);
        if (fused && !cpu_element_fma()) continue;  // no FMA on this CPU (or ZONA_CPU_FMA=0)
        set_cpu_simd_bits(simd_bits);
        set_cpu_simd_registers(registers);
        SCOPED_TRACE(::testing::Message()
                     << nt << " tetrahedra, clamp stretch " << clamp_stretch << ", fma "
                     << cpu_element_fma() << ", simd bits " << cpu_simd_bits() << ", registers "
                     << cpu_simd_registers());
        State s = loaded_state(m, u, 2);
        compute_tet_forces(m, s);
        StepDiagnostics d;
        reduce_tet_chunks(s, d);
        for (size_t t = 0; t < nt; ++t) {
          double scale = 0;
          for (const Vec3d& f : ref[t])
            for (int i = 0; i < 3; ++i) scale = std::max(scale, std::abs(f[i]));
          for (int c = 0; c < 4; ++c) {
            const Vec3d pass = corner_force(s, t, c);
            if ((ref_bits[t] & kElementClamped) || !fused) {
              EXPECT_EQ(std::memcmp(&pass, &ref[t][c], sizeof(Vec3d)), 0)
                  << "tet " << t << " corner " << c << " bits " << ref_bits[t];
            } else {
              for (int i = 0; i < 3; ++i)
                EXPECT_LE(std::abs(pass[i] - ref[t][c][i]), 1e-13 * scale)
                    << "tet " << t << " corner " << c << " component " << i;
            }
          }
        }
        EXPECT_EQ(d.clamped_count, clamped);
        EXPECT_EQ(d.inverted_count, inverted);
        EXPECT_EQ(d.collapsing_count, collapsing);
        EXPECT_EQ(d.first_inverted, first_inverted);
        EXPECT_EQ(d.first_collapsing, first_collapsing);
        EXPECT_EQ(d.element_health, health);
        EXPECT_NEAR(d.elastic_energy, ref_energy, 1e-13 * energy_scale);
      }
    }
  }
  set_cpu_element_fma(true);
  set_cpu_simd_bits(512);
  set_cpu_simd_registers(32);
}

// A rotation about a unit axis (Rodrigues) [-].
Mat3d rotation(Vec3d axis, double angle) {
  axis = axis / norm(axis);
  const double c = std::cos(angle), s = std::sin(angle);
  const Mat3d k{{{0, -axis.z, axis.y}, {axis.z, 0, -axis.x}, {-axis.y, axis.x, 0}}};
  return Mat3d::identity() + s * k + (1 - c) * (k * k);
}

// The packed clamped stress takes, lane by lane, every branch of svk_first_piola_clamped: on a
// soup of separate tetrahedra (each its own four vertices, so that each gets its own F) deformed
// by F = 0 exactly (no direction to start U from), mirror images, partial collapse (rank 1 and
// 2: the Gram-Schmidt fallback), repeated principal stretches (no Jacobi rotation), a C whose
// tiny off-diagonal entry beside a large diagonal gap takes Jacobi's large-angle tangent,
// random rotations of random signed stretches, and healthy ones between them, every clamped
// element's corner forces equal the scalar clamped element's bit for bit in every float64 pass,
// and the counts are the scalar ones. (Each of these branches, broken on purpose in the pass,
// failed this test.)
TEST(SimdElementPass, ClampedLanesEqualTheScalarClampedElementOnEveryBranch) {
  uint64_t seed = 4242;
  auto next = [&seed] {  // uniform in [-0.5, 0.5)
    seed = seed * 6364136223846793005ull + 1442695040888963407ull;
    return static_cast<double>(seed >> 11) / 9007199254740992.0 - 0.5;
  };
  auto random_vec = [&] { return Vec3d{next(), next(), next()}; };
  std::vector<Mat3d> deformations;
  auto diag = [](double a, double b, double c) { return Mat3d{{{a, 0, 0}, {0, b, 0}, {0, 0, c}}}; };
  // The first two on exact geometry (below): F = 0 exactly (no direction to start U from), and
  // a C = F^T F whose (0, 2) entry is tiny beside C22 - C00 while (0, 1) keeps Jacobi going.
  deformations.push_back(Mat3d::zero());
  deformations.push_back(Mat3d{{{1, 0.5, std::ldexp(1.0, -40)}, {0, 0.5, 0}, {0, 0, 64}}});
  constexpr size_t kExact = 2;
  deformations.push_back(diag(1, 1, -1));
  deformations.push_back(diag(-1, -1, -1));
  deformations.push_back(Mat3d::zero());
  deformations.push_back(outer(Vec3d{0.3, -0.2, 0.9}, Vec3d{0.5, 0.1, -0.4}));  // rank 1
  deformations.push_back(outer(Vec3d{1, 0, 0}, Vec3d{0, 1, 0}) +
                         outer(Vec3d{0, 0.5, 0.2}, Vec3d{0, 0, 1}));  // rank 2
  deformations.push_back(diag(0.3, 0.3, 0.3));
  deformations.push_back(diag(-0.5, 0.4, 0.4));
  deformations.push_back(diag(1e6, 1, 0.1));
  deformations.push_back(diag(2e3, 1e-3, 0.5));
  deformations.push_back(rotation({1, 2, 3}, 0.7) * diag(0.5, 0.5, 1.2));
  for (int i = 0; i < 600; ++i) {
    const Mat3d rot = rotation(random_vec(), 6 * next());
    const Mat3d rot2 = rotation(random_vec(), 6 * next());
    switch (i % 6) {
      case 0:  // random signed stretches, some below every clamp
        deformations.push_back(rot * diag(1 + next(), 0.9 + next(), 1.5 * next()) * rot2);
        break;
      case 1:  // healthy: within a few % of a rotation
        deformations.push_back(rot * (Mat3d::identity() + 0.05 * diag(next(), next(), next())));
        break;
      case 2:  // one stretch just around the default clamp
        deformations.push_back(rot * diag(1, 1, kSvkCollapseStretch + 0.02 * next()) * rot2);
        break;
      case 3:  // anisotropic
        deformations.push_back(rot * diag(1e4 * (1 + next()), 0.2 + next(), 1e-3 * next()));
        break;
      case 4:  // a rank-1 and a small random part
        deformations.push_back(outer(random_vec(), random_vec()) +
                               1e-9 * diag(next(), next(), next()));
        break;
      default:  // compressed and sheared
        deformations.push_back(Mat3d{{{0.2 + next(), next(), 0}, {0, 0.3, next()}, {0, 0, 0.4}}});
        break;
    }
  }
  // The soup: tetrahedron k's rest shape a random perturbation of the corner tetrahedron with
  // edge e = 2^-17 m (~kL), its vertices displaced by (F_k - I) X plus an offset; the first
  // kExact unperturbed and without offset, so that H = F_k - I exactly (powers of two).
  const double e = std::ldexp(1.0, -17);
  Mesh mesh;
  for (size_t k = 0; k < deformations.size(); ++k) {
    const Vec3d origin{std::ldexp(static_cast<double>(k), -15), 0, 0};
    const double jitter = k < kExact ? 0.0 : 0.1 * e;
    const Vec3d corners[4] = {
        Vec3d{0, 0, 0} + jitter * random_vec(), Vec3d{e, 0, 0} + jitter * random_vec(),
        Vec3d{0, e, 0} + jitter * random_vec(), Vec3d{0, 0, e} + jitter * random_vec()};
    const int32_t v0 = static_cast<int32_t>(mesh.rest_positions.size());
    for (const Vec3d& c : corners) mesh.rest_positions.push_back(origin + c);
    mesh.tets.push_back(Tet{v0, v0 + 1, v0 + 2, v0 + 3});
    mesh.tet_region.push_back(0);
  }
  std::vector<Vec3d> u(mesh.vertex_count());
  for (size_t k = 0; k < deformations.size(); ++k)
    for (int c = 0; c < 4; ++c) {
      const size_t v = 4 * k + static_cast<size_t>(c);
      const Vec3d x = mesh.rest_positions[v] - mesh.rest_positions[4 * k];
      const Vec3d offset = k < kExact ? Vec3d{0, 0, 0} : Vec3d{kL, -2 * kL, 0.5 * kL};
      u[v] = (deformations[k] - Mat3d::identity()) * x + offset;
    }
  for (double clamp_stretch : {kSvkCollapseStretch, 0.85, 0.2}) {
    ModelDesc desc;
    desc.inversion = InversionHandling::kClampStretch;
    desc.clamp_stretch = clamp_stretch;
    const Model m = build_model(mesh, desc).value();
    const size_t nt = m.tet_count();
    std::vector<std::array<Vec3d, 4>> ref(nt);
    int64_t clamped = 0, inverted = 0, collapsing = 0;
    std::vector<uint32_t> ref_bits(nt);
    for (size_t t = 0; t < nt; ++t) {
      scalar_clamped_element(m, t, u, ref[t].data(), &ref_bits[t]);
      clamped += (ref_bits[t] & kElementClamped) != 0;
      inverted += (ref_bits[t] & kElementInverted) != 0;
      collapsing += (ref_bits[t] & kElementCollapsing) != 0;
    }
    ASSERT_GT(clamped, static_cast<int64_t>(nt) / 4);
    ASSERT_LT(clamped, static_cast<int64_t>(nt));
    const std::tuple<bool, int, int> passes[] = {
        {false, 512, 32}, {false, 256, 32}, {true, 512, 32}, {true, 256, 16}, {true, 256, 32}};
    for (const auto& [fused, simd_bits, registers] : passes) {
      set_cpu_element_fma(fused);
      if (fused && !cpu_element_fma()) continue;
      set_cpu_simd_bits(simd_bits);
      set_cpu_simd_registers(registers);
      SCOPED_TRACE(::testing::Message()
                   << "clamp stretch " << clamp_stretch << ", fma " << cpu_element_fma()
                   << ", simd bits " << cpu_simd_bits() << ", registers " << cpu_simd_registers());
      State s = loaded_state(m, u, 2);
      compute_tet_forces(m, s);
      StepDiagnostics d;
      reduce_tet_chunks(s, d);
      for (size_t t = 0; t < nt; ++t) {
        if (!(ref_bits[t] & kElementClamped)) continue;
        for (int c = 0; c < 4; ++c) {
          const Vec3d pass = corner_force(s, t, c);
          EXPECT_EQ(std::memcmp(&pass, &ref[t][c], sizeof(Vec3d)), 0)
              << "tet " << t << " corner " << c << ": " << pass.x << " " << pass.y << " " << pass.z
              << " against " << ref[t][c].x << " " << ref[t][c].y << " " << ref[t][c].z;
        }
      }
      EXPECT_EQ(d.clamped_count, clamped);
      EXPECT_EQ(d.inverted_count, inverted);
      EXPECT_EQ(d.collapsing_count, collapsing);
    }
  }
  set_cpu_element_fma(true);
  set_cpu_simd_bits(512);
  set_cpu_simd_registers(32);
}

// The clamped passes look for clamped elements only where some lane has |H|^2 at or above
// clamp_check_skip_below_gradient_sq: below it the scalar clamp and health checks must pass for
// every H, in the worst directions and random ones, for clamp stretches from 0.1 to 0.999; a
// stretch just below the clamp must fail them; the bound is never above the health check's.
TEST(SimdElementPass, ClampChecksCannotFailBelowTheClampSkipBound) {
  uint64_t seed = 777;
  auto next = [&seed] {
    seed = seed * 6364136223846793005ull + 1442695040888963407ull;
    return static_cast<double>(seed >> 11) / 9007199254740992.0 - 0.5;
  };
  for (double stretch : {0.1, kSvkCollapseStretch, 0.7, 0.8, 0.9, 0.95, 0.99, 0.999}) {
    SCOPED_TRACE(::testing::Message() << "clamp stretch " << stretch);
    const double bound = clamp_check_skip_below_gradient_sq(stretch);
    ASSERT_GT(bound, 0);
    ASSERT_LE(bound, kHealthCheckSkipBelowGradientSq);
    const double r = std::sqrt(bound);  // largest |H| skipped
    std::vector<Mat3d> gradients;
    Mat3d h{};
    h.m[0][0] = -r;
    gradients.push_back(h);
    gradients.push_back((-r / std::sqrt(3.0)) * Mat3d::identity());
    h = Mat3d{};
    h.m[0][1] = r;
    gradients.push_back(h);
    for (int i = 0; i < 2000; ++i) {
      Mat3d g{};
      double norm_sq = 0;
      for (auto& row : g.m)
        for (double& x : row) {
          x = next();
          norm_sq += x * x;
        }
      gradients.push_back((r / std::sqrt(norm_sq)) * g);
    }
    for (const Mat3d& hd : gradients) {
      ASSERT_EQ(tet_health(hd, stretch), 0u);
      ASSERT_EQ(tet_health(hd), 0u);
    }
    h = Mat3d{};
    h.m[0][0] = -(1 - stretch) * 1.001;  // stretch 0.1 % of (1 - s) below s
    EXPECT_NE(tet_health(h, stretch) & kElementCollapsing, 0u);
  }
  EXPECT_EQ(clamp_check_skip_below_gradient_sq(kSvkCollapseStretch),
            kHealthCheckSkipBelowGradientSq);
  EXPECT_EQ(clamp_check_skip_below_gradient_sq(1 - 1e-7), 0.0);  // every batch checked
}

// The float32 step is as deterministic as the float64 one: the same bits for 1, 2 and 3 threads
// and on a second run.
TEST(SimdElementPass, Float32StepIsBitwiseIdenticalForAnyThreadCount) {
  const Mesh mesh = box_mesh({0, 0, 0}, {kL, kL, kL}, 5, 4, 4);
  ModelDesc d;
  d.fixed_vertices = vertices_where(mesh, 2, 0.0, 1e-9 * kL);
  d.material.damping = 1e5;
  d.element_precision = ElementPrecision::kFloat32;
  const Model m = build_model(mesh, d).value();
  std::vector<Vec3d> u0(mesh.vertex_count(), Vec3d{0, 0, 0});
  for (size_t v = 0; v < u0.size(); ++v)
    if (!m.vertex_fixed[v]) u0[v] = 0.03 * mesh.rest_positions[v].z * Vec3d{1, -0.5, 0.2};
  std::vector<std::vector<Vec3d>> finals;
  std::vector<double> energies;
  for (int threads : {1, 2, 3, 2}) {
    State s = loaded_state(m, u0, threads);
    for (int i = 0; i < 40; ++i) ASSERT_EQ(step(m, s) & kStepNotAdvanced, 0u);
    finals.push_back(s.u);
    energies.push_back(s.diag.elastic_energy + s.diag.kinetic_energy);
  }
  for (size_t i = 1; i < finals.size(); ++i) {
    EXPECT_EQ(std::memcmp(finals[0].data(), finals[i].data(), finals[0].size() * sizeof(Vec3d)),
              0);
    EXPECT_EQ(std::memcmp(&energies[0], &energies[i], sizeof(double)), 0);
  }
}

TEST(SimdElementPass, Float32IsRefusedWhereItIsNotImplemented) {
  const Mesh mesh = test_box();
  ModelDesc d;
  d.element_precision = ElementPrecision::kFloat32;
  d.formulation = Formulation::kTensorRebuilt;
  const Result<Model> tensor = build_model(mesh, d);
  ASSERT_FALSE(tensor.ok());
  EXPECT_NE(tensor.error().message.find("float32"), std::string::npos);
  d.formulation = Formulation::kGradient;
  d.inversion = InversionHandling::kClampStretch;
  EXPECT_FALSE(build_model(mesh, d).ok());
  d.inversion = InversionHandling::kReport;
  d.element_precision = static_cast<ElementPrecision>(7);
  EXPECT_FALSE(build_model(mesh, d).ok());
  d.element_precision = ElementPrecision::kFloat32;
  const Result<Model> ok = build_model(mesh, d);
  ASSERT_TRUE(ok.ok());
  EXPECT_EQ(ok->cpu_tet_batches_f32.size(), (mesh.tet_count() + 7) / 8 * kCpuTetBatchStrideF32);
  EXPECT_NE(describe_model(*ok).find("float32"), std::string::npos);
}

}  // namespace
}  // namespace zona
