// CPU internal-force assembly (both formulations, multi-threaded, bitwise deterministic),
// global tangent stiffness and the largest natural frequency, for tests and quasi-static tools.
//
// Determinism: every vertex force is a sum of its corner forces in ascending tetrahedron order,
// grouped by segment, with no shared writes: a vertex's corners in the segment of its first
// tetrahedron are added into its block by the one thread that runs that segment, in
// tetrahedron order; its corners in each later segment are added, in order, into one slot of
// that segment's; the vertex pass adds the slots to the block in segment order (AssemblyPlan in
// state.h). The segments are cut by the mesh alone (assembly_segment_count). Energies and
// counts are summed per fixed-size chunk and the chunks in order. No result depends on the
// thread count.
#pragma once

#include <Eigen/SparseCore>
#include <span>

#include "engine/fem/model.h"
#include "engine/core/simd_pack.h"
#include "engine/fem/state.h"

namespace zona {

/// Widest SIMD the float64 element pass uses: 512 (eight tetrahedra per AVX-512 pack) or 256
/// (four per AVX2 pack). Both give the same bits (cpu_element_fma() decides which). Default on
/// CPUs with AVX-512F: 256 when the fused pass runs (it made the step faster than the fused
/// 512-bit one; docs/performance.md), 512 with ZONA_CPU_FMA=0 or ZONA_CPU_SIMD_BITS=512;
/// ZONA_CPU_SIMD_BITS=256 forbids 512. For benchmarks and tests.
int cpu_simd_bits();
/// Limits the float64 element pass to 256-bit packs (bits < 512) or uses AVX-512 where the CPU
/// has it and ZONA_CPU_SIMD_BITS is not 256 (bits >= 512). Not thread-safe against a running
/// pass.
void set_cpu_simd_bits(int bits);

/// Vector registers the fused four-lane (256-bit) element pass and the step's vertex pass may
/// use: 32 on CPUs with AVX-512VL (both are then encoded with it: same vectors, same bits, no
/// spills, one-instruction two-source shuffles), else 16; 16 when the environment sets
/// ZONA_CPU_SIMD_REGISTERS=16. For benchmarks and tests.
int cpu_simd_registers();
/// 32 where the CPU has AVX-512VL and the environment allows it, else 16. Not thread-safe
/// against a running pass.
void set_cpu_simd_registers(int registers);

/// Whether the float64 gradient-form element pass fuses multiply-adds (~half the operations):
/// true on CPUs with AVX2 and FMA unless the environment sets ZONA_CPU_FMA=0. With FMA its corner
/// forces differ from the scalar fem_element.h functions in the last bits (relative 1e-13 of the
/// element's largest corner force; the AVX2 and AVX-512 passes still agree bit for bit, for any
/// thread count); without, they equal them bit for bit. One setting per process.
bool cpu_element_fma();
/// Switches the fused pass off (false) or back on where the CPU has FMA (true). Not thread-safe
/// against a running pass; for tests and benchmarks.
void set_cpu_element_fma(bool on);

/// The batched element passes skip the exact health checks (det F, SVK collapse) of a batch
/// whose displacement gradients all have |H|^2 (Frobenius) below this [-]: there the checks
/// cannot fail (engine/fem/forces_cpu.cpp says why; forces_simd_test checks it with the scalar
/// functions), so the flags are those of always checking.
inline constexpr double kHealthCheckSkipBelowGradientSq = 0.01;

/// The clamped SVK (InversionHandling::kClampStretch) runs in the batched float64 passes, which
/// look for elements to clamp only in batches where some lane has |H|^2 at or above this bound
/// [-]. Below it every principal stretch exceeds 1 - |H| > (1 + clamp_stretch) / 2 and 0.9, so
/// no element is clamped, inverted or collapsing, with margins that rounding cannot eat:
/// min(kHealthCheckSkipBelowGradientSq, ((1 - clamp_stretch) / 2)^2), or 0 (every batch is
/// checked) for a clamp stretch within 1e-6 of 1. forces_simd_test checks it with the scalar
/// functions.
inline double clamp_check_skip_below_gradient_sq(double clamp_stretch) {
  const double margin = 0.5 * (1.0 - clamp_stretch);
  if (!(margin > 5e-7)) return 0.0;
  return margin * margin < kHealthCheckSkipBelowGradientSq ? margin * margin
                                                           : kHealthCheckSkipBelowGradientSq;
}

/// Element pass: corner forces of every tetrahedron at displacements state.u, summed into the
/// blocks of state.assembly (vertex sums and late slots), energy and health per chunk into
/// state.tet_chunks. Runs on state.pool, one segment per claim.
void compute_tet_forces(const Model& model, State& state);

/// After compute_tet_forces with an all-late plan (make_assembly_plan(..., true)): the force of
/// corner c of tetrahedron t [N]. For tests.
Vec3d corner_force(const State& state, size_t t, int c);

/// Sums the element-pass chunks into diag: elastic energy, health bits, counts, first indices.
void reduce_tet_chunks(const State& state, StepDiagnostics& diag);

/// Consumes vertex v's sum after compute_tet_forces: its elastic force [N], its block (the sum
/// of its corners in its owning segment) plus its late slots in segment order,
/// x, y, z in lanes 0-2 of a pack (lane 3 holds no force: 0, or with the AVX-512VL pass a
/// copy of z; nothing reads it); v's blocks go back to their start values
/// (+0.0, late slots -0.0) for the next element pass. The step's vertex pass and
/// compute_elastic_forces read the sums through it.
[[gnu::always_inline]] inline P4 take_vertex_force(double* blocks, const int32_t* late_offsets,
                                                   size_t v) {
  P4 f = load4(blocks + 4 * v);
  store4(zero4(), blocks + 4 * v);
  for (int32_t k = late_offsets[v]; k < late_offsets[v + 1]; ++k) {
    f += load4(blocks + 4 * k);
    store4(P4(-0.0), blocks + 4 * k);
  }
  return f;
}

/// Elastic forces -dW/du at state.u into state.force [N] (fixed and prescribed vertices
/// included), with the elastic energy and element health in state.diag. Does not step.
void compute_elastic_forces(const Model& model, State& state);

/// Global tangent stiffness d^2W/du^2 at displacements u [N/m], (3 vertex_count)^2, symmetric;
/// the model's constitutive law (SVK or stable neo-Hookean tangent, or linear K). Host-only,
/// allocates.
Eigen::SparseMatrix<double> assemble_stiffness(const Model& model, std::span<const Vec3d> u);

/// Largest natural frequency omega_max [rad/s] of the linearised model (M^-1 K at rest, fixed
/// vertices removed) by power iteration; the explicit centred-difference scheme is stable for
/// dt <= 2 / omega_max. Converges from below. Host-only, allocates.
double estimate_max_frequency(const Model& model, int iterations = 400);

}  // namespace zona
