// The immutable physics model: materials, lumped masses, per-tetrahedron geometry or mass
// tensors, boundary conditions and the stable time step, built once from a descriptor.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "engine/core/aligned_vector.h"
#include "engine/core/base.h"
#include "engine/fem/fem_element.h"
#include "engine/fem/mass_tensor.h"
#include "engine/fem/material.h"
#include "engine/mesh/mesh.h"

namespace zona {

/// What the model does about inverted and collapsing SVK elements.
enum class InversionHandling : int32_t {
  kReport = 0,        ///< plain SVK; step() flags inverted/collapsing elements and goes on
  kClampStretch = 1,  ///< inversion-safe SVK: principal stretches clamped (fem_element.h)
};

/// Precision of the CPU element math (the gradient form). Displacements, their edge differences,
/// corner forces, their sums and the update stay float64 either way (as on the GPU); docs/physics.md
/// and docs/performance.md give the error and the speed of each.
enum class ElementPrecision : int32_t {
  kFloat64 = 0,  ///< the reference: four tetrahedra per AVX2 pack
  kFloat32 = 1,  ///< strain, stress and forces in float32: eight tetrahedra per AVX2 pack
};

/// How the critical (largest stable) time step is computed; docs/physics.md compares them.
enum class CriticalStep : int32_t {
  /// Element eigenvalue bound (default, rigorous for the linearised model): omega_max^2 is at
  /// most max_e omega_e^2 with omega_e^2 <= (4 / rho_e)(lambda sum_j |g_j|^2 + 2 mu
  /// lambda_max(sum_j g_j g_j^T)), so dt_crit = min_e sqrt(rho_e / (lambda sum|g|^2 + 2 mu
  /// lambda_max)). Measured at 0.65-1.0 of the exact limit. Cheap.
  kElementBound = 0,
  /// 2 / omega_max with omega_max from power iteration on M^-1 K (exact in the limit, from
  /// above in dt: keep dt_safety < 1). ~1.5x larger steps on regular meshes; costs a few
  /// hundred force evaluations at build.
  kPowerIteration = 1,
};

/// A material for the tetrahedra of one region tag.
struct RegionMaterial {
  int32_t region = 0;  ///< region tag (Mesh::tet_region)
  Material material;
};

/// Everything build_model needs besides the mesh. Defaults give a usable SVK model of the
/// mouse zona pellucida (Ladjal et al. Table I) with an automatic stable step.
struct ModelDesc {
  /// Material of every tetrahedron whose region has no entry in `region_materials`.
  Material material{};
  /// Per-region overrides.
  std::vector<RegionMaterial> region_materials;
  /// Lumped vertex mass [kg]: 0 derives masses from the densities (rho V / 4 per tetrahedron
  /// corner); > 0 gives every vertex this mass (Ladjal et al.'s choice: 0.07995e-5 mg = 7.995e-13 kg).
  double vertex_mass = 0;
  ConstitutiveModel constitutive = ConstitutiveModel::kSvk;
  Formulation formulation = Formulation::kGradient;
  InversionHandling inversion = InversionHandling::kReport;
  /// Smallest principal stretch the clamped SVK evaluates [-] (kClampStretch only).
  double clamp_stretch = kSvkCollapseStretch;
  /// Vertices held at zero displacement.
  std::vector<int32_t> fixed_vertices;
  /// Uniform mass scaling factor (>= 1 to speed up quasi-static runs): every mass times this,
  /// the critical step times its square root. The factor used is reported in Model.
  double mass_scaling = 1.0;
  /// When > 0: raise mass_scaling as far as needed for the automatic step to reach this [s].
  double target_dt = 0;
  /// Time step [s]: 0 chooses dt_safety * dt_critical. A value above dt_critical is refused.
  double dt = 0;
  /// Fraction of the critical step used by the automatic step, in (0, 1]. Below 1 also because
  /// SVK stiffens under stretch, which lowers the limit of the deformed body.
  double dt_safety = 0.9;
  /// How dt_critical is computed.
  CriticalStep critical_step = CriticalStep::kElementBound;
  /// step() flags an energy blow-up when kinetic + elastic energy exceeds this factor times
  /// (initial energy + work put in by loads and prescribed vertices).
  double energy_blowup_factor = 10.0;
  /// Experiments only: accept dt above dt_critical (every step then reports
  /// kStepDtAboveCritical). Used to show the blow-up; never set it in a simulation.
  bool unsafe_allow_dt_above_critical = false;
  /// Threads of build_model's per-element work (shapes, the critical step, the CPU batches, stored
  /// tensors; 1: serial). Does not change the result.
  int precompute_threads = 1;
  /// Stable neo-Hookean only: the volumetric term averaged at the vertices (nodal pressure,
  /// after Bonet and Burton 1998; fem_element.h snh_first_piola_nodal) instead of taken per
  /// element. Linear tetrahedra with one volume per element lock when nearly incompressible
  /// (nu 0.49: coarse meshes far too stiff); with one volume per vertex they do not
  /// (docs/physics.md, "Nodal pressure").
  bool nodal_pressure = false;
  /// With nodal_pressure: the fraction beta in [0, 1) of each element's lambda kept in the
  /// element (lambda_s = mu + beta lambda) and not averaged at the vertices (lambda_v scaled by
  /// 1 - beta), so that vertex-to-vertex pressure modes meet beta lambda (docs/physics.md,
  /// "Nodal pressure"). 0: none. The CPU's element passes (explicit and static) take it; the
  /// CUDA backend does not yet and refuses a model with it.
  double nodal_stabilisation = 0;
  /// CPU element math precision; kFloat32 needs the gradient form without the stretch clamp.
  /// The CUDA backend always evaluates elements in float32 and ignores this.
  ElementPrecision element_precision = ElementPrecision::kFloat64;
};

/// Doubles per batch of eight tetrahedra in Model::cpu_tet_batches.
inline constexpr int kCpuTetBatchStride = 96;
/// Floats per batch of eight tetrahedra in Model::cpu_tet_batches_f32.
inline constexpr int kCpuTetBatchStrideF32 = 96;
/// Offsets per batch of eight tetrahedra in Model::cpu_tet_corner_offsets.
inline constexpr int kCpuTetOffsetStride = 32;

/// Integration coefficients of one vertex for the centred-difference update
/// u+ = a u - b u- + c f (docs/physics.md section 3), with gamma = alpha M:
/// a = 2M / (M + gamma dt/2), b = (M - gamma dt/2) / (M + gamma dt/2), c = dt^2 / (M + gamma dt/2).
struct VertexCoefficients {
  double a = 0;  ///< [-]
  double b = 0;  ///< [-]
  double c = 0;  ///< [s^2/kg]
};

/// The immutable model. Build it with build_model; afterwards only read it.
struct Model {
  // Mesh.
  std::vector<Vec3d> rest_positions;  ///< rest positions [m], (vertex_count)
  std::vector<Tet> tets;              ///< vertex indices, (tet_count)
  VertexTetAdjacency adjacency;       ///< tetrahedra around each vertex, ascending

  // Materials.
  std::vector<Material> materials;     ///< distinct materials, (material_count)
  std::vector<Lame> material_lame;     ///< their Lame coefficients [Pa], (material_count)
  std::vector<int32_t> tet_material;   ///< material index per tetrahedron, (tet_count)
  ConstitutiveModel constitutive = ConstitutiveModel::kSvk;
  Formulation formulation = Formulation::kGradient;
  InversionHandling inversion = InversionHandling::kReport;
  double clamp_stretch = kSvkCollapseStretch;  ///< [-]
  /// ModelDesc::nodal_pressure. Then per vertex: 1 / V_v with V_v the sum of a quarter of each
  /// adjacent element's volume [1/m^3], and lambda_v the V_e / 4-weighted mean of their
  /// materials' lambda [Pa], (vertex_count); empty otherwise.
  bool nodal_pressure = false;
  double nodal_stabilisation = 0;  ///< ModelDesc::nodal_stabilisation; lambda_v carries 1 - it
  std::vector<double> vertex_inverse_volume;
  std::vector<double> vertex_lambda;

  // Precomputed element data.
  std::vector<TetShape<double>> tet_shape;  ///< shape gradients [1/m] and volume [m^3], (tet_count)
  MassTensors tensors;  ///< stored tensors, filled only for Formulation::kTensorStored
  /// The CPU backend's copy of the gradient-form data in batches of eight tetrahedra, lane-major
  /// so that one load fills eight lanes (AVX-512) or four (half a batch): per batch 12 x 8
  /// doubles (grad[1..3] x/y/z, volume, lambda, mu; lane l = tetrahedron 8 b + l, the last one
  /// repeated past the end), (ceil(tet_count / 8) x 96). Same numbers as tet_shape and tet_lame;
  /// grad[0] = -(grad[1] + grad[2] + grad[3]) is left out: the element functions never read it
  /// (H from edge differences, f_0 = -(f_1 + f_2 + f_3)).
  CacheAlignedVector<double> cpu_tet_batches;
  /// Where each corner's displacement starts in State::u, in doubles (3 x vertex index), in the
  /// same batches: per batch 4 corners x 8 lanes, (ceil(tet_count / 8) x 32). The element pass
  /// loads corners through it: no index scaling, no special case for the last batch.
  std::vector<int32_t> cpu_tet_corner_offsets;
  /// CPU element math precision (ModelDesc::element_precision).
  ElementPrecision element_precision = ElementPrecision::kFloat64;
  /// kFloat32 only: the same numbers rounded to float in batches of eight (lane l = tetrahedron
  /// 8 b + l, the last one repeated past the end), (ceil(tet_count / 8) x 96); empty otherwise.
  CacheAlignedVector<float> cpu_tet_batches_f32;

  // Masses and boundary conditions.
  std::vector<double> vertex_mass;          ///< lumped mass, scaled [kg], (vertex_count)
  std::vector<double> vertex_damping;       ///< gamma = alpha M [kg/s], (vertex_count)
  std::vector<VertexCoefficients> vertex_coefficients;  ///< update coefficients, (vertex_count)
  std::vector<int32_t> fixed_vertices;      ///< sorted, unique
  std::vector<uint8_t> vertex_fixed;        ///< 1 for fixed vertices, (vertex_count)

  // Time step.
  double dt = 0;               ///< time step [s]
  double dt_critical = 0;      ///< stability limit used (ModelDesc::critical_step) [s]
  double dt_element_bound = 0; ///< rigorous element-eigenvalue bound on the limit [s]
  double omega_max = 0;        ///< power-iteration omega_max, 0 unless asked for [rad/s]
  double min_altitude = 0;     ///< smallest element altitude h_min [m]
  double max_wave_speed = 0;   ///< largest effective dilatational wave speed c_d [m/s]
  /// The textbook estimate h_min / c_d [s], reported only: measured 4-58 % ABOVE the exact
  /// limit on tetrahedral meshes (docs/physics.md), so never used as the step.
  double dt_altitude_estimate = 0;
  double mass_scaling = 1.0;   ///< factor applied to every mass [-]
  bool unsafe_allow_dt_above_critical = false;

  // Health thresholds.
  double energy_blowup_factor = 10.0;  ///< [-]
  /// Energies below this are noise [J]: mu * total volume * (1e-8)^2.
  double energy_floor = 0;

  // Precompute timings (Ladjal et al. Table II column 3).
  double precompute_seconds = 0;         ///< whole build_model [s]
  double tensor_precompute_seconds = 0;  ///< stored tensors alone, 0 when not stored [s]

  size_t vertex_count() const { return rest_positions.size(); }
  size_t tet_count() const { return tets.size(); }
  /// Lame coefficients of tetrahedron t [Pa].
  const Lame& tet_lame(size_t t) const { return material_lame[static_cast<size_t>(tet_material[t])]; }
};

/// Builds a model. The mesh must have passed validate_mesh (positive volumes). Errors (one
/// line each): invalid materials (E <= 0, nu outside [0, 0.5), ...), fixed vertex out of range,
/// bad mass scaling or safety factor, dt above the critical step.
Result<Model> build_model(const Mesh& mesh, const ModelDesc& desc);

/// One-line summary: sizes, model, formulation, dt and dt_critical, mass scaling; with
/// explicit_step false (a static run, which has no time step) the sizes and the law alone.
std::string describe_model(const Model& model, bool explicit_step = true);

}  // namespace zona
