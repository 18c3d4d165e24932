// The CUDA backend's class and the launch helpers shared by its translation units:
// cuda_backend.cu (upload, the sub-step graphs, downloads) and cuda_job.cu (the device-resident
// injection step). Included by those two files only.
#pragma once

#include <cuda_runtime.h>

#include <algorithm>
#include <cmath>
#include <memory>
#include <type_traits>

#include "kernels/cuda_backend.h"
#include "kernels/cuda_check.h"
#include "kernels/device_buffer.h"
#include "kernels/device_layout.h"
#include "kernels/step_kernels.cuh"

namespace zona::cuda {

class CudaJob;

// Calls f(std::integral_constant<ElementKind, K>) for the run-time kind k: one switch here,
// compile-time kinds in the kernels.
template <class F>
inline void with_kind(ElementKind k, F&& f) {
  using EK = ElementKind;
  switch (k) {
    case EK::kSvkGradient:
      f(std::integral_constant<EK, EK::kSvkGradient>{});
      break;
    case EK::kSvkGradientClamped:
      f(std::integral_constant<EK, EK::kSvkGradientClamped>{});
      break;
    case EK::kLinearGradient:
      f(std::integral_constant<EK, EK::kLinearGradient>{});
      break;
    case EK::kSvkRebuilt:
      f(std::integral_constant<EK, EK::kSvkRebuilt>{});
      break;
    case EK::kLinearRebuilt:
      f(std::integral_constant<EK, EK::kLinearRebuilt>{});
      break;
    case EK::kSvkStored:
      f(std::integral_constant<EK, EK::kSvkStored>{});
      break;
    case EK::kLinearStored:
      f(std::integral_constant<EK, EK::kLinearStored>{});
      break;
    case EK::kSnhGradient:
      f(std::integral_constant<EK, EK::kSnhGradient>{});
      break;
  }
}

// Calls f(std::bool_constant<b>) for the run-time b.
template <class F>
inline void with_bool(bool b, F&& f) {
  if (b)
    f(std::true_type{});
  else
    f(std::false_type{});
}

// The element kind for a model evaluated in `formulation`. Stable neo-Hookean has the gradient
// form only: upload refuses it with a tensor formulation before asking here.
inline ElementKind choose_kind(const Model& model, Formulation formulation) {
  if (model.constitutive == ConstitutiveModel::kStableNeoHookean) return ElementKind::kSnhGradient;
  const bool svk = model.constitutive == ConstitutiveModel::kSvk;
  switch (formulation) {
    case Formulation::kGradient:
      if (!svk) return ElementKind::kLinearGradient;
      return model.inversion == InversionHandling::kClampStretch ? ElementKind::kSvkGradientClamped
                                                                 : ElementKind::kSvkGradient;
    case Formulation::kTensorRebuilt:
      return svk ? ElementKind::kSvkRebuilt : ElementKind::kLinearRebuilt;
    case Formulation::kTensorStored:
      return svk ? ElementKind::kSvkStored : ElementKind::kLinearStored;
  }
  return ElementKind::kSvkGradient;
}

inline const char* kind_name(ElementKind k) {
  switch (k) {
    case ElementKind::kSvkGradient:
      return "svk/gradient";
    case ElementKind::kSvkGradientClamped:
      return "svk/gradient+clamp";
    case ElementKind::kLinearGradient:
      return "linear/gradient";
    case ElementKind::kSvkRebuilt:
      return "svk/tensor_rebuilt";
    case ElementKind::kLinearRebuilt:
      return "linear/tensor_rebuilt";
    case ElementKind::kSvkStored:
      return "svk/tensor_stored";
    case ElementKind::kLinearStored:
      return "linear/tensor_stored";
    case ElementKind::kSnhGradient:
      return "neohookean/gradient";
  }
  return "?";
}

inline unsigned blocks_for(size_t n) {
  return static_cast<unsigned>((n + kBlock - 1) / kBlock);
}

class CudaBackend final : public Backend {
 public:
  CudaBackend(const BackendOptions& options, std::string device_name)
      : options_(options), device_name_(std::move(device_name)) {}
  ~CudaBackend() override;  // cuda_job.cu

  const char* name() const override { return "cuda"; }

  std::string description() const override {
    return "cuda: " + device_name_ + ", " + kind_name(kind_) + ", " +
           assembly_name(options_.assembly) + (options_.reorder ? ", reordered" : "") +
           ", float32 forces / float64 displacements" +
           (options_.warp_aggregate ? ", warp-aggregated atomics" : "") +
           (options_.programmatic_launch ? ", programmatic launch" : "");
  }

  Status upload(const Model& model, const State& state) override;
  Status set_prescribed_targets(std::span<const Vec3d> targets) override;
  Status set_external_forces(std::span<const Vec3d> forces) override;
  StepReport step(int substeps) override;
  Status download(State& state) override;
  Status elastic_forces(std::span<const Vec3d> u, std::span<Vec3d> f) override;
  /// Zeroes the nodal pressure's sums (either form) on stream s.
  Status clear_nodal_sums(cudaStream_t s);
  Result<StateSummary> summarize() override;
  Result<JobRunner*> start_job(const JobSetup& setup) override;  // cuda_job.cu

  DeviceStateView device_state() const override {
    DeviceStateView view;
    if (!model_) return view;
    view.u = d_u_[phase_step_ % 3].data();
    view.length_unit = length_unit_;
    view.vertex_old_to_new = old_to_new_;
    view.stream = stream_.get();
    view.device = options_.device;
    return view;
  }

 private:
  friend class CudaJob;
  struct CachedGraph {
    int substeps = 0;
    int phase = 0;
    GraphExec exec;
  };

  VertexParams vertex_params(int64_t g);
  Status enqueue_substep(int64_t g, int substep, bool diag, DeviceStatus* st);
  Result<cudaGraphExec_t> window_graph(int substeps, int phase);
  Status to_device_order(std::span<const Vec3d> in, double scale, std::vector<double>& out) const;

  BackendOptions options_;
  std::string device_name_;
  const Model* model_ = nullptr;
  ElementKind kind_ = ElementKind::kSvkGradient;
  std::vector<int32_t> new_to_old_, old_to_new_;  // vertex permutations
  std::vector<int32_t> tet_new_to_old_;           // model tet of each device tet
  double length_unit_ = 1, force_unit_ = 1;
  size_t nv_ = 0, nt_ = 0;

  Stream stream_;
  Event ev_start_, ev_stop_;
  TetParams tp_;
  DeviceBuffer<int4> d_tet_vertices_;
  DeviceBuffer<float4> d_shape_a_, d_shape_b_;
  DeviceBuffer<float2> d_shape_c_;
  DeviceBuffer<float> d_tensors_;
  DeviceBuffer<float> d_vertex_q_;        ///< nodal pressure: TetParams::vertex_q
  DeviceBuffer<unsigned long long> d_vertex_q_fixed_;  ///< or TetParams::vertex_q_fixed
  DeviceBuffer<float2> d_vertex_nodal_;   ///< nodal pressure: TetParams::vertex_nodal
  DeviceBuffer<int32_t> d_tet_new_to_old_, d_vertex_new_to_old_;
  DeviceBuffer<double> d_u_[3];
  DeviceBuffer<float4> d_force_[2], d_tet_force_, d_external_;
  PinnedBuffer<float4> h_external_;  // staging of set_external_forces
  DeviceBuffer<unsigned long long> d_fixed_[2];  // fixed-point accumulators (3 per vertex)
  DeviceBuffer<float2> d_update_;
  DeviceBuffer<double> d_mass_;
  DeviceBuffer<int> d_gather_offsets_, d_gather_entries_;
  bool has_external_ = false;

  // Prescribed vertices: the window's start and per-sub-step increment travel through pinned
  // memory, copied by the graph's first node.
  int presc_count_ = 0;
  PrescribedParams pp_;
  DeviceBuffer<int32_t> d_presc_vertices_;
  DeviceBuffer<double> d_presc_window_, d_presc_mass_, d_presc_damping_;
  PinnedBuffer<double> h_presc_window_;              // start (3K) then delta (3K) [length_unit]
  std::vector<Vec3d> presc_current_, presc_target_;  // [m], (K)

  DeviceBuffer<DeviceStatus> d_status_, d_scratch_status_;
  PinnedBuffer<DeviceStatus> h_status_init_, h_status_out_;

  // Scratch for elastic_forces and summarize.
  DeviceBuffer<float4> d_scratch_force_;
  DeviceBuffer<unsigned long long> d_scratch_fixed_;
  DeviceBuffer<double> d_scratch_u64_;
  DeviceBuffer<double> d_reduce_a_, d_reduce_b_, d_reduce_out_;
  DeviceBuffer<unsigned char> d_cub_temp_;
  size_t cub_temp_bytes_ = 0;

  std::vector<CachedGraph> graphs_;
  int64_t phase_step_ = 0;  // sub-steps since upload: selects the buffer of each role
  double time_ = 0;
  int64_t step_count_ = 0;
  StepDiagnostics diag_;
  bool budget_valid_ = false;
  StepErrorLog step_log_;
  std::unique_ptr<JobRunner> job_;  // the device-resident injection step (a CudaJob), once started
};

// Launches a kernel of kBlock threads on `stream`, with programmatic dependent launch when
// `pdl` (the kernel then starts while the previous one finishes; it waits for it inside).
template <class... KernelArgs, class... Args>
inline cudaError_t launch(bool pdl, void (*kernel)(KernelArgs...), unsigned grid, cudaStream_t stream,
                   Args... args) {
  cudaLaunchConfig_t config = {};
  config.gridDim = dim3(grid);
  config.blockDim = dim3(kBlock);
  config.stream = stream;
  cudaLaunchAttribute attribute[1];
  attribute[0].id = cudaLaunchAttributeProgrammaticStreamSerialization;
  attribute[0].val.programmaticStreamSerializationAllowed = 1;
  config.attrs = attribute;
  config.numAttrs = pdl ? 1 : 0;
  return cudaLaunchKernelEx(&config, kernel, static_cast<KernelArgs>(args)...);
}

inline Scatter scatter_of(Assembly a, bool warp_aggregate) {
  switch (a) {
    case Assembly::kScatterAtomic:
      return warp_aggregate ? Scatter::kFloatWarp : Scatter::kFloatAtomic;
    case Assembly::kScatterFixed:
      return Scatter::kFixedWarp;
    case Assembly::kGatherStored:
      return Scatter::kStore;
    case Assembly::kGatherRecompute:
      break;
  }
  return Scatter::kStore;
}

// Calls f(std::integral_constant<Scatter, M>) for the run-time mode m.
template <class F>
inline void with_scatter(Scatter m, F&& f) {
  switch (m) {
    case Scatter::kFloatAtomic:
      f(std::integral_constant<Scatter, Scatter::kFloatAtomic>{});
      break;
    case Scatter::kFloatWarp:
      f(std::integral_constant<Scatter, Scatter::kFloatWarp>{});
      break;
    case Scatter::kFixedWarp:
      f(std::integral_constant<Scatter, Scatter::kFixedWarp>{});
      break;
    case Scatter::kStore:
      f(std::integral_constant<Scatter, Scatter::kStore>{});
      break;
  }
}

}  // namespace zona::cuda
