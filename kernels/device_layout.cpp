// Builds the CUDA backend's packed, renumbered layout from a Model (host code, no CUDA).
#include "kernels/device_layout.h"

#include <algorithm>
#include <cmath>
#include <functional>
#include <numeric>

#include "engine/core/parallel.h"

namespace zona {
namespace {

// Spreads the low 21 bits of x so that two zero bits separate consecutive bits.
uint64_t spread_bits_3(uint64_t x) {
  x &= 0x1fffffull;
  x = (x | x << 32) & 0x1f00000000ffffull;
  x = (x | x << 16) & 0x1f0000ff0000ffull;
  x = (x | x << 8) & 0x100f00f00f00f00full;
  x = (x | x << 4) & 0x10c30c30c30c30c3ull;
  x = (x | x << 2) & 0x1249249249249249ull;
  return x;
}

}  // namespace

uint64_t morton_code(Vec3d p, Vec3d lo, Vec3d hi) {
  constexpr double kMax = static_cast<double>((1u << 21) - 1);
  uint64_t q[3];
  for (int i = 0; i < 3; ++i) {
    const double extent = hi[i] - lo[i];
    double s = extent > 0 ? (p[i] - lo[i]) / extent : 0.0;
    s = std::clamp(s, 0.0, 1.0);
    q[i] = static_cast<uint64_t>(s * kMax);
  }
  return spread_bits_3(q[0]) | spread_bits_3(q[1]) << 1 | spread_bits_3(q[2]) << 2;
}

double nearest_power_of_two(double x) {
  if (!(x > 0) || !std::isfinite(x)) return 1.0;
  return std::exp2(std::round(std::log2(x)));
}

Result<DeviceLayout> build_device_layout(const Model& model, const DeviceLayoutOptions& options) {
  const int threads = setup_thread_count(options.threads);
  const size_t nv = model.vertex_count();
  const size_t nt = model.tet_count();
  if (nv == 0 || nt == 0) return make_error("cuda layout: the model has no tetrahedra");
  if (model.material_lame.size() > static_cast<size_t>(kMaxDeviceMaterials))
    return make_error("cuda layout: %zu materials, the kernels take at most %d",
                      model.material_lame.size(), kMaxDeviceMaterials);
  if (nt >= (size_t{1} << 29) || nv >= (size_t{1} << 28))
    return make_error(
        "cuda layout: %zu vertices / %zu tetrahedra exceed the packed index range "
        "(2^28 / 2^29)",
        nv, nt);
  if (model.tet_shape.size() != nt || model.vertex_coefficients.size() != nv ||
      model.vertex_mass.size() != nv || model.tet_material.size() != nt)
    return make_error(
        "cuda layout: the model's arrays do not match its mesh (not built by "
        "build_model?)");

  DeviceLayout out;

  // Units: powers of two, so that scaling is exact and only moves exponents.
  double volume_sum = 0;
  for (const TetShape<double>& s : model.tet_shape) volume_sum += s.volume;
  out.length_unit = nearest_power_of_two(std::cbrt(volume_sum / static_cast<double>(nt)));
  double mu_max = 0;
  for (const Lame& l : model.material_lame) mu_max = std::max(mu_max, l.mu);
  out.stress_unit = nearest_power_of_two(mu_max);
  out.force_unit = out.stress_unit * out.length_unit * out.length_unit;

  // Vertex order: Morton code of the rest position, ties by model index (deterministic).
  out.vertex_new_to_old.resize(nv);
  std::iota(out.vertex_new_to_old.begin(), out.vertex_new_to_old.end(), 0);
  if (options.reorder) {
    Vec3d lo = model.rest_positions[0], hi = lo;
    for (const Vec3d& p : model.rest_positions)
      for (int i = 0; i < 3; ++i) {
        lo[i] = std::min(lo[i], p[i]);
        hi[i] = std::max(hi[i], p[i]);
      }
    std::vector<uint64_t> code(nv);
    parallel_ranges(nv, threads, 16384, [&](size_t, size_t begin, size_t end) {
      for (size_t v = begin; v < end; ++v) code[v] = morton_code(model.rest_positions[v], lo, hi);
    });
    parallel_sort(out.vertex_new_to_old.begin(), out.vertex_new_to_old.end(), threads, 16384,
                  [&](int32_t a, int32_t b) {
                    return code[a] != code[b] ? code[a] < code[b] : a < b;
                  });
  }
  out.vertex_old_to_new.resize(nv);
  for (size_t i = 0; i < nv; ++i) out.vertex_old_to_new[out.vertex_new_to_old[i]] = int32_t(i);

  // Corner order: ascending device vertex (the shape gradients are permuted alike; the
  // element's forces do not depend on the order of its corners). Tetrahedron order: by material
  // (the kernels find a tet's material from these ranges), then by first and second vertex
  // when reordering, else by model index. Neighbouring threads then often share their corner 0
  // and 1 vertex, which the warp aggregation of the atomics exploits. One 64-bit key each:
  // material (3 bits) | first vertex (28 bits) | second vertex (31 bits); ties by model index.
  std::vector<std::array<int32_t, 4>> corner_order(nt);  // model corner of each device corner
  std::vector<std::pair<uint64_t, int32_t>> key(nt);
  parallel_ranges(nt, threads, 16384, [&](size_t, size_t begin, size_t end) {
    for (size_t t = begin; t < end; ++t) {
      std::array<int32_t, 4>& order = corner_order[t];
      order = {0, 1, 2, 3};
      if (options.reorder)
        std::sort(order.begin(), order.end(), [&](int32_t a, int32_t b) {
          return out.vertex_old_to_new[model.tets[t][a]] < out.vertex_old_to_new[model.tets[t][b]];
        });
      const uint64_t v0 = options.reorder ? out.vertex_old_to_new[model.tets[t][order[0]]] : 0;
      const uint64_t v1 = options.reorder ? out.vertex_old_to_new[model.tets[t][order[1]]] : 0;
      key[t] = {static_cast<uint64_t>(model.tet_material[t]) << 59 | v0 << 31 | v1,
                static_cast<int32_t>(t)};
    }
  });
  // The model index in each key: no two keys are equal.
  parallel_sort(key.begin(), key.end(), threads, 16384, std::less<>());
  out.tet_new_to_old.resize(nt);
  for (size_t i = 0; i < nt; ++i) out.tet_new_to_old[i] = key[i].second;

  // Materials: ranges over the sorted tetrahedra and scaled Lame coefficients.
  const size_t nm = model.material_lame.size();
  out.material_tet_begin.assign(nm + 1, 0);
  for (size_t t = 0; t < nt; ++t) ++out.material_tet_begin[model.tet_material[t] + 1];
  for (size_t k = 0; k < nm; ++k) out.material_tet_begin[k + 1] += out.material_tet_begin[k];
  for (const Lame& l : model.material_lame)
    out.material_lame.push_back({static_cast<float>(l.lambda / out.stress_unit),
                                 static_cast<float>(l.mu / out.stress_unit)});

  // Packed tetrahedra: corners keep the model's order (the shape gradients follow it).
  const double lu = out.length_unit;
  out.tet_vertices.resize(nt);
  out.tet_shape_a.resize(nt);
  out.tet_shape_b.resize(nt);
  out.tet_shape_c.resize(nt);
  parallel_ranges(nt, threads, 16384, [&](size_t, size_t begin, size_t end) {
    for (size_t i = begin; i < end; ++i) {
      const size_t t = static_cast<size_t>(out.tet_new_to_old[i]);
      const std::array<int32_t, 4>& order = corner_order[t];
      for (int c = 0; c < 4; ++c)
        out.tet_vertices[i][c] = out.vertex_old_to_new[model.tets[t][order[c]]];
      const TetShape<double>& s = model.tet_shape[t];
      // Gradient k of device corner j: the model corner it came from.
      auto g = [&](int j, int k) { return static_cast<float>(s.grad[order[j]][k] * lu); };
      out.tet_shape_a[i] = {g(1, 0), g(1, 1), g(1, 2), g(2, 0)};
      out.tet_shape_b[i] = {g(2, 1), g(2, 2), g(3, 0), g(3, 1)};
      out.tet_shape_c[i] = {g(3, 2), static_cast<float>(s.volume / (lu * lu * lu))};
    }
  });

  // Vertices: update coefficients and masses in device order.
  out.vertex_update.resize(nv);
  out.vertex_mass.resize(nv);
  for (size_t i = 0; i < nv; ++i) {
    const size_t v = static_cast<size_t>(out.vertex_new_to_old[i]);
    const VertexCoefficients& k = model.vertex_coefficients[v];
    const bool fixed = !model.vertex_fixed.empty() && model.vertex_fixed[v] != 0;
    out.vertex_update[i].b = fixed ? 0.0f : static_cast<float>(k.b);
    out.vertex_update[i].c = fixed ? kFixedMarker : static_cast<float>(k.c * out.force_unit / lu);
    out.vertex_mass[i] = model.vertex_mass[v];
  }

  // Gather lists by counting sort; visiting tets in device order makes each list ascending.
  out.gather_offsets.assign(nv + 1, 0);
  for (const auto& e : out.tet_vertices)
    for (int c = 0; c < 4; ++c) ++out.gather_offsets[e[c] + 1];
  for (size_t v = 0; v < nv; ++v) out.gather_offsets[v + 1] += out.gather_offsets[v];
  out.gather_entries.resize(4 * nt);
  std::vector<int32_t> cursor(out.gather_offsets.begin(), out.gather_offsets.end() - 1);
  for (size_t i = 0; i < nt; ++i)
    for (int c = 0; c < 4; ++c)
      out.gather_entries[cursor[out.tet_vertices[i][c]]++] = static_cast<int32_t>(i << 2) | c;
  return out;
}

}  // namespace zona
