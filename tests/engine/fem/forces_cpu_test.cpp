// CPU force assembly: formulations agree on a mesh, patch test, uniaxial stretch against the
// closed-form SVK answer, rotation, determinism across thread counts, stiffness, frequency, the
// stable neo-Hookean pass.
#include "engine/fem/forces_cpu.h"

#include <gtest/gtest.h>

#include <Eigen/Dense>
#include <Eigen/SparseCholesky>
#include <algorithm>
#include <array>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <string>
#include <vector>

#include "engine/sim/integrator.h"
#include "engine/mesh/mesh_generate.h"
#include "bench/scaling/scaling_bench.h"
#include "tests/engine/physics_test_meshes.h"

namespace zona {
namespace {

using testing::box_mesh;
using testing::vertices_where;

constexpr double kL = 10e-6;  // box edge [m]

Model make_model(const Mesh& mesh, ConstitutiveModel cm, Formulation fm) {
  ModelDesc d;
  d.constitutive = cm;
  d.formulation = fm;
  Result<Model> m = build_model(mesh, d);
  EXPECT_TRUE(m.ok()) << (m.ok() ? "" : m.error().message);
  return std::move(m).value();
}

// A smooth non-affine displacement with strains of order `strain`.
std::vector<Vec3d> wavy_displacement(const Mesh& mesh, double strain) {
  std::vector<Vec3d> u(mesh.vertex_count());
  for (size_t v = 0; v < u.size(); ++v) {
    const Vec3d x = mesh.rest_positions[v] / kL;
    u[v] = strain * kL *
           Vec3d{std::sin(2.0 * x.y + 0.3) * x.x, 0.5 * std::cos(1.5 * x.z) * x.y + 0.2 * x.x * x.x,
                 -0.4 * x.z * x.x + 0.3 * std::sin(x.y)};
  }
  return u;
}

std::vector<Vec3d> forces_of(const Model& model, std::span<const Vec3d> u, int threads = 1,
                             double* energy = nullptr) {
  State s = make_state(model, threads);
  std::copy(u.begin(), u.end(), s.u.begin());
  compute_elastic_forces(model, s);
  if (energy) *energy = s.diag.elastic_energy;
  return s.force;
}

double max_norm(const std::vector<Vec3d>& f) {
  double m = 0;
  for (const Vec3d& v : f) m = std::max(m, norm(v));
  return m;
}

TEST(ForcesCpu, AllFormulationsAgreeOnAMesh) {
  const Mesh mesh = box_mesh({0, 0, 0}, {kL, kL, kL}, 3, 3, 3);
  const std::vector<Vec3d> u = wavy_displacement(mesh, 0.2);
  for (ConstitutiveModel cm : {ConstitutiveModel::kSvk, ConstitutiveModel::kLinear}) {
    double wg, ws, wr;
    const auto fg = forces_of(make_model(mesh, cm, Formulation::kGradient), u, 1, &wg);
    const auto fs = forces_of(make_model(mesh, cm, Formulation::kTensorStored), u, 1, &ws);
    const auto fr = forces_of(make_model(mesh, cm, Formulation::kTensorRebuilt), u, 1, &wr);
    const double scale = max_norm(fg);
    for (size_t v = 0; v < u.size(); ++v) {
      EXPECT_LE(norm(fs[v] - fg[v]), 1e-12 * scale) << "vertex " << v;
      EXPECT_LE(norm(fr[v] - fg[v]), 1e-12 * scale) << "vertex " << v;
    }
    EXPECT_NEAR(ws, wg, 1e-12 * wg);
    EXPECT_NEAR(wr, wg, 1e-12 * wg);
  }
}

TEST(ForcesCpu, AssemblyEqualsTheSumOfElementForces) {
  const Mesh mesh = box_mesh({0, 0, 0}, {kL, kL, kL}, 2, 3, 2);
  const Model model = make_model(mesh, ConstitutiveModel::kSvk, Formulation::kGradient);
  const std::vector<Vec3d> u = wavy_displacement(mesh, 0.3);
  double energy;
  const auto f = forces_of(model, u, 2, &energy);
  std::vector<Vec3d> ref(u.size(), Vec3d{0, 0, 0});
  double ref_energy = 0, scale = 0;
  for (size_t t = 0; t < model.tet_count(); ++t) {
    const Tet& e = model.tets[t];
    const Vec3d ue[4] = {u[e[0]], u[e[1]], u[e[2]], u[e[3]]};
    Vec3d fe[4];
    ref_energy += tet_svk_forces(model.tet_shape[t], model.tet_lame(t).lambda,
                                 model.tet_lame(t).mu, ue, fe);
    for (int c = 0; c < 4; ++c) {
      ref[e[c]] += fe[c];
      scale = std::max(scale, norm(fe[c]));
    }
  }
  // Same terms in the same order (ascending tetrahedron): identical bits where the element pass
  // is the scalar functions' (no FMA), within 1e-13 of the largest corner force where it fuses.
  for (size_t v = 0; v < u.size(); ++v) {
    if (cpu_element_fma())
      EXPECT_LE(norm(f[v] - ref[v]), 1e-13 * scale) << "vertex " << v;
    else
      EXPECT_EQ(norm(f[v] - ref[v]), 0.0) << "vertex " << v;
  }
  EXPECT_NEAR(energy, ref_energy, 1e-14 * ref_energy);
}

TEST(ForcesCpu, ForcesAreBitwiseIdenticalForAnyThreadCount) {
  const Mesh mesh = box_mesh({0, 0, 0}, {kL, kL, kL}, 5, 4, 4);  // 480 tets: several chunks
  const Model model = make_model(mesh, ConstitutiveModel::kSvk, Formulation::kGradient);
  const std::vector<Vec3d> u = wavy_displacement(mesh, 0.25);
  double e1, e2, e3;
  const auto f1 = forces_of(model, u, 1, &e1);
  const auto f2 = forces_of(model, u, 2, &e2);
  const auto f3 = forces_of(model, u, 3, &e3);
  EXPECT_EQ(std::memcmp(f1.data(), f2.data(), f1.size() * sizeof(Vec3d)), 0);
  EXPECT_EQ(std::memcmp(f1.data(), f3.data(), f1.size() * sizeof(Vec3d)), 0);
  EXPECT_EQ(std::memcmp(&e1, &e2, sizeof e1), 0);
  EXPECT_EQ(std::memcmp(&e1, &e3, sizeof e1), 0);
}

// What an assembly plan with these segment boundaries must give, from the scalar element
// forces: per vertex, the owner segment's corners summed from +0 in ascending tetrahedron order,
// then each later segment's corners summed from -0 in that order (one late slot per segment),
// added in segment order. With one segment, or in all-late mode (every corner its own slot),
// this is the plain ordered sum.
std::vector<Vec3d> plan_ordered_forces(const Model& model, std::span<const Vec3d> u,
                                       const std::vector<int64_t>& segment_chunk, bool all_late) {
  const size_t nv = model.vertex_count(), nt = model.tet_count();
  std::vector<std::array<Vec3d, 4>> fe(nt);
  for (size_t t = 0; t < nt; ++t) {
    const Tet& e = model.tets[t];
    const Vec3d ue[4] = {u[e[0]], u[e[1]], u[e[2]], u[e[3]]};
    tet_svk_forces(model.tet_shape[t], model.tet_lame(t).lambda, model.tet_lame(t).mu, ue,
                   fe[t].data());
  }
  const auto segment_of = [&](size_t t) {
    size_t k = 0;
    while (k + 2 < segment_chunk.size() &&
           segment_chunk[k + 1] <= static_cast<int64_t>(t) / kTetChunk)
      ++k;
    return k;
  };
  const Vec3d minus_zero{-0.0, -0.0, -0.0};
  std::vector<Vec3d> out(nv, Vec3d{0, 0, 0});
  const VertexTetAdjacency& adj = model.adjacency;
  for (size_t v = 0; v < nv; ++v) {
    const int32_t begin = adj.offsets[v], end = adj.offsets[v + 1];
    if (begin == end) continue;
    Vec3d total{0, 0, 0};
    const size_t owner = segment_of(static_cast<size_t>(adj.tets[static_cast<size_t>(begin)]));
    size_t open = owner;
    Vec3d partial = minus_zero;
    bool in_owner = !all_late;
    for (int32_t i = begin; i < end; ++i) {
      const size_t t = static_cast<size_t>(adj.tets[static_cast<size_t>(i)]);
      const Vec3d f = fe[t][static_cast<size_t>(adj.corner[static_cast<size_t>(i)])];
      const size_t seg = segment_of(t);
      if (all_late) {
        total += minus_zero + f;
      } else if (in_owner && seg == owner) {
        total += f;
      } else {
        if (in_owner || seg != open) {
          if (!in_owner) total += partial;
          in_owner = false;
          open = seg;
          partial = minus_zero;
        }
        partial += f;
      }
    }
    if (!all_late && !in_owner) total += partial;
    out[v] = total;
  }
  return out;
}

// The assembly plan decides which corners are added into a vertex's block and which into a
// late slot (one per later segment). Whatever the plan, the plain (unfused) element pass gives
// bit for bit what plan_ordered_forces gives from the scalar element functions, for every
// thread count; plans differ from one another only by rounding; the fused pass gives the same
// bits for every thread count of a plan. The late slots are exactly the (vertex, later segment)
// pairs.
TEST(ForcesCpu, ForcesAreBitwiseThePlansPartialSumsForAnyThreadCount) {
  const Mesh mesh = box_mesh({0, 0, 0}, {kL, kL, kL}, 8, 8, 6);  // 2304 tets: 18 chunks
  const Model model = make_model(mesh, ConstitutiveModel::kSvk, Formulation::kGradient);
  const std::vector<Vec3d> u = wavy_displacement(mesh, 0.25);
  const int64_t chunks = static_cast<int64_t>((model.tet_count() + kTetChunk - 1) / kTetChunk);
  const std::vector<int64_t> one_segment = {0, chunks};
  const std::vector<Vec3d> ordered = plan_ordered_forces(model, u, one_segment, false);
  const double scale = max_norm(ordered);
  const bool fused = cpu_element_fma();
  for (int64_t segments : {int64_t{1}, int64_t{2}, int64_t{3}, int64_t{5}, chunks, int64_t{0}}) {
    SCOPED_TRACE(::testing::Message() << segments << " segments");
    std::vector<Vec3d> plain_first, fused_first, ref;
    for (int threads : {1, 2, 3}) {
      SCOPED_TRACE(::testing::Message() << threads << " threads");
      State s = make_state(model, threads);
      make_assembly_plan(model, s, segments == 0 ? 1 : segments, /*all_late=*/segments == 0);
      // Segments cover the chunks in order, none empty.
      const AssemblyPlan& plan = s.assembly;
      const std::vector<int64_t>& bounds = plan.segment_chunk;
      EXPECT_EQ(plan.segment_count(), segments == 0 ? 1 : std::min(segments, chunks));
      EXPECT_EQ(bounds.front(), 0);
      EXPECT_EQ(bounds.back(), chunks);
      for (size_t k = 0; k + 1 < bounds.size(); ++k) EXPECT_LT(bounds[k], bounds[k + 1]);
      // Late slots: none for one segment, one per corner in all-late mode, otherwise one per
      // (vertex, later segment) pair.
      if (segments == 0) {
        EXPECT_EQ(plan.late_count(), static_cast<int64_t>(4 * model.tet_count()));
      } else {
        int64_t pairs = 0;
        for (size_t v = 0; v < model.vertex_count(); ++v) {
          std::vector<int64_t> segs;
          for (int32_t i = model.adjacency.offsets[v]; i < model.adjacency.offsets[v + 1]; ++i) {
            const int64_t chunk = model.adjacency.tets[static_cast<size_t>(i)] / kTetChunk;
            segs.push_back(std::upper_bound(bounds.begin(), bounds.end() - 1, chunk) -
                           bounds.begin() - 1);
          }
          std::sort(segs.begin(), segs.end());
          pairs += std::unique(segs.begin(), segs.end()) - segs.begin() - (segs.empty() ? 0 : 1);
        }
        EXPECT_EQ(plan.late_count(), pairs);
        if (segments == 1) {
          EXPECT_EQ(pairs, 0);
        } else {
          EXPECT_GT(pairs, 0);
        }
      }
      if (ref.empty()) ref = plan_ordered_forces(model, u, bounds, segments == 0);
      std::copy(u.begin(), u.end(), s.u.begin());
      set_cpu_element_fma(false);
      compute_elastic_forces(model, s);
      EXPECT_EQ(std::memcmp(s.force.data(), ref.data(), ref.size() * sizeof(Vec3d)), 0);
      if (plain_first.empty()) plain_first = s.force;
      // Against the plain ordered sum: rounding only.
      for (size_t v = 0; v < u.size(); ++v)
        EXPECT_LE(norm(s.force[v] - ordered[v]), 1e-14 * scale) << "vertex " << v;
      // The fused pass: the same bits for every thread count.
      set_cpu_element_fma(fused);
      compute_elastic_forces(model, s);
      if (fused_first.empty()) fused_first = s.force;
      EXPECT_EQ(std::memcmp(s.force.data(), fused_first.data(), fused_first.size() * sizeof(Vec3d)),
                0);
    }
    // Segments and all-late mode change where partial sums start, so with several segments
    // some vertex must differ from the plain ordered sum in its last bits (else the reference
    // above would not be testing the partial sums).
    if (segments >= 2) {
      EXPECT_NE(std::memcmp(ref.data(), ordered.data(), ref.size() * sizeof(Vec3d)), 0);
    }
  }
  set_cpu_element_fma(fused);
}

// Steps (element pass, then the vertex pass that adds the late slots) give the same state for
// every thread count with a given plan, and states within rounding of each other across plans.
TEST(ForcesCpu, StepsAreBitwiseIdenticalForAnyThreadCountOfAPlan) {
  const Mesh mesh = box_mesh({0, 0, 0}, {kL, kL, kL}, 8, 8, 6);
  ModelDesc d;
  d.fixed_vertices = vertices_where(mesh, 2, 0.0, 1e-12);
  const Model model = build_model(mesh, d).value();
  const std::vector<Vec3d> u = wavy_displacement(mesh, 0.02);
  std::vector<Vec3d> reference;
  for (int64_t segments : {int64_t{1}, int64_t{4}, int64_t{18}, int64_t{0}}) {
    SCOPED_TRACE(::testing::Message() << segments << " segments");
    std::vector<Vec3d> first;
    for (int threads : {1, 2, 3}) {
      State s = make_state(model, threads);
      make_assembly_plan(model, s, segments == 0 ? 1 : segments, segments == 0);
      set_displacement(s, u);
      for (int i = 0; i < 50; ++i) ASSERT_EQ(step(model, s), kStepOk);
      if (first.empty()) first = s.u;
      EXPECT_EQ(std::memcmp(s.u.data(), first.data(), first.size() * sizeof(Vec3d)), 0)
          << threads << " threads";
    }
    if (reference.empty()) reference = first;
    const double scale = max_norm(reference);
    for (size_t v = 0; v < first.size(); ++v)
      EXPECT_LE(norm(first[v] - reference[v]), 1e-12 * scale) << "vertex " << v;
  }
  EXPECT_GT(max_norm(reference), 0);
}

// Sums (a vertex's block and its late slots) that the vertex pass reads on a thread other than
// the one whose element segment wrote them, with the vertex chunks claimed in `order`: a thread's
// home slice (ThreadPool) of the order runs on it, a segment runs on the thread whose slice holds
// it.
int64_t remote_sums(const Model& model, const State& s, const std::vector<int32_t>& order,
                    int64_t threads) {
  const AssemblyPlan& plan = s.assembly;
  const int64_t segments = plan.segment_count();
  const auto slice_of = [&](int64_t i, int64_t count) {
    int64_t t = 0;
    while (t + 1 < threads && count * (t + 1) / threads <= i) ++t;
    return t;
  };
  const auto segment_of = [&](int64_t tet) {
    int64_t seg = 0;
    while (seg + 1 < segments && plan.segment_chunk[static_cast<size_t>(seg) + 1] <= tet / kTetChunk)
      ++seg;
    return seg;
  };
  const int64_t chunks = static_cast<int64_t>(order.size());
  std::vector<int64_t> runner(static_cast<size_t>(chunks));
  for (int64_t i = 0; i < chunks; ++i)
    runner[static_cast<size_t>(order[static_cast<size_t>(i)])] = slice_of(i, chunks);
  int64_t remote = 0;
  const VertexTetAdjacency& adj = model.adjacency;
  for (size_t v = 0; v < model.vertex_count(); ++v) {
    const int64_t here = runner[v / kVertexChunk];
    const int64_t owner = segment_of(adj.tets[static_cast<size_t>(adj.offsets[v])]);
    remote += slice_of(owner, segments) != here;
    int64_t open = owner;  // one late slot per later segment
    for (int32_t i = adj.offsets[v]; i < adj.offsets[v + 1]; ++i) {
      const int64_t seg = segment_of(adj.tets[static_cast<size_t>(i)]);
      if (seg != open) remote += slice_of(seg, segments) != here;
      open = seg;
    }
  }
  return remote;
}

// The vertex pass claims its chunks in AssemblyPlan::vertex_chunk_order: a permutation (every
// chunk once), the identity for one thread, and one that leaves fewer sums to be read across
// cores than chunk order does (on the bench mesh, where two segments leave 195 late slots: at
// two threads 207 sums against 246 in chunk order, too few to pay by default, hence forced).
// Forced on with ZONA_CPU_VERTEX_ORDER=1: by default the plan also asks whether the data fits
// in this machine's L2 cache.
TEST(ForcesCpu, VertexChunkOrderKeepsSumsOnTheThreadThatWroteThem) {
  const Mesh mesh = generate_cell_mesh(table2_spec(1093)).value();
  ModelDesc d;
  d.fixed_vertices = bench_fixed_vertices(mesh);
  const Model model = build_model(mesh, d).value();
  const char* saved = std::getenv("ZONA_CPU_VERTEX_ORDER");
  const std::string restore = saved ? saved : "";
  ::setenv("ZONA_CPU_VERTEX_ORDER", "1", 1);
  std::vector<State> states;
  for (int threads : {1, 2, 3}) states.push_back(make_state(model, threads));
  if (saved)
    ::setenv("ZONA_CPU_VERTEX_ORDER", restore.c_str(), 1);
  else
    ::unsetenv("ZONA_CPU_VERTEX_ORDER");
  for (const State& s : states) {
    const int threads = s.pool->thread_count();
    SCOPED_TRACE(::testing::Message() << threads << " threads");
    const std::vector<int32_t>& order = s.assembly.vertex_chunk_order;
    std::vector<int32_t> identity(s.vertex_chunks.size());
    for (size_t i = 0; i < identity.size(); ++i) identity[i] = static_cast<int32_t>(i);
    std::vector<int32_t> sorted = order;
    std::sort(sorted.begin(), sorted.end());
    ASSERT_EQ(sorted, identity);
    if (threads == 1) {
      EXPECT_EQ(order, identity);
      continue;
    }
    const int64_t ordered = remote_sums(model, s, order, threads);
    const int64_t plain = remote_sums(model, s, identity, threads);
    EXPECT_LT(ordered, plain) << ordered << " against " << plain;
  }
}

// Patch test: an affine displacement u = A x + b gives a uniform strain, so every interior
// vertex is in equilibrium and every element carries the same stress.
TEST(ForcesCpu, PatchTestAffineDisplacement) {
  const Mesh mesh = box_mesh({0, 0, 0}, {kL, kL, kL}, 3, 3, 3);
  const Mat3d a{{{0.08, 0.03, -0.02}, {0.01, -0.05, 0.04}, {0.02, 0.06, 0.1}}};
  const Vec3d b{1e-6, -2e-6, 0.5e-6};
  std::vector<Vec3d> u(mesh.vertex_count());
  for (size_t v = 0; v < u.size(); ++v) u[v] = a * mesh.rest_positions[v] + b;
  auto interior = [&](size_t v) {
    const Vec3d x = mesh.rest_positions[v];
    for (int i = 0; i < 3; ++i)
      if (x[i] < 1e-3 * kL || x[i] > (1 - 1e-3) * kL) return false;
    return true;
  };
  for (ConstitutiveModel cm :
       {ConstitutiveModel::kSvk, ConstitutiveModel::kLinear, ConstitutiveModel::kStableNeoHookean})
    for (Formulation fm :
         {Formulation::kGradient, Formulation::kTensorStored, Formulation::kTensorRebuilt}) {
      if (cm == ConstitutiveModel::kStableNeoHookean && fm != Formulation::kGradient) continue;
      const Model model = make_model(mesh, cm, fm);
      const auto f = forces_of(model, u);
      const double scale = max_norm(f);
      int interior_count = 0;
      for (size_t v = 0; v < u.size(); ++v)
        if (interior(v)) {
          ++interior_count;
          EXPECT_LE(norm(f[v]), 1e-11 * scale) << "interior vertex " << v;
        }
      EXPECT_EQ(interior_count, 8);
      // Uniform stress: every element's displacement gradient is A.
      for (size_t t = 0; t < model.tet_count(); ++t) {
        const Tet& e = model.tets[t];
        const Vec3d ue[4] = {u[e[0]], u[e[1]], u[e[2]], u[e[3]]};
        const Mat3d h = tet_displacement_gradient(model.tet_shape[t], ue);
        for (int r = 0; r < 3; ++r)
          for (int c = 0; c < 3; ++c) EXPECT_NEAR(h.m[r][c], a.m[r][c], 1e-13);
      }
    }
}

// Uniaxial stretch: F = diag(s, q, q) with the lateral stretch q making S22 = S33 = 0.
// Closed form for SVK: E22 = -nu E11, S11 = E_young E11, P11 = s S11; the x = L face carries
// the total force P11 * A and the lateral faces none.
TEST(ForcesCpu, UniaxialStretchMatchesClosedFormSvk) {
  const Mesh mesh = box_mesh({0, 0, 0}, {kL, kL, kL}, 3, 3, 3);
  const Model model = make_model(mesh, ConstitutiveModel::kSvk, Formulation::kGradient);
  const Material mat = model.materials[0];
  for (double s : {1.3, 0.8}) {
    const double e11 = 0.5 * (s * s - 1);
    const double q = std::sqrt(1 + 2 * (-mat.poisson * e11));
    std::vector<Vec3d> u(mesh.vertex_count());
    for (size_t v = 0; v < u.size(); ++v) {
      const Vec3d x = mesh.rest_positions[v];
      u[v] = Vec3d{(s - 1) * x.x, (q - 1) * x.y, (q - 1) * x.z};
    }
    double energy;
    const auto f = forces_of(model, u, 1, &energy);
    const double p11 = s * mat.young * e11;
    Vec3d right{0, 0, 0}, top{0, 0, 0};
    for (int32_t v : vertices_where(mesh, 0, kL, 1e-9 * kL)) right += f[v];
    for (int32_t v : vertices_where(mesh, 1, kL, 1e-9 * kL))
      if (mesh.rest_positions[v].x > 1e-9 * kL && mesh.rest_positions[v].x < kL * (1 - 1e-9))
        top += f[v];
    // The internal force on the loaded face balances the applied traction: -P11 A.
    EXPECT_NEAR(right.x, -p11 * kL * kL, 1e-10 * std::abs(p11) * kL * kL) << "stretch " << s;
    EXPECT_NEAR(right.y, 0.0, 1e-10 * std::abs(p11) * kL * kL);
    EXPECT_LE(norm(top), 1e-10 * std::abs(p11) * kL * kL);
    // W = V (E_young / 2) E11^2 for uniaxial stress.
    EXPECT_NEAR(energy, kL * kL * kL * 0.5 * mat.young * e11 * e11, 1e-10 * energy);
  }
}

TEST(ForcesCpu, RigidRotationOfAMesh) {
  const Mesh mesh = box_mesh({0, 0, 0}, {kL, kL, kL}, 2, 2, 2);
  const double c = std::cos(0.7), s = std::sin(0.7);
  const Mat3d r{{{c, -s, 0}, {s, c, 0}, {0, 0, 1}}};
  std::vector<Vec3d> u(mesh.vertex_count()), stretch(mesh.vertex_count());
  for (size_t v = 0; v < u.size(); ++v) {
    u[v] = r * mesh.rest_positions[v] - mesh.rest_positions[v];
    stretch[v] = Vec3d{0.1 * mesh.rest_positions[v].x, 0, 0};
  }
  const double scale =
      max_norm(forces_of(make_model(mesh, ConstitutiveModel::kSvk, Formulation::kGradient),
                         stretch));
  EXPECT_LE(max_norm(forces_of(make_model(mesh, ConstitutiveModel::kSvk, Formulation::kGradient),
                               u)),
            1e-10 * scale);
  EXPECT_LE(max_norm(forces_of(
                make_model(mesh, ConstitutiveModel::kStableNeoHookean, Formulation::kGradient), u)),
            1e-10 * scale);
  // The linear model sees a strain of 1 - cos(0.7) = 24 % and pushes back hard.
  EXPECT_GT(max_norm(forces_of(
                make_model(mesh, ConstitutiveModel::kLinear, Formulation::kGradient), u)),
            scale);
}

TEST(ForcesCpu, AssembledStiffnessMatchesForceDifferences) {
  for (ConstitutiveModel cm : {ConstitutiveModel::kSvk, ConstitutiveModel::kStableNeoHookean}) {
    SCOPED_TRACE(cm == ConstitutiveModel::kSvk ? "svk" : "neohookean");
    const Mesh mesh = box_mesh({0, 0, 0}, {kL, kL, kL}, 2, 2, 1);
    const Model model = make_model(mesh, cm, Formulation::kGradient);
    const std::vector<Vec3d> u = wavy_displacement(mesh, 0.2);
    const Eigen::SparseMatrix<double> k = assemble_stiffness(model, u);
    // Direction of the derivative.
    std::vector<Vec3d> d = wavy_displacement(mesh, 1.0);
    for (Vec3d& x : d) x = Vec3d{x.y, -x.z, x.x};
    const double h = 1e-6 * kL;
    std::vector<Vec3d> up(u), um(u);
    for (size_t v = 0; v < u.size(); ++v) {
      up[v] += (h / kL) * d[v];
      um[v] -= (h / kL) * d[v];
    }
    const auto fp = forces_of(model, up), fm = forces_of(model, um);
    Eigen::VectorXd dv(3 * u.size());
    for (size_t v = 0; v < u.size(); ++v)
      for (int i = 0; i < 3; ++i) dv[static_cast<Eigen::Index>(3 * v + i)] = d[v][i] / kL;
    const Eigen::VectorXd kd = k * dv;
    double scale = kd.cwiseAbs().maxCoeff();
    for (size_t v = 0; v < u.size(); ++v)
      for (int i = 0; i < 3; ++i) {
        const double fd = -(fp[v][i] - fm[v][i]) / (2 * h);
        EXPECT_NEAR(kd[static_cast<Eigen::Index>(3 * v + i)], fd, 1e-6 * scale);
      }
    // Symmetric.
    const Eigen::SparseMatrix<double> kt = k.transpose();
    EXPECT_LE((k - kt).norm(), 1e-12 * k.norm());
  }
}

TEST(ForcesCpu, NeoHookeanPassIsItsElementFunctionAndReportsInversion) {
  const Mesh mesh = box_mesh({0, 0, 0}, {kL, kL, kL}, 5, 4, 4);  // 480 tets: several chunks
  const Model model =
      make_model(mesh, ConstitutiveModel::kStableNeoHookean, Formulation::kGradient);
  std::vector<Vec3d> u = wavy_displacement(mesh, 0.3);
  // An interior vertex pushed through its neighbours: some elements inverted.
  size_t centre = 0;
  for (size_t v = 0; v < u.size(); ++v)
    if (norm(mesh.rest_positions[v] - Vec3d{0.4, 0.5, 0.5} * kL) <
        norm(mesh.rest_positions[centre] - Vec3d{0.4, 0.5, 0.5} * kL))
      centre = v;
  u[centre] += Vec3d{0, 0, -0.6 * kL};
  std::vector<Vec3d> ref(u.size(), Vec3d{0, 0, 0});
  double ref_energy = 0, scale = 0;
  int64_t inverted = 0;
  for (size_t t = 0; t < model.tet_count(); ++t) {
    const Tet& e = model.tets[t];
    const Vec3d ue[4] = {u[e[0]], u[e[1]], u[e[2]], u[e[3]]};
    Vec3d fe[4];
    uint32_t bits = 0;
    ref_energy += tet_snh_forces(model.tet_shape[t], model.tet_lame(t).lambda, model.tet_lame(t).mu,
                                 ue, fe, &bits);
    inverted += bits & kElementInverted ? 1 : 0;
    for (int c = 0; c < 4; ++c) {
      ref[e[c]] += fe[c];
      scale = std::max(scale, norm(fe[c]));
    }
  }
  ASSERT_GT(inverted, 0);
  State s1 = make_state(model, 1), s3 = make_state(model, 3);
  for (State* s : {&s1, &s3}) {
    std::copy(u.begin(), u.end(), s->u.begin());
    compute_elastic_forces(model, *s);
  }
  // The scalar pass sums the same corner forces in ascending tetrahedron order.
  for (size_t v = 0; v < u.size(); ++v)
    EXPECT_LE(norm(s1.force[v] - ref[v]), 1e-13 * scale) << "vertex " << v;
  EXPECT_NEAR(s1.diag.elastic_energy, ref_energy, 1e-13 * ref_energy);
  // Inversion is reported (not a failure for this law), and no result depends on threads.
  EXPECT_EQ(s1.diag.inverted_count, inverted);
  EXPECT_TRUE(s1.diag.element_health & kElementInverted);
  EXPECT_FALSE(s1.diag.element_health & (kElementCollapsing | kElementClamped));
  EXPECT_EQ(std::memcmp(s1.force.data(), s3.force.data(), u.size() * sizeof(Vec3d)), 0);
  EXPECT_EQ(s1.diag.elastic_energy, s3.diag.elastic_energy);
  EXPECT_EQ(s1.diag.first_inverted, s3.diag.first_inverted);
}

TEST(ForcesCpu, MaxFrequencyMatchesADenseEigensolver) {
  const Mesh mesh = box_mesh({0, 0, 0}, {kL, kL, kL}, 2, 1, 1);
  ModelDesc desc;
  desc.fixed_vertices = {0, 3};
  const Model model = build_model(mesh, desc).value();
  const std::vector<Vec3d> rest(model.vertex_count(), Vec3d{0, 0, 0});
  const Eigen::MatrixXd k = Eigen::MatrixXd(assemble_stiffness(model, rest));
  // Linear stiffness at rest, free DOFs only, mass-normalised.
  std::vector<int> free;
  for (size_t v = 0; v < model.vertex_count(); ++v)
    if (!model.vertex_fixed[v])
      for (int i = 0; i < 3; ++i) free.push_back(static_cast<int>(3 * v + i));
  const Eigen::Index n = static_cast<Eigen::Index>(free.size());
  Eigen::MatrixXd a(n, n);
  for (Eigen::Index r = 0; r < n; ++r)
    for (Eigen::Index c = 0; c < n; ++c)
      a(r, c) = k(free[r], free[c]) / std::sqrt(model.vertex_mass[free[r] / 3] *
                                                model.vertex_mass[free[c] / 3]);
  Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> eig(a);
  const double exact = std::sqrt(eig.eigenvalues().maxCoeff());
  EXPECT_NEAR(estimate_max_frequency(model, 2000), exact, 1e-6 * exact);
}

// Static indentation of a block (bottom fixed, the central quarter of the top pushed down by
// `depth`), solved with the linear stiffness: the force on the patch [N].
double linear_indentation_force(int n, double depth, double poisson = 0.49) {
  const Mesh mesh = box_mesh({0, 0, 0}, {kL, kL, 0.5 * kL}, n, n, n / 2);
  ModelDesc d;
  d.constitutive = ConstitutiveModel::kLinear;
  d.material.poisson = poisson;
  for (int32_t v : vertices_where(mesh, 2, 0.0, 1e-9 * kL)) d.fixed_vertices.push_back(v);
  const Model model = build_model(mesh, d).value();
  std::vector<int> kind(mesh.vertex_count(), 0);  // 0 free, 1 fixed, 2 patch
  for (int32_t v : d.fixed_vertices) kind[v] = 1;
  for (int32_t v : vertices_where(mesh, 2, 0.5 * kL, 1e-9 * kL)) {
    const Vec3d x = mesh.rest_positions[v];
    if (x.x > 0.25 * kL - 1e-9 * kL && x.x < 0.75 * kL + 1e-9 * kL && x.y > 0.25 * kL - 1e-9 * kL &&
        x.y < 0.75 * kL + 1e-9 * kL)
      kind[v] = 2;
  }
  const std::vector<Vec3d> zero(mesh.vertex_count(), Vec3d{0, 0, 0});
  const Eigen::SparseMatrix<double> k = assemble_stiffness(model, zero);
  // Unknowns: the free vertices' DOFs; the patch's are known (0, 0, -depth).
  std::vector<Eigen::Index> index(3 * mesh.vertex_count(), -1);
  Eigen::Index nf = 0;
  for (size_t v = 0; v < mesh.vertex_count(); ++v)
    if (kind[v] == 0)
      for (int i = 0; i < 3; ++i) index[3 * v + i] = nf++;
  Eigen::VectorXd known = Eigen::VectorXd::Zero(k.rows());
  for (size_t v = 0; v < mesh.vertex_count(); ++v)
    if (kind[v] == 2) known[static_cast<Eigen::Index>(3 * v + 2)] = -depth;
  const Eigen::VectorXd rhs_full = -(k * known);
  std::vector<Eigen::Triplet<double>> trip;
  Eigen::VectorXd rhs(nf);
  for (Eigen::Index c = 0; c < k.outerSize(); ++c)
    for (Eigen::SparseMatrix<double>::InnerIterator it(k, c); it; ++it)
      if (index[it.row()] >= 0 && index[it.col()] >= 0)
        trip.emplace_back(index[it.row()], index[it.col()], it.value());
  for (Eigen::Index r = 0; r < k.rows(); ++r)
    if (index[r] >= 0) rhs[index[r]] = rhs_full[r];
  Eigen::SparseMatrix<double> kff(nf, nf);
  kff.setFromTriplets(trip.begin(), trip.end());
  Eigen::SimplicialLDLT<Eigen::SparseMatrix<double>> solver(kff);
  EXPECT_EQ(solver.info(), Eigen::Success);
  const Eigen::VectorXd uf = solver.solve(rhs);
  Eigen::VectorXd u = known;
  for (Eigen::Index r = 0; r < k.rows(); ++r)
    if (index[r] >= 0) u[r] = uf[index[r]];
  const Eigen::VectorXd f = k * u;  // force needed at each DOF to hold u
  double fz = 0;
  for (size_t v = 0; v < mesh.vertex_count(); ++v)
    if (kind[v] == 2) fz += f[static_cast<Eigen::Index>(3 * v + 2)];
  return fz;
}

TEST(ForcesCpu, StaticIndentationConvergesUnderMeshRefinement) {
  const double depth = 0.01 * kL;
  std::string report;
  for (double nu : {0.3, 0.49}) {
    const double f4 = linear_indentation_force(4, depth, nu);
    const double f8 = linear_indentation_force(8, depth, nu);
    const double f12 = linear_indentation_force(12, depth, nu);
    char text[200];
    std::snprintf(text, sizeof text, "nu %.2f: n=4 %.5g N, n=8 %.5g N, n=12 %.5g N; ", nu, f4, f8,
                  f12);
    report += text;
    // Pushing down takes a downward force; coarse meshes are too stiff, so the force falls
    // monotonically with refinement and the changes shrink.
    EXPECT_LT(f4, 0);
    EXPECT_GT(f8, f4);
    EXPECT_GT(f12, f8);
    EXPECT_LT(std::abs(f12 - f8), std::abs(f8 - f4));
    // At nu = 0.3, n = 8 is within 15 % of n = 12. At nu = 0.49 linear tetrahedra lock
    // (near-incompressibility) and converge much more slowly (docs/physics.md).
    if (nu == 0.3) {
      EXPECT_LT(std::abs(f8 - f12), 0.15 * std::abs(f12));
    }
  }
  RecordProperty("indentation_force", report);
}

TEST(ForcesCpu, RelaxedSvkIndentationEqualsTheLinearSolveForSmallDepth) {
  // Dynamic relaxation of the SVK model against the direct linear solve, at 0.1 % strain.
  const int n = 4;
  const double depth = 1e-4 * kL;
  const double linear = linear_indentation_force(n, depth);
  const Mesh mesh = box_mesh({0, 0, 0}, {kL, kL, 0.5 * kL}, n, n, n / 2);
  ModelDesc d;
  d.fixed_vertices = vertices_where(mesh, 2, 0.0, 1e-9 * kL);
  const Model model = build_model(mesh, d).value();
  State s = make_state(model, 1);
  std::vector<int32_t> patch;
  for (int32_t v : vertices_where(mesh, 2, 0.5 * kL, 1e-9 * kL)) {
    const Vec3d x = mesh.rest_positions[v];
    if (x.x > 0.24 * kL && x.x < 0.76 * kL && x.y > 0.24 * kL && x.y < 0.76 * kL)
      patch.push_back(v);
  }
  ASSERT_TRUE(set_prescribed_vertices(model, s, patch).ok());
  for (Vec3d& t : s.prescribed_displacement) t = Vec3d{0, 0, -depth};
  RelaxOptions o;
  o.relative_tolerance = 1e-10;
  ASSERT_TRUE(relax_to_equilibrium(model, s, o).converged);
  // Constraint force = force applied to hold the patch = the linear solve's K u on the patch.
  EXPECT_NEAR(s.diag.constraint_force.z, linear, 2e-3 * std::abs(linear));
}

}  // namespace
}  // namespace zona
