// The CUDA backend's data layout, built on the host from a Model: vertices renumbered along a
// Morton curve, tetrahedra sorted by material and first vertex, per-tetrahedron geometry
// packed into 56 bytes of float32 in scaled units, per-vertex update coefficients, and the
// vertex-to-tetrahedron gather lists. Plain host code (no CUDA): it is tested on every machine.
#pragma once

#include <array>
#include <cstdint>
#include <vector>

#include "engine/core/base.h"
#include "engine/fem/model.h"

namespace zona {

/// Most materials the device kernels take (as kernel parameters, not per-tetrahedron bytes).
inline constexpr int kMaxDeviceMaterials = 8;

/// How the device layout is built.
struct DeviceLayoutOptions {
  /// Renumber vertices along a Morton (Z-order) curve of the rest positions, order each
  /// tetrahedron's corners by vertex and sort the tetrahedra by (material, first, second
  /// vertex): neighbouring threads then touch neighbouring vertices, so gathers and atomics hit
  /// the caches and warp aggregation finds runs. Off keeps the model's numbering and corner
  /// order (the tetrahedra are still grouped by material).
  bool reorder = true;
  /// Threads for the build (engine/core/parallel.h; 0: the hardware's count). The layout is the
  /// same for any count.
  int threads = 1;
};

/// Per-vertex update coefficients, in the device's order: u+ = u + b (u - u-) + c f, with f in
/// device force units. b = (M - gamma dt/2)/(M + gamma dt/2); this is the model's
/// a u - b u- + c f rewritten with a = 1 + b, so that the increment, not the position, carries
/// the rounding. Fixed vertices have c = kFixedMarker, prescribed ones c = kPrescribedMarker;
/// vertices no tetrahedron uses have b = c = 0 (they stay where they are).
struct DeviceVertexUpdate {
  float b = 0;  ///< [-]
  float c = 0;  ///< dt^2 / (M + gamma dt / 2) times the force unit, over the length unit [-]
};

/// c of a vertex whose displacement the prescribed-vertex kernel writes (the update skips it).
inline constexpr float kPrescribedMarker = -1.0f;
/// c of a fixed vertex: the update writes zero (as the CPU step does).
inline constexpr float kFixedMarker = -2.0f;

/// The layout (corners of each tetrahedron in ascending device vertex order, tetrahedra sorted
/// by material, first and second vertex). Lengths are in units of `length_unit`, stresses in
/// `stress_unit`, forces in stress_unit * length_unit^2: powers of two chosen from the mesh and the
/// materials so that the float32 arithmetic of every formulation stays far from underflow (SVK's D
/// tensor carries 1/V^3: at 1 um elements V^3 = 1e-54 m^9, below float32's range in SI units).
struct DeviceLayout {
  double length_unit = 1;  ///< [m], a power of two near the typical element size
  double stress_unit = 1;  ///< [Pa], a power of two near the largest shear modulus
  double force_unit = 1;   ///< stress_unit * length_unit^2 [N]

  std::vector<int32_t> vertex_new_to_old;  ///< model vertex of device vertex i, (vertex_count)
  std::vector<int32_t> vertex_old_to_new;  ///< device vertex of model vertex v, (vertex_count)
  std::vector<int32_t> tet_new_to_old;     ///< model tetrahedron of device tet i, (tet_count)

  /// Device vertex indices of each tetrahedron, ascending (with reorder), (tet_count).
  std::vector<std::array<int32_t, 4>> tet_vertices;
  /// Packed shape: grad N_1, grad N_2, grad N_3 of the device corners 1..3 [1/length_unit] and
  /// volume [length_unit^3]
  /// in three arrays of 16, 16 and 8 bytes so each thread loads them with vector loads:
  /// a = (g1.x, g1.y, g1.z, g2.x), b = (g2.y, g2.z, g3.x, g3.y), c = (g3.z, V), (tet_count).
  std::vector<std::array<float, 4>> tet_shape_a;
  std::vector<std::array<float, 4>> tet_shape_b;
  std::vector<std::array<float, 2>> tet_shape_c;

  /// Tetrahedra of material k are [material_tet_begin[k], material_tet_begin[k+1]), (k+1).
  std::vector<int32_t> material_tet_begin;
  /// Lame coefficients (lambda, mu) per material [stress_unit], (material_count).
  std::vector<std::array<float, 2>> material_lame;

  std::vector<DeviceVertexUpdate> vertex_update;  ///< (vertex_count)
  std::vector<double> vertex_mass;                ///< lumped mass [kg], (vertex_count)

  /// Gather lists: the tetrahedra around device vertex v are
  /// gather_entries[gather_offsets[v] .. gather_offsets[v+1]), each packed as
  /// (device tet << 2) | corner, ascending: the fixed order that makes a gather deterministic.
  std::vector<int32_t> gather_offsets;  ///< (vertex_count + 1)
  std::vector<int32_t> gather_entries;  ///< (4 tet_count)

  size_t vertex_count() const { return vertex_new_to_old.size(); }
  size_t tet_count() const { return tet_vertices.size(); }
  size_t material_count() const { return material_lame.size(); }
  /// Bytes of packed per-tetrahedron data the force kernel streams: 16 + 16 + 16 + 8 = 56.
  static constexpr size_t kTetBytes = 56;
};

/// Builds the layout. Errors: more than kMaxDeviceMaterials materials, more than 2^29
/// tetrahedra (the gather entries pack tet << 2 into 31 bits), a mesh that is empty.
Result<DeviceLayout> build_device_layout(const Model& model, const DeviceLayoutOptions& options);

/// 63-bit Morton code of a point in the box [lo, hi] (21 bits per axis).
uint64_t morton_code(Vec3d p, Vec3d lo, Vec3d hi);

/// The power of two nearest to x (x > 0).
double nearest_power_of_two(double x);

}  // namespace zona
