// The kernels of one explicit step on the GPU: the element pass (scatter with atomics, plain or
// aggregated per block, in float32 or in deterministic fixed point; or per-corner forces for a
// later gather), the deterministic gather fused with the centred-difference update, the update
// after a scatter (with the prescribed vertices in one extra block), stored-tensor build and the
// on-demand reductions. Thin wrappers: the element math is eval_element() (element_eval.h), the
// same functions the CPU runs. Included by cuda_backend.cu only.
#pragma once

#include <climits>
#include <cstdint>
#include <cub/block/block_reduce.cuh>
#include <cuda/atomic>
#include <type_traits>

#include "engine/sim/integrator.h"
#include "kernels/device_layout.h"
#include "engine/fem/element_eval.h"

namespace zona::cuda {

/// Threads per block of every kernel (the CUB block reductions are sized for it).
inline constexpr int kBlock = 256;

/// How the element pass hands its corner forces on.
enum class Scatter : int {
  kFloatAtomic = 0,  ///< one float4 atomic per corner into the vertex force
  kFloatWarp = 1,    ///< runs of equal vertices in a warp summed by shuffles first (corners 0, 1)
  kFixedWarp = 2,    ///< like kFloatWarp in 64-bit fixed point: integer sums, deterministic
  kStore = 3,        ///< written to tet_force[4 t + corner] for a gather (deterministic)
};

/// Fixed-point scale of kFixedWarp: forces in device units (order 1 at unit strain) times
/// 2^40. Headroom 2^23 device units per vertex, resolution 1e-12: finer than float32's rounding
/// of any contribution above 1e-5 device units.
inline constexpr double kFixedScale = 1099511627776.0;  // 2^40
inline constexpr double kFixedInverse = 1.0 / kFixedScale;
/// Contributions beyond this are treated as a blow-up (flagged non-finite, not wrapped).
inline constexpr float kFixedLimit = 4194304.0f;  // 2^22

/// Per-tetrahedron inputs of the element pass, passed by value.
struct TetParams {
  const int4* vertices = nullptr;   ///< device vertex indices, (tet_count)
  const float4* shape_a = nullptr;  ///< packed shape, see DeviceLayout, (tet_count)
  const float4* shape_b = nullptr;
  const float2* shape_c = nullptr;
  const float* tensors = nullptr;              ///< stored kinds: tensor_stride floats per tet
  const int32_t* tet_new_to_old = nullptr;     ///< model index of each device tet (messages)
  const int32_t* vertex_new_to_old = nullptr;  ///< model index of each device vertex (messages)
  int tensor_stride = 0;
  int tet_count = 0;
  int material_count = 1;
  int material_begin[kMaxDeviceMaterials + 1] = {};
  float lambda[kMaxDeviceMaterials] = {};  ///< [stress_unit]
  float mu[kMaxDeviceMaterials] = {};      ///< [stress_unit]
  float clamp_stretch = 0;
  bool clamp_at_collapse = true;
  /// Nodal pressure (Model::nodal_pressure; stable neo-Hookean only), else null: per device
  /// vertex the sum of V_e / 4 (J_e - 1) over its elements [length_unit^3], filled by
  /// volume_change_kernel and zeroed by the step's vertex kernel after the element pass, and
  /// (lambda_v [stress_unit], 1 / V_v [1/length_unit^3]).
  float* vertex_q = nullptr;
  /// Nodal pressure with the fixed-point scatter (Assembly::kScatterFixed): the same sums in
  /// 64-bit fixed point (kFixedScale), so that they, and the run, do not depend on the order of
  /// the atomics; vertex_q is then null.
  unsigned long long* vertex_q_fixed = nullptr;
  const float2* vertex_nodal = nullptr;
  /// Nodal pressure's stabilisation beta (Model::nodal_stabilisation): the element keeps
  /// lambda_s = mu + beta lambda (vertex_nodal's lambda_v carry 1 - beta); 0: mu exactly.
  float nodal_stabilisation = 0;
  double energy_unit = 1;  ///< J per device energy unit (stress_unit * length_unit^3)
};

/// Whether the model has nodal pressure (either form of the sums).
__host__ __device__ inline bool has_nodal(const TetParams& tp) {
  return tp.vertex_q != nullptr || tp.vertex_q_fixed != nullptr;
}

/// The vertex's nodal sum of V_e / 4 (J_e - 1) [length_unit^3].
__device__ __forceinline__ float nodal_sum(const TetParams& tp, int v) {
  if (tp.vertex_q_fixed)
    return float(double(static_cast<long long>(tp.vertex_q_fixed[v])) * kFixedInverse);
  return tp.vertex_q[v];
}

/// Per-vertex arrays of one sub-step (pointers chosen by the sub-step's buffer phase).
struct VertexParams {
  const double* u = nullptr;            ///< u_n [length_unit], (3 vertex_count)
  const double* u_prev = nullptr;       ///< u_{n-1}
  double* u_next = nullptr;             ///< u_{n+1} (written)
  float4* force = nullptr;              ///< elastic force at u_n [force_unit], (vertex_count)
  float4* force_clear = nullptr;        ///< float scatter: the next sub-step's accumulator, zeroed
  unsigned long long* fixed = nullptr;  ///< fixed scatter: this sub-step's sums, (3 nv)
  unsigned long long* fixed_clear = nullptr;  ///< fixed scatter: the next one's, zeroed
  const float4* tet_force = nullptr;          ///< gather_stored: corner forces, (4 tet_count)
  const float4* external = nullptr;           ///< loads [force_unit], or null when there are none
  const float2* update = nullptr;             ///< DeviceVertexUpdate (b, c), (vertex_count)
  const double* mass = nullptr;               ///< [kg], (vertex_count)
  const int* gather_offsets = nullptr;
  const int* gather_entries = nullptr;
  const int32_t* vertex_new_to_old = nullptr;
  float* nodal_clear = nullptr;  ///< TetParams::vertex_q, zeroed by the update (nodal pressure)
  unsigned long long* nodal_clear_fixed = nullptr;  ///< TetParams::vertex_q_fixed, likewise
  int vertex_count = 0;
  double length_unit = 1;  ///< [m]
  double force_unit = 1;   ///< [N]
  double half_inv_dt = 0;  ///< 1 / (2 dt) [1/s]
};

/// Zeroes the vertex's nodal sum for the next step (the update kernels).
__device__ __forceinline__ void clear_nodal(const VertexParams& vp, int v) {
  if (vp.nodal_clear) vp.nodal_clear[v] = 0.0f;
  if (vp.nodal_clear_fixed) vp.nodal_clear_fixed[v] = 0ull;
}

/// Prescribed vertices of one window.
struct PrescribedParams {
  const int32_t* vertices = nullptr;  ///< device indices, (count)
  const double* start = nullptr;      ///< target at the window start [length_unit], (3 count)
  const double* delta = nullptr;      ///< target increment per sub-step [length_unit], (3 count)
  const double* mass = nullptr;       ///< [kg], (count)
  const double* damping = nullptr;    ///< gamma [kg/s], (count)
  int count = 0;
  double inv_dt2 = 0;  ///< 1 / dt^2 [1/s^2]
};

/// What the device reports for one window; zero (and "none" sentinels) at the window start.
struct DeviceStatus {
  uint32_t flags = 0;                ///< StepStatusBits
  int32_t failed_substep = INT_MAX;  ///< first sub-step with a non-finite update
  unsigned long long inverted_count = 0;
  unsigned long long collapsing_count = 0;
  unsigned long long clamped_count = 0;
  long long first_inverted = LLONG_MAX;    ///< model tet index
  long long first_collapsing = LLONG_MAX;  ///< model tet index
  long long first_nonfinite = LLONG_MAX;   ///< model vertex index
  double elastic_energy = 0;               ///< last sub-step [J]
  double kinetic_energy = 0;               ///< last sub-step [J]
  double input_work = 0;                   ///< whole window [J]
  double residual_sq = 0;                  ///< last sub-step [N^2]
  double reference_sq = 0;                 ///< last sub-step [N^2]
  double constraint_force[3] = {0, 0, 0};  ///< last sub-step [N]
};

/// Programmatic dependent launch (sm_90): wait until the previous kernel of the stream has
/// finished and its writes are visible. A no-op when the kernel was launched without the
/// attribute. Every kernel calls it before touching memory an earlier kernel wrote.
__device__ __forceinline__ void wait_for_previous_kernel() {
#if defined(__CUDA_ARCH__) && __CUDA_ARCH__ >= 900
  asm volatile("griddepcontrol.wait;" ::: "memory");
#endif
}

/// Lets the next kernel of the stream be launched now: its blocks are scheduled as this one's
/// retire and wait in wait_for_previous_kernel(), so the launch latency overlaps this kernel.
__device__ __forceinline__ void allow_next_kernel() {
#if defined(__CUDA_ARCH__) && __CUDA_ARCH__ >= 900
  asm volatile("griddepcontrol.launch_dependents;" :::);
#endif
}

/// True when a sub-step before `substep` in this window was not finite: every later kernel then
/// leaves the state as it is (the step is not advanced, as on the CPU). Concurrent writers of
/// this sub-step only ever write `substep` itself, so every thread of a block decides alike.
__device__ __forceinline__ bool halted(DeviceStatus* st, int substep) {
  ::cuda::atomic_ref<int32_t, ::cuda::thread_scope_device> failed(st->failed_substep);
  return failed.load(::cuda::memory_order_relaxed) < substep;
}

/// Records a non-finite value at `substep` (model vertex `vertex` for the message).
__device__ __forceinline__ void flag_nonfinite(DeviceStatus* st, int substep, long long vertex) {
  atomicOr(&st->flags, uint32_t{kStepNonFinite});
  atomicMin(&st->failed_substep, substep);
  atomicMin(&st->first_nonfinite, vertex);
}

/// Adds a block's sum of `v` to *dst (one atomic per block). Every thread of the block calls it.
__device__ __forceinline__ void block_sum_add(double v, double* dst) {
  using Reduce = cub::BlockReduce<double, kBlock>;
  __shared__ typename Reduce::TempStorage temp;
  const double s = Reduce(temp).Sum(v);
  if (threadIdx.x == 0 && s != 0) atomicAdd(dst, s);
  __syncthreads();  // temp is reused by the next call
}

/// The larger of two values (the reduction operator of block_max_store).
struct MaxOf {
  __device__ __forceinline__ double operator()(double a, double b) const { return a > b ? a : b; }
};

/// Raises *dst to the block's largest v (v >= 0: a non-negative double orders as its bits).
__device__ __forceinline__ void block_max_store(double v, double* dst) {
  using Reduce = cub::BlockReduce<double, kBlock>;
  __shared__ typename Reduce::TempStorage temp;
  const double m = Reduce(temp).Reduce(v, MaxOf{});
  if (threadIdx.x == 0 && m > 0)
    atomicMax(reinterpret_cast<unsigned long long*>(dst),
              static_cast<unsigned long long>(__double_as_longlong(m)));
  __syncthreads();  // temp is reused by the next call
}

/// Packed shape and material of device tetrahedron t.
__device__ __forceinline__ TetShape<float> load_shape(const TetParams& tp, int t, float* lambda,
                                                      float* mu) {
  const float4 a = tp.shape_a[t];
  const float4 b = tp.shape_b[t];
  const float2 c = tp.shape_c[t];
  int m = 0;
  // Tetrahedra are sorted by material: a few uniform comparisons find the range.
  for (int k = 1; k < tp.material_count; ++k) m += t >= tp.material_begin[k] ? 1 : 0;
  *lambda = tp.lambda[m];
  *mu = tp.mu[m];
  return tet_shape_from_packed(Vec3f{a.x, a.y, a.z}, Vec3f{a.w, b.x, b.y}, Vec3f{b.z, b.w, c.x},
                               c.y);
}

/// Displacements of corners 1..3 of the tetrahedron with device vertices `id` relative to corner 0
/// (u_c - u_0), formed in float64 and rounded to float32 [length_unit]: a large rigid
/// displacement of the cell costs no digits of strain.
__device__ __forceinline__ void load_relative_displacements(const double* u64, int4 id,
                                                            Vec3f du[3]) {
  const int v[4] = {id.x, id.y, id.z, id.w};
  const double* p0 = u64 + 3 * static_cast<size_t>(v[0]);
  const double x0 = p0[0], y0 = p0[1], z0 = p0[2];
  for (int c = 1; c < 4; ++c) {
    const double* p = u64 + 3 * static_cast<size_t>(v[c]);
    du[c - 1] = Vec3f{float(p[0] - x0), float(p[1] - y0), float(p[2] - z0)};
  }
}

/// The stable neo-Hookean element with nodal pressure (the CPU's batch_pass_snh<L, true>): the
/// element law with lambda_s = mu + beta lambda (TetParams::nodal_stabilisation; beta 0:
/// snh_first_piola_nodal's law) and the corner means of lambda_v (Jbar_v - 1) and of
/// lambda_v / 2 (Jbar_v - 1)^2 from TetParams::vertex_q and vertex_nodal. Energy
/// [stress_unit length_unit^3] returned; kElementInverted where J <= 0.
__device__ __forceinline__ float eval_nodal_tet(const TetParams& tp, const TetShape<float>& s,
                                                float lambda, float mu, int4 id, const Vec3f u[4],
                                                Vec3f f[4], uint32_t* bits) {
  const int v[4] = {id.x, id.y, id.z, id.w};
  float pressure = 0, density = 0;
  for (int c = 0; c < 4; ++c) {
    const float2 n = tp.vertex_nodal[v[c]];
    const float jm1 = nodal_sum(tp, v[c]) * n.y;
    pressure += n.x * jm1;
    density += 0.5f * n.x * jm1 * jm1;
  }
  Mat3f p;
  float jm1;
  // lambda_s = mu + beta lambda (beta 0: mu exactly, the law without the stabilisation).
  const float psi = snh_first_piola_with(tet_displacement_gradient(s, u), mu,
                                         snh_lambda(tp.nodal_stabilisation * lambda, mu),
                                         0.25f * pressure, &p, &jm1);
  *bits = jm1 > -1.0f ? 0u : uint32_t{kElementInverted};
  tet_forces_from_stress(s, p, f);
  return s.volume * (psi + 0.25f * density);
}

/// Sums v[0..N-1] over each run of consecutive lanes of the warp holding the same `key` and
/// returns true on the run's first lane, which then holds the run's total. The tetrahedra are
/// sorted by (first vertex, second vertex) and their corners by vertex index, so corner 0 of
/// neighbouring threads is often the same vertex (runs of about six), corner 1 sometimes (about
/// two): one atomic per run instead of one per corner. Equal keys need not be contiguous
/// (corner 1 of a later run may repeat an earlier one): each lane sums up to the end of its own
/// run only, and every run's head adds its run. Every lane of the warp must call it.
template <class V, int N>
__device__ __forceinline__ bool warp_run_sum(int key, V (&v)[N]) {
  constexpr unsigned kAll = 0xffffffffu;
  const int lane = threadIdx.x & 31;
  const int previous = __shfl_up_sync(kAll, key, 1);
  const bool head = lane == 0 || previous != key;
  // The run of this lane ends before the next head.
  const unsigned heads = __ballot_sync(kAll, head);
  const unsigned later = lane == 31 ? 0u : heads & (~0u << (lane + 1));
  const int end = later ? __ffs(later) - 1 : 32;
  // After the step with offset d, a lane holds the sum over [lane, min(lane + 2d, end)).
  for (int d = 1; d < 32; d <<= 1) {
    V o[N];
    for (int i = 0; i < N; ++i) o[i] = __shfl_down_sync(kAll, v[i], d);
    if (lane + d < end)
      for (int i = 0; i < N; ++i) v[i] += o[i];
  }
  return head;
}

/// Nodal pressure, the step's first pass (TetParams::vertex_q set): V_e / 4 (J_e - 1)
/// [length_unit^3] of every tetrahedron added to its corners' sums, which the previous step's
/// vertex kernel zeroed: corners 0 and 1 summed over their warp's runs first (warp_run_sum, as
/// the element pass; one scalar atomic per corner made this pass, with a tenth of the element
/// pass's arithmetic, slower than it: 226 against 212 us at 1M vertices, H200). Float atomics:
/// the sums' order, and so their last bits, vary; the fixed-point sums do not.
/// Internal linkage: this header is compiled into two translation units.
static __global__ void __launch_bounds__(kBlock)
    volume_change_kernel(TetParams tp, const double* __restrict__ u64, int substep,
                         DeviceStatus* st) {
  wait_for_previous_kernel();
  allow_next_kernel();
  if (halted(st, substep)) return;
  const int t = blockIdx.x * kBlock + threadIdx.x;
  const bool active = t < tp.tet_count;
  float q = 0;
  int v[4] = {-1, -2, -3, -4};  // distinct keys for inactive lanes: they join no run
  if (active) {
    const int4 id = tp.vertices[t];
    float lambda, mu;
    const TetShape<float> s = load_shape(tp, t, &lambda, &mu);
    Vec3f du[3];
    load_relative_displacements(u64, id, du);
    q = 0.25f * s.volume * snh_volume_change(tet_displacement_gradient_from_edges(s, du));
    v[0] = id.x;
    v[1] = id.y;
    v[2] = id.z;
    v[3] = id.w;
  }
  if (tp.vertex_q_fixed) {
    // Integer sums: the same bits in any order. A non-finite q is the element's own non-finite
    // state, which its forces report; it adds nothing here.
    const unsigned long long qf =
        fabsf(q) < kFixedLimit
            ? static_cast<unsigned long long>(__double2ll_rn(double(q) * kFixedScale))
            : 0ull;
    for (int c = 0; c < 4; ++c) {
      unsigned long long sum[1] = {qf};
      const bool lead = c < 2 ? warp_run_sum(v[c], sum) : true;
      if (active && lead) atomicAdd(tp.vertex_q_fixed + v[c], sum[0]);
    }
    return;
  }
  for (int c = 0; c < 4; ++c) {
    float sum[1] = {q};
    const bool lead = c < 2 ? warp_run_sum(v[c], sum) : true;
    if (active && lead) atomicAdd(tp.vertex_q + v[c], sum[0]);
  }
}

/// Evaluates device tetrahedron t at displacements u (float64): corner forces [force_unit] and
/// energy [stress_unit length_unit^3]; health bits go to the status (rare path). The element is
/// translated so that corner 0 sits at zero (energy and forces depend on displacement
/// differences only) and the differences are formed in float64 before rounding to float32: a
/// large rigid displacement of the cell costs no digits of strain.
template <ElementKind K>
__device__ __forceinline__ float eval_device_tet(const TetParams& tp, int t, int4 id,
                                                 const double* u64, Vec3f f[4], DeviceStatus* st,
                                                 bool record_health) {
  float lambda, mu;
  const TetShape<float> s = load_shape(tp, t, &lambda, &mu);
  Vec3f u[4];
  u[0] = Vec3f{0, 0, 0};
  load_relative_displacements(u64, id, &u[1]);
  const float* tensors = nullptr;
  if constexpr (element_kind_stored(K))
    tensors = tp.tensors + static_cast<size_t>(t) * static_cast<size_t>(tp.tensor_stride);
  uint32_t bits = 0;
  float energy;
  if constexpr (K == ElementKind::kSnhGradient) {
    if (has_nodal(tp))
      energy = eval_nodal_tet(tp, s, lambda, mu, id, u, f, &bits);
    else
      energy = eval_element<K, float>(s, lambda, mu, tensors, tp.clamp_stretch,
                                      tp.clamp_at_collapse, u, f, &bits);
  } else {
    energy = eval_element<K, float>(s, lambda, mu, tensors, tp.clamp_stretch,
                                    tp.clamp_at_collapse, u, f, &bits);
  }
  if (record_health) {
    // Rare per element, common per step near the tip (clamped, collapsing elements under a
    // needle): one set of atomics per warp, not per element, so that thousands of flagged
    // elements do not serialise on the status block.
    const unsigned mask = __activemask();
    if (__ballot_sync(mask, bits != 0)) {
      const int lane = threadIdx.x & 31;
      const unsigned inverted = __ballot_sync(mask, (bits & kElementInverted) != 0);
      const unsigned collapsing = __ballot_sync(mask, (bits & kElementCollapsing) != 0);
      const unsigned clamped = __ballot_sync(mask, (bits & kElementClamped) != 0);
      const int model_tet = tp.tet_new_to_old[t];
      const int first_inverted =
          __reduce_min_sync(mask, (bits & kElementInverted) ? model_tet : INT_MAX);
      const int first_collapsing =
          __reduce_min_sync(mask, (bits & kElementCollapsing) ? model_tet : INT_MAX);
      if (lane == __ffs(mask) - 1) {
        uint32_t flags = 0;
        if (inverted) {
          flags |= kStepInvertedElement;
          atomicAdd(&st->inverted_count, static_cast<unsigned long long>(__popc(inverted)));
          atomicMin(&st->first_inverted, static_cast<long long>(first_inverted));
        }
        if (collapsing) {
          flags |= kStepCollapsingElement;
          atomicAdd(&st->collapsing_count, static_cast<unsigned long long>(__popc(collapsing)));
          atomicMin(&st->first_collapsing, static_cast<long long>(first_collapsing));
        }
        if (clamped) {
          flags |= kStepClampedElement;
          atomicAdd(&st->clamped_count, static_cast<unsigned long long>(__popc(clamped)));
        }
        atomicOr(&st->flags, flags);
      }
    }
  }
  return energy;
}

/// Adds a corner force to vertex v: one float4 vector atomic (sm_90), or three scalar ones.
__device__ __forceinline__ void add_force(float4* force, int v, const float f[3]) {
#if defined(__CUDA_ARCH__) && __CUDA_ARCH__ >= 900
  // One 16-byte vector reduction in L2 instead of three scalar ones.
  atomicAdd(force + v, make_float4(f[0], f[1], f[2], 0.0f));
#else
  float* p = reinterpret_cast<float*>(force + v);
  for (int i = 0; i < 3; ++i) atomicAdd(p + i, f[i]);
#endif
}

/// Adds a fixed-point corner force to vertex v (integer additions: order-independent).
__device__ __forceinline__ void add_fixed(unsigned long long* fixed, int v,
                                          const unsigned long long q[3]) {
  for (int i = 0; i < 3; ++i) atomicAdd(fixed + 3 * static_cast<size_t>(v) + i, q[i]);
}

/// Element pass, one thread per tetrahedron; MODE says where the corner forces go (Scatter).
/// DIAG: also sums the elastic energy (the window's last sub-step).
template <ElementKind K, bool DIAG, Scatter MODE>
__global__ void __launch_bounds__(kBlock)
    tet_pass_kernel(TetParams tp, const double* __restrict__ u64, float4* force,
                    unsigned long long* fixed, float4* __restrict__ tet_force, int substep,
                    DeviceStatus* st, bool record_health) {
  wait_for_previous_kernel();
  allow_next_kernel();
  if (halted(st, substep)) return;
  const int t = blockIdx.x * kBlock + threadIdx.x;
  const bool active = t < tp.tet_count;
  float energy = 0;
  Vec3f f[4] = {{0, 0, 0}, {0, 0, 0}, {0, 0, 0}, {0, 0, 0}};
  int v[4] = {-1, -2, -3, -4};  // distinct keys for inactive lanes: they join no run
  if (active) {
    const int4 id = tp.vertices[t];
    energy = eval_device_tet<K>(tp, t, id, u64, f, st, record_health);
    v[0] = id.x;
    v[1] = id.y;
    v[2] = id.z;
    v[3] = id.w;
  }
  if constexpr (MODE == Scatter::kStore) {
    if (active) {
      float4* out = tet_force + 4 * static_cast<size_t>(t);
      for (int c = 0; c < 4; ++c) out[c] = make_float4(f[c].x, f[c].y, f[c].z, 0.0f);
    }
  } else if constexpr (MODE == Scatter::kFloatAtomic) {
    if (active)
      for (int c = 0; c < 4; ++c) {
        const float fc[3] = {f[c].x, f[c].y, f[c].z};
        add_force(force, v[c], fc);
      }
  } else if constexpr (MODE == Scatter::kFloatWarp) {
    for (int c = 0; c < 4; ++c) {
      float fc[3] = {f[c].x, f[c].y, f[c].z};
      // Corners 2 and 3 rarely repeat between neighbours: the shuffles would not pay.
      const bool lead = c < 2 ? warp_run_sum(v[c], fc) : true;
      if (active && lead) add_force(force, v[c], fc);
    }
  } else {
    static_assert(MODE == Scatter::kFixedWarp);
    // Integer sums do not depend on their order: the result is the same bits every run.
    bool finite = true;
    for (int c = 0; c < 4; ++c) {
      const float fc[3] = {f[c].x, f[c].y, f[c].z};
      unsigned long long q[3];
      for (int i = 0; i < 3; ++i) {
        finite = finite && fabsf(fc[i]) < kFixedLimit;  // false for NaN too
        q[i] = static_cast<unsigned long long>(__double2ll_rn(double(fc[i]) * kFixedScale));
      }
      const bool lead = c < 2 ? warp_run_sum(v[c], q) : true;
      if (active && lead) add_fixed(fixed, v[c], q);
    }
    if (active && !finite) flag_nonfinite(st, substep, tp.vertex_new_to_old[v[0]]);
  }
  if constexpr (DIAG)
    block_sum_add(static_cast<double>(energy) * tp.energy_unit, &st->elastic_energy);
}

/// Per-vertex sums a window's last sub-step reports (SI units).
struct VertexDiag {
  double kinetic = 0, work = 0, residual_sq = 0, reference_sq = 0;
};

/// The centred-difference update of device vertex v with elastic force f [force_unit]:
/// u+ = u + b (u - u-) + c (f + f_ext) for free vertices, 0 for fixed, untouched for
/// prescribed ones (their block writes them). Non-finite results raise the flag.
__device__ __forceinline__ void update_vertex(const VertexParams& vp, int v, float4 f, float4 fe,
                                              int substep, DeviceStatus* st, VertexDiag* d) {
  const float2 bc = vp.update[v];
  const double fu2 = vp.force_unit * vp.force_unit;
  if (bc.y == kPrescribedMarker) {
    d->reference_sq += fu2 * (double(f.x) * f.x + double(f.y) * f.y + double(f.z) * f.z +
                              double(fe.x) * fe.x + double(fe.y) * fe.y + double(fe.z) * fe.z);
    return;
  }
  const double* u = vp.u + 3 * static_cast<size_t>(v);
  const double* up = vp.u_prev + 3 * static_cast<size_t>(v);
  double next[3];
  if (bc.y == kFixedMarker) {
    next[0] = next[1] = next[2] = 0;
    d->reference_sq += fu2 * (double(f.x) * f.x + double(f.y) * f.y + double(f.z) * f.z);
  } else {
    const float ft[3] = {f.x + fe.x, f.y + fe.y, f.z + fe.z};
    const float fext[3] = {fe.x, fe.y, fe.z};
    for (int i = 0; i < 3; ++i) {
      const double un = u[i], upi = up[i];
      // The increment carries the rounding, not the position (DeviceVertexUpdate).
      next[i] = un + double(bc.x) * (un - upi) + double(bc.y) * double(ft[i]);
      const double du = next[i] - upi;  // 2 dt v_n [length_unit]
      const double vel = du * vp.length_unit * vp.half_inv_dt;
      d->kinetic += 0.5 * vp.mass[v] * vel * vel;
      d->work += 0.5 * double(fext[i]) * vp.force_unit * du * vp.length_unit;
      d->residual_sq += fu2 * double(ft[i]) * double(ft[i]);
    }
  }
  d->reference_sq += fu2 * (double(fe.x) * fe.x + double(fe.y) * fe.y + double(fe.z) * fe.z);
  double* out = vp.u_next + 3 * static_cast<size_t>(v);
  out[0] = next[0];
  out[1] = next[1];
  out[2] = next[2];
  if (!isfinite(next[0] + next[1] + next[2]))
    flag_nonfinite(st, substep, static_cast<long long>(vp.vertex_new_to_old[v]));
}

/// update_vertex with the loads of vp.external (none when it is null).
__device__ __forceinline__ void update_vertex(const VertexParams& vp, int v, float4 f, int substep,
                                              DeviceStatus* st, VertexDiag* d) {
  update_vertex(vp, v, f, vp.external ? vp.external[v] : make_float4(0, 0, 0, 0), substep, st, d);
}

/// Sums the per-vertex diagnostics of a block into the status: the loads' work on every
/// sub-step that has loads, the rest on the window's last sub-step.
template <bool DIAG>
__device__ __forceinline__ void reduce_vertex_diag(const VertexParams& vp, const VertexDiag& d,
                                                   DeviceStatus* st) {
  if (vp.external) block_sum_add(d.work, &st->input_work);
  if constexpr (DIAG) {
    block_sum_add(d.kinetic, &st->kinetic_energy);
    block_sum_add(d.residual_sq, &st->residual_sq);
    block_sum_add(d.reference_sq, &st->reference_sq);
  }
}

/// The elastic force of device vertex v after a scatter: the float accumulator, or the fixed
/// point one converted.
template <bool FIXED>
__device__ __forceinline__ float4 scattered_force(const VertexParams& vp, int v) {
  if constexpr (FIXED) {
    const unsigned long long* q = vp.fixed + 3 * static_cast<size_t>(v);
    return make_float4(float(double(static_cast<long long>(q[0])) * kFixedInverse),
                       float(double(static_cast<long long>(q[1])) * kFixedInverse),
                       float(double(static_cast<long long>(q[2])) * kFixedInverse), 0.0f);
  } else {
    return vp.force[v];
  }
}

/// Prescribed vertices, run by one block: each moves to start + (substep + 1) delta; the force
/// the constraint applies, M a + gamma v - f_el - f_ext, is summed over the set in a fixed
/// order (CUB block reduction: deterministic) into the status.
template <bool DIAG, bool FIXED>
__device__ void prescribed_block(const PrescribedParams& pp, const VertexParams& vp, int substep,
                                 DeviceStatus* st) {
  double r[3] = {0, 0, 0};
  double kinetic = 0, work = 0;
  const double lu = vp.length_unit, fu = vp.force_unit;
  for (int k = threadIdx.x; k < pp.count; k += kBlock) {
    const int v = pp.vertices[k];
    const double* u = vp.u + 3 * static_cast<size_t>(v);
    const double* up = vp.u_prev + 3 * static_cast<size_t>(v);
    double* out = vp.u_next + 3 * static_cast<size_t>(v);
    const float4 f = scattered_force<FIXED>(vp, v);
    const float4 fe = vp.external ? vp.external[v] : make_float4(0, 0, 0, 0);
    const double fel[3] = {f.x, f.y, f.z}, fext[3] = {fe.x, fe.y, fe.z};
    for (int i = 0; i < 3; ++i) {
      const double next = pp.start[3 * k + i] + double(substep + 1) * pp.delta[3 * k + i];
      out[i] = next;
      const double du = (next - up[i]) * lu;
      const double vel = du * vp.half_inv_dt;
      const double acc = (next - 2.0 * u[i] + up[i]) * lu * pp.inv_dt2;
      const double ri = pp.mass[k] * acc + pp.damping[k] * vel - fel[i] * fu - fext[i] * fu;
      r[i] += ri;
      kinetic += 0.5 * pp.mass[k] * vel * vel;
      work += 0.5 * (ri + fext[i] * fu) * du;
    }
  }
  using Reduce = cub::BlockReduce<double, kBlock>;
  __shared__ typename Reduce::TempStorage temp;
  double sums[5];
  const double in[5] = {r[0], r[1], r[2], kinetic, work};
  for (int i = 0; i < 5; ++i) {
    sums[i] = Reduce(temp).Sum(in[i]);
    __syncthreads();
  }
  if (threadIdx.x == 0) {
    for (int i = 0; i < 3; ++i) st->constraint_force[i] = sums[i];
    // Atomics: the update blocks of the same kernel add to these concurrently.
    atomicAdd(&st->input_work, sums[4]);
    if (DIAG) {
      atomicAdd(&st->kinetic_energy, sums[3]);
      atomicAdd(&st->reference_sq, sums[0] * sums[0] + sums[1] * sums[1] + sums[2] * sums[2]);
    }
  }
}

/// Update after a scatter pass: reads this sub-step's accumulated force (FIXED: the fixed
/// point sums, converted and written to `force` for downloads), clears the next sub-step's
/// accumulator, updates. The last block, when there are prescribed vertices, does their work
/// instead (it reads only this sub-step's finished forces and writes only their u+).
template <bool DIAG, bool FIXED>
__global__ void __launch_bounds__(kBlock)
    update_kernel(VertexParams vp, PrescribedParams pp, int substep, DeviceStatus* st) {
  wait_for_previous_kernel();
  allow_next_kernel();
  if (halted(st, substep)) return;
  if (pp.count > 0 && blockIdx.x == gridDim.x - 1) {
    prescribed_block<DIAG, FIXED>(pp, vp, substep, st);
    return;
  }
  const int v = blockIdx.x * kBlock + threadIdx.x;
  VertexDiag d;
  if (v < vp.vertex_count) {
    const float4 f = scattered_force<FIXED>(vp, v);
    if constexpr (FIXED) {
      vp.force[v] = f;
      unsigned long long* clear = vp.fixed_clear + 3 * static_cast<size_t>(v);
      clear[0] = clear[1] = clear[2] = 0;
    } else {
      vp.force_clear[v] = make_float4(0, 0, 0, 0);
    }
    clear_nodal(vp, v);
    update_vertex(vp, v, f, substep, st, &d);
  }
  reduce_vertex_diag<DIAG>(vp, d, st);
}

/// Deterministic gather, one thread per vertex: the corner forces of the tetrahedra around v in
/// ascending tet order, either recomputed (RECOMPUTE, element kind K) or read from tet_force;
/// the sum is written to force[v] and, when `update`, fed to the centred-difference update.
template <ElementKind K, bool RECOMPUTE, bool DIAG>
__global__ void __launch_bounds__(kBlock)
    gather_kernel(TetParams tp, VertexParams vp, int substep, DeviceStatus* st, bool update) {
  wait_for_previous_kernel();
  allow_next_kernel();
  if (halted(st, substep)) return;
  const int v = blockIdx.x * kBlock + threadIdx.x;
  VertexDiag d;
  float energy = 0;
  if (v < vp.vertex_count) {
    float fx = 0, fy = 0, fz = 0;
    const int end = vp.gather_offsets[v + 1];
    for (int i = vp.gather_offsets[v]; i < end; ++i) {
      const int entry = vp.gather_entries[i];
      if constexpr (RECOMPUTE) {
        const int t = entry >> 2, corner = entry & 3;
        Vec3f f[4];
        // Each tetrahedron is evaluated by its four corners' threads: its energy and health are
        // counted by the thread of corner 0 only.
        const float e = eval_device_tet<K>(tp, t, tp.vertices[t], vp.u, f, st, corner == 0);
        if (corner == 0) energy += e;
        // Selects, not f[corner]: a run-time index would put f in local memory.
        const Vec3f fc = corner == 0 ? f[0] : (corner == 1 ? f[1] : (corner == 2 ? f[2] : f[3]));
        fx += fc.x;
        fy += fc.y;
        fz += fc.z;
      } else {
        const float4 fc = vp.tet_force[entry];
        fx += fc.x;
        fy += fc.y;
        fz += fc.z;
      }
    }
    const float4 f = make_float4(fx, fy, fz, 0.0f);
    vp.force[v] = f;
    if (update) update_vertex(vp, v, f, substep, st, &d);
  }
  if constexpr (DIAG && RECOMPUTE)
    block_sum_add(static_cast<double>(energy) * tp.energy_unit, &st->elastic_energy);
  if (update) reduce_vertex_diag<DIAG>(vp, d, st);
}

/// Prescribed vertices after a gather (which has written every vertex's force).
template <bool DIAG>
__global__ void __launch_bounds__(kBlock)
    prescribed_kernel(PrescribedParams pp, VertexParams vp, int substep, DeviceStatus* st) {
  wait_for_previous_kernel();
  allow_next_kernel();
  // A non-finite update in this very sub-step also stops it: that step is not taken.
  if (halted(st, substep + 1)) return;
  prescribed_block<DIAG, false>(pp, vp, substep, st);
}

/// Builds the stored tensors of every tetrahedron on the device (svk_mass_tensors or
/// linear_mass_tensor: the CPU precompute's functions), tet-major, `stride` floats each.
static __global__ void __launch_bounds__(kBlock)
    build_tensors_kernel(TetParams tp, bool svk, float* tensors, int stride) {
  const int t = blockIdx.x * kBlock + threadIdx.x;
  if (t >= tp.tet_count) return;
  float lambda, mu;
  const TetShape<float> s = load_shape(tp, t, &lambda, &mu);
  float* out = tensors + static_cast<size_t>(t) * static_cast<size_t>(stride);
  if (svk)
    svk_mass_tensors(s, lambda, mu, out);
  else
    linear_mass_tensor(s, lambda, mu, out);
}

/// Per-vertex |u| [m] and kinetic energy [J] (v = (u - u-) / dt) for the on-demand reductions.
static __global__ void __launch_bounds__(kBlock)
    summary_terms_kernel(VertexParams vp, double inv_dt, double* norm_u, double* kinetic) {
  const int v = blockIdx.x * kBlock + threadIdx.x;
  if (v >= vp.vertex_count) return;
  const double* u = vp.u + 3 * static_cast<size_t>(v);
  const double* up = vp.u_prev + 3 * static_cast<size_t>(v);
  double n2 = 0, v2 = 0;
  for (int i = 0; i < 3; ++i) {
    n2 += u[i] * u[i];
    const double vel = (u[i] - up[i]) * vp.length_unit * inv_dt;
    v2 += vel * vel;
  }
  norm_u[v] = sqrt(n2) * vp.length_unit;
  kinetic[v] = 0.5 * vp.mass[v] * v2;
}

}  // namespace zona::cuda
