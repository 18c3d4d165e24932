// Tests for kernels/device_layout (host code, runs everywhere): renumbering, packing, units,
// material ranges, gather lists and coefficients of the CUDA backend's layout.
#include "kernels/device_layout.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <numeric>
#include <random>

#include "engine/mesh/mesh_generate.h"

namespace zona {
namespace {

// A box whose vertex numbers are shuffled: the layout's reordering has something to repair.
Mesh shuffled_box(int n) {
  Mesh mesh = generate_box_mesh(Vec3d{0, 0, 0}, Vec3d{8e-6, 6e-6, 5e-6}, n, n, n);
  std::vector<int32_t> perm(mesh.vertex_count());
  std::iota(perm.begin(), perm.end(), 0);
  std::mt19937 rng(7);
  std::shuffle(perm.begin(), perm.end(), rng);
  std::vector<Vec3d> pos(mesh.vertex_count());
  for (size_t v = 0; v < pos.size(); ++v) pos[perm[v]] = mesh.rest_positions[v];
  mesh.rest_positions = pos;
  for (Tet& t : mesh.tets)
    for (int32_t& v : t) v = perm[v];
  // Two regions so that two materials are packed.
  for (size_t t = 0; t < mesh.tet_count(); ++t) mesh.tet_region[t] = t % 3 == 0 ? 2 : 1;
  return mesh;
}

Model model_of(const Mesh& mesh) {
  ModelDesc desc;
  desc.material.young = 2e3;
  RegionMaterial zona;
  zona.region = 2;
  zona.material.young = 17.9e3;
  desc.region_materials.push_back(zona);
  desc.fixed_vertices = {0, 5};
  Result<Model> model = build_model(mesh, desc);
  EXPECT_TRUE(model.ok()) << (model ? "" : model.error().message);
  return std::move(model).value();
}

// Median |i - j| over the edges of the tetrahedra: small means neighbours sit close in memory
// (the median, not the mean: a space-filling curve keeps most edges short and a few long).
double median_index_span(const DeviceLayout& l) {
  std::vector<int32_t> span;
  for (const auto& t : l.tet_vertices)
    for (int a = 0; a < 4; ++a)
      for (int b = a + 1; b < 4; ++b) span.push_back(std::abs(t[a] - t[b]));
  std::nth_element(span.begin(), span.begin() + span.size() / 2, span.end());
  return span[span.size() / 2];
}

TEST(DeviceLayout, RenumberingIsAPermutationAndKeepsTheElements) {
  const Model model = model_of(shuffled_box(6));
  Result<DeviceLayout> l = build_device_layout(model, DeviceLayoutOptions{});
  ASSERT_TRUE(l.ok()) << l.error().message;
  ASSERT_EQ(l->vertex_count(), model.vertex_count());
  ASSERT_EQ(l->tet_count(), model.tet_count());
  for (size_t i = 0; i < l->vertex_count(); ++i)
    EXPECT_EQ(l->vertex_old_to_new[l->vertex_new_to_old[i]], static_cast<int32_t>(i));
  std::vector<int32_t> seen(model.tet_count(), 0);
  for (size_t i = 0; i < l->tet_count(); ++i) {
    const int32_t t = l->tet_new_to_old[i];
    ++seen[t];
    // The same corners, in ascending device order.
    std::array<int32_t, 4> a, b = model.tets[t];
    for (int c = 0; c < 4; ++c) a[c] = l->vertex_new_to_old[l->tet_vertices[i][c]];
    std::sort(a.begin(), a.end());
    std::sort(b.begin(), b.end());
    EXPECT_EQ(a, b);
    EXPECT_TRUE(std::is_sorted(l->tet_vertices[i].begin(), l->tet_vertices[i].end()));
  }
  for (int32_t s : seen) EXPECT_EQ(s, 1);
}

TEST(DeviceLayout, IsTheSameForAnyThreadCount) {
  // 35,937 vertices and 196,608 tetrahedra: several ranges of every parallel part.
  const Model model = model_of(shuffled_box(32));
  Result<DeviceLayout> one = build_device_layout(model, DeviceLayoutOptions{true, 1});
  Result<DeviceLayout> four = build_device_layout(model, DeviceLayoutOptions{true, 4});
  ASSERT_TRUE(one.ok() && four.ok());
  EXPECT_EQ(one->vertex_new_to_old, four->vertex_new_to_old);
  EXPECT_EQ(one->tet_new_to_old, four->tet_new_to_old);
  EXPECT_EQ(one->tet_vertices, four->tet_vertices);
  ASSERT_EQ(one->tet_shape_a.size(), four->tet_shape_a.size());
  EXPECT_EQ(std::memcmp(one->tet_shape_a.data(), four->tet_shape_a.data(),
                        one->tet_shape_a.size() * sizeof(one->tet_shape_a[0])),
            0);
  EXPECT_EQ(std::memcmp(one->tet_shape_c.data(), four->tet_shape_c.data(),
                        one->tet_shape_c.size() * sizeof(one->tet_shape_c[0])),
            0);
  EXPECT_EQ(one->gather_entries, four->gather_entries);
}

TEST(DeviceLayout, MortonOrderBringsNeighboursTogether) {
  const Model model = model_of(shuffled_box(8));
  Result<DeviceLayout> plain = build_device_layout(model, DeviceLayoutOptions{false});
  Result<DeviceLayout> sorted = build_device_layout(model, DeviceLayoutOptions{true});
  ASSERT_TRUE(plain.ok() && sorted.ok());
  EXPECT_LT(median_index_span(*sorted), 0.1 * median_index_span(*plain));
  // Tetrahedra follow their first (smallest) vertex, then their second, within each material.
  for (size_t k = 0; k + 1 < sorted->material_tet_begin.size(); ++k)
    for (int32_t i = sorted->material_tet_begin[k] + 1; i < sorted->material_tet_begin[k + 1];
         ++i) {
      const auto& a = sorted->tet_vertices[i - 1];
      const auto& b = sorted->tet_vertices[i];
      EXPECT_TRUE(a[0] < b[0] || (a[0] == b[0] && a[1] <= b[1]));
    }
}

TEST(DeviceLayout, PackedShapesAndMaterialsInScaledUnits) {
  const Model model = model_of(shuffled_box(4));
  Result<DeviceLayout> l = build_device_layout(model, DeviceLayoutOptions{});
  ASSERT_TRUE(l.ok());
  // Units are powers of two near the element size and the largest shear modulus.
  EXPECT_EQ(std::exp2(std::round(std::log2(l->length_unit))), l->length_unit);
  EXPECT_EQ(std::exp2(std::round(std::log2(l->stress_unit))), l->stress_unit);
  EXPECT_GT(l->length_unit, 0.2e-6);
  EXPECT_LT(l->length_unit, 5e-6);
  EXPECT_EQ(l->force_unit, l->stress_unit * l->length_unit * l->length_unit);
  // Material ranges cover the tetrahedra, each range holds its material's elements.
  ASSERT_EQ(l->material_count(), 2u);
  EXPECT_EQ(l->material_tet_begin.front(), 0);
  EXPECT_EQ(l->material_tet_begin.back(), static_cast<int32_t>(model.tet_count()));
  for (size_t k = 0; k < 2; ++k) {
    EXPECT_FLOAT_EQ(l->material_lame[k][1],
                    static_cast<float>(model.material_lame[k].mu / l->stress_unit));
    for (int32_t i = l->material_tet_begin[k]; i < l->material_tet_begin[k + 1]; ++i) {
      EXPECT_EQ(model.tet_material[l->tet_new_to_old[i]], static_cast<int32_t>(k));
    }
  }
  // Shapes: float32 of grad * length_unit (of the model corner each device corner came from)
  // and V / length_unit^3.
  for (size_t i = 0; i < l->tet_count(); ++i) {
    const int32_t t = l->tet_new_to_old[i];
    const TetShape<double>& s = model.tet_shape[t];
    const double lu = l->length_unit;
    auto model_corner = [&](int c) {
      const int32_t v = l->vertex_new_to_old[l->tet_vertices[i][c]];
      return static_cast<int>(std::find(model.tets[t].begin(), model.tets[t].end(), v) -
                              model.tets[t].begin());
    };
    const Vec3d g1 = s.grad[model_corner(1)], g3 = s.grad[model_corner(3)];
    EXPECT_NEAR(l->tet_shape_a[i][0], g1.x * lu, 1e-6 * std::abs(g1.x * lu) + 1e-7);
    EXPECT_NEAR(l->tet_shape_b[i][3], g3.y * lu, 1e-6 * std::abs(g3.y * lu) + 1e-7);
    EXPECT_NEAR(l->tet_shape_c[i][1], s.volume / (lu * lu * lu), 1e-6 * s.volume / (lu * lu * lu));
  }
}

TEST(DeviceLayout, GatherListsAreCompleteAndAscending) {
  const Model model = model_of(shuffled_box(4));
  Result<DeviceLayout> l = build_device_layout(model, DeviceLayoutOptions{});
  ASSERT_TRUE(l.ok());
  ASSERT_EQ(l->gather_offsets.back(), static_cast<int32_t>(4 * l->tet_count()));
  for (size_t v = 0; v < l->vertex_count(); ++v) {
    const int32_t b = l->gather_offsets[v], e = l->gather_offsets[v + 1];
    EXPECT_EQ(e - b, model.adjacency.offsets[l->vertex_new_to_old[v] + 1] -
                         model.adjacency.offsets[l->vertex_new_to_old[v]]);
    for (int32_t i = b; i < e; ++i) {
      const int32_t t = l->gather_entries[i] >> 2, c = l->gather_entries[i] & 3;
      EXPECT_EQ(l->tet_vertices[t][c], static_cast<int32_t>(v));
      if (i > b) {
        EXPECT_LT(l->gather_entries[i - 1] >> 2, t);
      }
    }
  }
}

TEST(DeviceLayout, VertexCoefficientsMarkFixedVertices) {
  const Model model = model_of(shuffled_box(3));
  Result<DeviceLayout> l = build_device_layout(model, DeviceLayoutOptions{});
  ASSERT_TRUE(l.ok());
  for (size_t i = 0; i < l->vertex_count(); ++i) {
    const int32_t v = l->vertex_new_to_old[i];
    if (model.vertex_fixed[v]) {
      EXPECT_EQ(l->vertex_update[i].c, kFixedMarker);
    } else {
      const VertexCoefficients& k = model.vertex_coefficients[v];
      EXPECT_FLOAT_EQ(l->vertex_update[i].b, static_cast<float>(k.b));
      EXPECT_NEAR(l->vertex_update[i].c, k.c * l->force_unit / l->length_unit,
                  1e-6 * k.c * l->force_unit / l->length_unit);
      EXPECT_GT(l->vertex_update[i].c, 0.0f);
      EXPECT_DOUBLE_EQ(k.a, 1.0 + k.b);  // the rewrite u + b (u - u-) relies on a = 1 + b
    }
    EXPECT_EQ(l->vertex_mass[i], model.vertex_mass[v]);
  }
}

TEST(DeviceLayout, MortonCodeInterleavesAxes) {
  const Vec3d lo{0, 0, 0}, hi{1, 1, 1};
  EXPECT_EQ(morton_code(lo, lo, hi), 0u);
  EXPECT_EQ(morton_code(Vec3d{1, 0, 0}, lo, hi), 0x1249249249249249ull);
  EXPECT_EQ(morton_code(Vec3d{0, 1, 0}, lo, hi), 0x1249249249249249ull << 1);
  EXPECT_EQ(morton_code(Vec3d{0, 0, 1}, lo, hi), 0x1249249249249249ull << 2);
  EXPECT_EQ(nearest_power_of_two(3e-6), std::exp2(-18.0));
}

}  // namespace
}  // namespace zona
