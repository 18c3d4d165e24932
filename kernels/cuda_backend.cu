// The CUDA backend: the whole step on the device. State stays in device memory; one step()
// call replays a captured CUDA graph of N sub-steps and brings back only a small status block
// (flags, needle force, energies) through pinned memory. Buffers rotate instead of being
// copied: u over three arrays (a failed sub-step leaves u_n and u_{n-1} intact), the float32
// copy of u and the force accumulator over two, so a graph depends on the step index mod 6.
#include <cuda_runtime.h>

#include <algorithm>
#include <cmath>
#include <cub/device/device_reduce.cuh>
#include <type_traits>

#include "kernels/cuda_backend_impl.cuh"

namespace zona {
namespace cuda {

// Device order and length units from model order and SI: out[3 i + c] = in[old(i)][c] / scale.
Status CudaBackend::to_device_order(std::span<const Vec3d> in, double scale,
                                    std::vector<double>& out) const {
  if (in.size() != nv_)
    return make_error("cuda backend: %zu vertices given, the model has %zu", in.size(), nv_);
  out.resize(3 * nv_);
  for (size_t i = 0; i < nv_; ++i) {
    const Vec3d p = in[static_cast<size_t>(new_to_old_[i])];
    for (int c = 0; c < 3; ++c) out[3 * i + c] = p[c] / scale;
  }
  return {};
}

Status CudaBackend::upload(const Model& model, const State& state) {
  if (state.u.size() != model.vertex_count() || state.u_prev.size() != model.vertex_count())
    return make_error("cuda backend: the state has %zu vertices, the model %zu", state.u.size(),
                      model.vertex_count());
  ZONA_CUDA_TRY(cudaSetDevice(options_.device));
  model_ = &model;
  graphs_.clear();
  const Formulation form = options_.formulation >= 0
                               ? static_cast<Formulation>(options_.formulation)
                               : model.formulation;
  if (model.constitutive == ConstitutiveModel::kStableNeoHookean && form != Formulation::kGradient)
    return make_error(
        "cuda backend: the neohookean model has no mass-tensor form: use the "
        "gradient formulation");
  if (model.nodal_pressure && options_.assembly != Assembly::kScatterAtomic &&
      options_.assembly != Assembly::kScatterFixed)
    return make_error(
        "cuda backend: nodal pressure (\"volumetric\": \"nodal\") needs a scatter assembly "
        "(atomic or fixed)");
  kind_ = choose_kind(model, form);

  Result<DeviceLayout> built = build_device_layout(model, DeviceLayoutOptions{options_.reorder, 0});
  if (!built) return built.error();
  const DeviceLayout& L = *built;
  nv_ = L.vertex_count();
  nt_ = L.tet_count();
  new_to_old_ = L.vertex_new_to_old;
  old_to_new_ = L.vertex_old_to_new;
  tet_new_to_old_ = L.tet_new_to_old;
  length_unit_ = L.length_unit;
  force_unit_ = L.force_unit;

  if (!stream_.get()) {
    if (Status s = stream_.create(); !s) return s;
    if (Status s = ev_start_.create(true); !s) return s;
    if (Status s = ev_stop_.create(true); !s) return s;
  }

  // Tetrahedra.
  if (Status s = d_tet_vertices_.upload_raw(L.tet_vertices.data(), nt_, "tet vertices"); !s)
    return s;
  if (Status s = d_shape_a_.upload_raw(L.tet_shape_a.data(), nt_, "tet shapes"); !s) return s;
  if (Status s = d_shape_b_.upload_raw(L.tet_shape_b.data(), nt_, "tet shapes"); !s) return s;
  if (Status s = d_shape_c_.upload_raw(L.tet_shape_c.data(), nt_, "tet shapes"); !s) return s;
  if (Status s = d_tet_new_to_old_.upload(L.tet_new_to_old, "tet numbering"); !s) return s;
  if (Status s = d_vertex_new_to_old_.upload(L.vertex_new_to_old, "vertex numbering"); !s) return s;
  tp_ = TetParams{};
  tp_.vertices = d_tet_vertices_.data();
  tp_.shape_a = d_shape_a_.data();
  tp_.shape_b = d_shape_b_.data();
  tp_.shape_c = d_shape_c_.data();
  tp_.tet_new_to_old = d_tet_new_to_old_.data();
  tp_.vertex_new_to_old = d_vertex_new_to_old_.data();
  tp_.tet_count = static_cast<int>(nt_);
  tp_.material_count = static_cast<int>(L.material_count());
  for (size_t k = 0; k <= L.material_count(); ++k) tp_.material_begin[k] = L.material_tet_begin[k];
  for (size_t k = 0; k < L.material_count(); ++k) {
    tp_.lambda[k] = L.material_lame[k][0];
    tp_.mu[k] = L.material_lame[k][1];
  }
  tp_.nodal_stabilisation = static_cast<float>(model.nodal_stabilisation);
  tp_.clamp_stretch = static_cast<float>(model.clamp_stretch);
  tp_.clamp_at_collapse = model.clamp_stretch == kSvkCollapseStretch;
  tp_.energy_unit = L.force_unit * L.length_unit;

  // Stored tensors: built on the device from the packed shapes by the CPU precompute's own
  // functions (svk_mass_tensors / linear_mass_tensor), in float32 and scaled units.
  d_tensors_ = DeviceBuffer<float>{};
  if (element_kind_stored(kind_)) {
    const int stride = element_kind_tensor_size(kind_);
    const size_t bytes = nt_ * static_cast<size_t>(stride) * sizeof(float);
    size_t free_bytes = 0, total_bytes = 0;
    ZONA_CUDA_TRY(cudaMemGetInfo(&free_bytes, &total_bytes));
    if (bytes + (size_t{1} << 30) > free_bytes)
      return make_error(
          "cuda backend: stored tensors need %.2f GB (%d floats per tetrahedron x "
          "%zu), the device has %.2f GB free: use the gradient or rebuilt form",
          static_cast<double>(bytes) * 1e-9, stride, nt_, static_cast<double>(free_bytes) * 1e-9);
    if (Status s = d_tensors_.allocate(nt_ * static_cast<size_t>(stride), "stored tensors"); !s)
      return s;
    tp_.tensors = d_tensors_.data();
    tp_.tensor_stride = stride;
    build_tensors_kernel<<<blocks_for(nt_), kBlock, 0, stream_.get()>>>(
        tp_, kind_ == ElementKind::kSvkStored, d_tensors_.data(), stride);
    ZONA_CUDA_TRY_LAUNCH();
  }

  // Nodal pressure: per device vertex (lambda_v, 1 / V_v) in device units, and the sums of the
  // step's first pass, zero between steps.
  d_vertex_q_ = DeviceBuffer<float>{};
  d_vertex_q_fixed_ = DeviceBuffer<unsigned long long>{};
  tp_.vertex_q = nullptr;
  tp_.vertex_q_fixed = nullptr;
  d_vertex_nodal_ = DeviceBuffer<float2>{};
  if (model.nodal_pressure) {
    const double volume_unit = L.length_unit * L.length_unit * L.length_unit;
    std::vector<float2> nodal(nv_);
    for (size_t i = 0; i < nv_; ++i) {
      const size_t v = static_cast<size_t>(new_to_old_[i]);
      nodal[i] = make_float2(static_cast<float>(model.vertex_lambda[v] / L.stress_unit),
                             static_cast<float>(model.vertex_inverse_volume[v] * volume_unit));
    }
    if (Status s = d_vertex_nodal_.upload(nodal, "nodal pressure coefficients"); !s) return s;
    if (options_.assembly == Assembly::kScatterFixed) {
      // Fixed point like the forces: the sums, and so the run, independent of atomic order.
      if (Status s = d_vertex_q_fixed_.allocate(nv_, "nodal volume changes"); !s) return s;
      if (Status s = d_vertex_q_fixed_.fill_bytes(0); !s) return s;
      tp_.vertex_q_fixed = d_vertex_q_fixed_.data();
    } else {
      if (Status s = d_vertex_q_.allocate(nv_, "nodal volume changes"); !s) return s;
      if (Status s = d_vertex_q_.fill_bytes(0); !s) return s;
      tp_.vertex_q = d_vertex_q_.data();
    }
    tp_.vertex_nodal = d_vertex_nodal_.data();
  }

  // Vertices: update coefficients, masses, gather lists, numbering.
  if (Status s = d_update_.upload_raw(L.vertex_update.data(), nv_, "vertex coefficients"); !s)
    return s;
  if (Status s = d_mass_.upload(L.vertex_mass, "vertex masses"); !s) return s;
  if (Status s = d_gather_offsets_.upload(L.gather_offsets, "gather offsets"); !s) return s;
  if (Status s = d_gather_entries_.upload(L.gather_entries, "gather lists"); !s) return s;

  // State: u_n in u[0], u_{n-1} in u[2]; force[0] accumulates the first sub-step, force[1]
  // holds the uploaded force (what download returns before any step). The other buffers are
  // written before they are read.
  std::vector<double> host;
  for (auto& b : d_u_)
    if (Status s = b.allocate(3 * nv_, "displacements"); !s) return s;
  for (auto& b : d_force_)
    if (Status s = b.allocate(nv_, "forces"); !s) return s;
  for (auto& b : d_fixed_) {
    const size_t n = options_.assembly == Assembly::kScatterFixed ? 3 * nv_ : 0;
    if (Status s = b.allocate(n, "fixed-point forces"); !s) return s;
    if (Status s = b.fill_bytes(0); !s) return s;
  }
  if (options_.poison_outputs)
    for (auto& b : d_u_)
      if (Status s = b.fill_bytes(0xFF); !s) return s;
  if (Status s = to_device_order(state.u, length_unit_, host); !s) return s;
  ZONA_CUDA_TRY(cudaMemcpy(d_u_[0].data(), host.data(), d_u_[0].bytes(), cudaMemcpyHostToDevice));
  if (Status s = to_device_order(state.u_prev, length_unit_, host); !s) return s;
  ZONA_CUDA_TRY(cudaMemcpy(d_u_[2].data(), host.data(), d_u_[2].bytes(), cudaMemcpyHostToDevice));
  if (Status s = d_force_[0].fill_bytes(0); !s) return s;
  {
    std::vector<float4> f(nv_, make_float4(0, 0, 0, 0));
    if (state.force.size() == nv_)
      for (size_t i = 0; i < nv_; ++i) {
        const Vec3d p = state.force[static_cast<size_t>(new_to_old_[i])] / force_unit_;
        f[i] = make_float4(float(p.x), float(p.y), float(p.z), 0.0f);
      }
    ZONA_CUDA_TRY(
        cudaMemcpy(d_force_[1].data(), f.data(), d_force_[1].bytes(), cudaMemcpyHostToDevice));
  }
  if (options_.assembly == Assembly::kGatherStored) {
    if (Status s = d_tet_force_.allocate(4 * nt_, "corner forces"); !s) return s;
    if (options_.poison_outputs)
      if (Status s = d_tet_force_.fill_bytes(0xFF); !s) return s;
  }

  // Loads: a dense array only when some vertex has one (otherwise no bytes per step).
  has_external_ = false;
  for (const Vec3d& f : state.external_force)
    if (f.x != 0 || f.y != 0 || f.z != 0) has_external_ = true;
  d_external_ = DeviceBuffer<float4>{};
  if (has_external_) {
    std::vector<float4> fe(nv_);
    for (size_t i = 0; i < nv_; ++i) {
      const Vec3d p = state.external_force[static_cast<size_t>(new_to_old_[i])] / force_unit_;
      fe[i] = make_float4(float(p.x), float(p.y), float(p.z), 0.0f);
    }
    if (Status s = d_external_.upload_raw(fe.data(), nv_, "loads"); !s) return s;
  }

  // Prescribed vertices: marked in the coefficients so the update leaves them to their kernel.
  presc_count_ = static_cast<int>(state.prescribed_vertices.size());
  pp_ = PrescribedParams{};
  pp_.count = presc_count_;
  pp_.inv_dt2 = 1.0 / (model.dt * model.dt);
  presc_current_.assign(state.prescribed_displacement.begin(), state.prescribed_displacement.end());
  presc_target_ = presc_current_;
  if (presc_count_ > 0) {
    if (presc_current_.size() != static_cast<size_t>(presc_count_))
      return make_error("cuda backend: %d prescribed vertices but %zu targets", presc_count_,
                        presc_current_.size());
    std::vector<int32_t> vertices(static_cast<size_t>(presc_count_));
    std::vector<double> mass(vertices.size()), damping(vertices.size());
    std::vector<DeviceVertexUpdate> update = L.vertex_update;
    for (size_t k = 0; k < vertices.size(); ++k) {
      const int32_t v = state.prescribed_vertices[k];
      if (v < 0 || static_cast<size_t>(v) >= nv_)
        return make_error("cuda backend: prescribed vertex %d out of range", v);
      vertices[k] = old_to_new_[static_cast<size_t>(v)];
      mass[k] = model.vertex_mass[static_cast<size_t>(v)];
      damping[k] = model.vertex_damping[static_cast<size_t>(v)];
      update[static_cast<size_t>(vertices[k])].c = kPrescribedMarker;
    }
    if (Status s = d_update_.upload_raw(update.data(), nv_, "vertex coefficients"); !s) return s;
    if (Status s = d_presc_vertices_.upload(vertices, "prescribed vertices"); !s) return s;
    if (Status s = d_presc_mass_.upload(mass, "prescribed masses"); !s) return s;
    if (Status s = d_presc_damping_.upload(damping, "prescribed damping"); !s) return s;
    if (Status s = d_presc_window_.allocate(6 * vertices.size(), "prescribed targets"); !s)
      return s;
    if (Status s = h_presc_window_.allocate(6 * vertices.size(), "prescribed targets"); !s)
      return s;
    pp_.vertices = d_presc_vertices_.data();
    pp_.start = d_presc_window_.data();
    pp_.delta = d_presc_window_.data() + 3 * vertices.size();
    pp_.mass = d_presc_mass_.data();
    pp_.damping = d_presc_damping_.data();
  }

  // Status blocks and scratch.
  if (Status s = d_status_.allocate(1, "status"); !s) return s;
  if (Status s = d_scratch_status_.allocate(1, "status"); !s) return s;
  if (Status s = h_status_init_.allocate(1, "status"); !s) return s;
  if (Status s = h_status_out_.allocate(1, "status"); !s) return s;
  h_status_init_[0] = DeviceStatus{};
  if (Status s = d_reduce_a_.allocate(nv_, "reduction terms"); !s) return s;
  if (Status s = d_reduce_b_.allocate(nv_, "reduction terms"); !s) return s;
  if (Status s = d_reduce_out_.allocate(2, "reduction results"); !s) return s;
  size_t max_bytes = 0, sum_bytes = 0;
  ZONA_CUDA_TRY(cub::DeviceReduce::Max(nullptr, max_bytes, d_reduce_a_.data(), d_reduce_out_.data(),
                                       static_cast<int>(nv_)));
  ZONA_CUDA_TRY(cub::DeviceReduce::Sum(nullptr, sum_bytes, d_reduce_b_.data(),
                                       d_reduce_out_.data() + 1, static_cast<int>(nv_)));
  cub_temp_bytes_ = std::max(max_bytes, sum_bytes);
  if (Status s = d_cub_temp_.allocate(cub_temp_bytes_, "reduction scratch"); !s) return s;

  phase_step_ = 0;
  time_ = state.time;
  step_count_ = state.step_count;
  diag_ = state.diag;
  budget_valid_ = state.energy_budget_valid;
  // Whole device: the synchronous copies above ran on the legacy stream from pageable memory
  // (cudaMemcpy may return before their DMA lands) and the step stream is non-blocking.
  ZONA_CUDA_TRY(cudaDeviceSynchronize());
  return {};
}

Status CudaBackend::set_prescribed_targets(std::span<const Vec3d> targets) {
  if (targets.size() != presc_target_.size())
    return make_error("cuda backend: %zu prescribed targets given for %zu prescribed vertices",
                      targets.size(), presc_target_.size());
  for (size_t k = 0; k < targets.size(); ++k) {
    if (!(std::isfinite(targets[k].x) && std::isfinite(targets[k].y) &&
          std::isfinite(targets[k].z)))
      return make_error("cuda backend: prescribed target %zu is not finite", k);
    presc_target_[k] = targets[k];
  }
  return {};
}

// The buffers of global sub-step g: u rotates over three arrays, its float copy and the force
// accumulator over two.
VertexParams CudaBackend::vertex_params(int64_t g) {
  VertexParams vp;
  vp.u = d_u_[g % 3].data();
  vp.u_prev = d_u_[(g + 2) % 3].data();
  vp.u_next = d_u_[(g + 1) % 3].data();
  vp.force = d_force_[g % 2].data();
  vp.force_clear = d_force_[(g + 1) % 2].data();
  vp.fixed = d_fixed_[g % 2].data();
  vp.fixed_clear = d_fixed_[(g + 1) % 2].data();
  vp.tet_force = d_tet_force_.data();
  vp.external = has_external_ ? d_external_.data() : nullptr;
  vp.update = d_update_.data();
  vp.mass = d_mass_.data();
  vp.gather_offsets = d_gather_offsets_.data();
  vp.gather_entries = d_gather_entries_.data();
  vp.vertex_new_to_old = d_vertex_new_to_old_.data();
  vp.nodal_clear = tp_.vertex_q;
  vp.nodal_clear_fixed = tp_.vertex_q_fixed;
  vp.vertex_count = static_cast<int>(nv_);
  vp.length_unit = length_unit_;
  vp.force_unit = force_unit_;
  vp.half_inv_dt = 0.5 / model_->dt;
  return vp;
}

// One sub-step's kernels on the stream (also used while capturing a graph):
//   scatter assemblies: element pass, then update (+ prescribed vertices in its last block);
//   gather_stored:      element pass (corner forces), gather + update, prescribed vertices;
//   gather_recompute:   gather (re-evaluating elements) + update, prescribed vertices.
Status CudaBackend::enqueue_substep(int64_t g, int substep, bool diag, DeviceStatus* st) {
  const VertexParams vp = vertex_params(g);
  const cudaStream_t s = stream_.get();
  const bool pdl = options_.programmatic_launch;
  const unsigned tb = blocks_for(nt_), vb = blocks_for(nv_);
  const Assembly a = options_.assembly;
  const bool scatter = a == Assembly::kScatterAtomic || a == Assembly::kScatterFixed;
  float4* tet_force = d_tet_force_.data();
  cudaError_t err = cudaSuccess;
  auto keep = [&err](cudaError_t e) {
    if (err == cudaSuccess) err = e;
  };
  with_kind(kind_, [&](auto kc) {
    with_bool(diag, [&](auto dc) {
      constexpr ElementKind K = decltype(kc)::value;
      constexpr bool D = decltype(dc)::value;
      if (has_nodal(tp_)) keep(launch(pdl, volume_change_kernel, tb, s, tp_, vp.u, substep, st));
      if (a != Assembly::kGatherRecompute)
        with_scatter(scatter_of(a, options_.warp_aggregate), [&](auto mc) {
          constexpr Scatter M = decltype(mc)::value;
          keep(launch(pdl, tet_pass_kernel<K, D, M>, tb, s, tp_, vp.u, vp.force, vp.fixed,
                      tet_force, substep, st, true));
        });
      if (scatter) {
        // The prescribed vertices ride in one extra block of the update.
        const unsigned grid = vb + (presc_count_ > 0 ? 1u : 0u);
        if (a == Assembly::kScatterFixed)
          keep(launch(pdl, update_kernel<D, true>, grid, s, vp, pp_, substep, st));
        else
          keep(launch(pdl, update_kernel<D, false>, grid, s, vp, pp_, substep, st));
        return;
      }
      if (a == Assembly::kGatherRecompute)
        keep(launch(pdl, gather_kernel<K, true, D>, vb, s, tp_, vp, substep, st, true));
      else
        keep(launch(pdl, gather_kernel<ElementKind::kSvkGradient, false, D>, vb, s, tp_, vp,
                    substep, st, true));
      if (presc_count_ > 0) keep(launch(pdl, prescribed_kernel<D>, 1, s, pp_, vp, substep, st));
    });
  });
  if (err != cudaSuccess)
    return cuda_error(err, "cudaLaunchKernelEx (sub-step)", __FILE__, __LINE__);
  ZONA_CUDA_TRY_LAUNCH();
  return {};
}

// The graph of a window of `substeps` sub-steps starting at buffer phase `phase` (mod 6):
// reset the status, copy the prescribed window in, the sub-steps, copy the status out.
// Captured on first use and cached; capturing allocates, replaying does not.
Result<cudaGraphExec_t> CudaBackend::window_graph(int substeps, int phase) {
  for (CachedGraph& c : graphs_)
    if (c.substeps == substeps && c.phase == phase) return c.exec.get();
  const cudaStream_t s = stream_.get();
  ZONA_CUDA_TRY(cudaStreamBeginCapture(s, cudaStreamCaptureModeThreadLocal));
  Status body = [&]() -> Status {
    ZONA_CUDA_TRY(cudaMemcpyAsync(d_status_.data(), h_status_init_.data(), sizeof(DeviceStatus),
                                  cudaMemcpyHostToDevice, s));
    if (presc_count_ > 0)
      ZONA_CUDA_TRY(cudaMemcpyAsync(d_presc_window_.data(), h_presc_window_.data(),
                                    h_presc_window_.bytes(), cudaMemcpyHostToDevice, s));
    for (int i = 0; i < substeps; ++i)
      if (Status st = enqueue_substep(phase + i, i, i == substeps - 1, d_status_.data()); !st)
        return st;
    ZONA_CUDA_TRY(cudaMemcpyAsync(h_status_out_.data(), d_status_.data(), sizeof(DeviceStatus),
                                  cudaMemcpyDeviceToHost, s));
    return {};
  }();
  cudaGraph_t graph = nullptr;
  const cudaError_t end = cudaStreamEndCapture(s, &graph);
  if (!body) {
    if (graph) (void)cudaGraphDestroy(graph);
    return body.error();
  }
  if (end != cudaSuccess) return cuda_error(end, "cudaStreamEndCapture", __FILE__, __LINE__);
  // Keep a handful: the step size rarely changes, the phase takes six values.
  if (graphs_.size() >= 12) graphs_.erase(graphs_.begin());
  graphs_.push_back(CachedGraph{substeps, phase, GraphExec{}});
  if (Status st = graphs_.back().exec.instantiate(graph); !st) {
    graphs_.pop_back();
    return st.error();
  }
  return graphs_.back().exec.get();
}

StepReport CudaBackend::step(int substeps) {
  StepReport report;
  if (!model_ || substeps < 1) return report;
  const Model& m = *model_;
  if (m.dt > m.dt_critical && !m.unsafe_allow_dt_above_critical) {
    report.status = kStepDtAboveCritical;
    return report;
  }
  // The window's prescribed motion: start + (i + 1) delta, as the CPU backend computes it.
  const double n = static_cast<double>(substeps);
  const size_t k_count = static_cast<size_t>(presc_count_);
  for (size_t k = 0; k < k_count; ++k) {
    const Vec3d start = presc_current_[k];
    const Vec3d delta = (presc_target_[k] - start) / n;
    for (int c = 0; c < 3; ++c) {
      h_presc_window_[3 * k + c] = start[c] / length_unit_;
      h_presc_window_[3 * k_count + 3 * k + c] = delta[c] / length_unit_;
    }
  }
  const int phase = static_cast<int>(phase_step_ % 6);
  Result<cudaGraphExec_t> graph = window_graph(substeps, phase);
  const cudaStream_t s = stream_.get();
  const bool launched = graph && ZONA_CUDA_STEP(step_log_, cudaEventRecord(ev_start_.get(), s)) &&
                        ZONA_CUDA_STEP(step_log_, cudaGraphLaunch(*graph, s)) &&
                        ZONA_CUDA_STEP(step_log_, cudaEventRecord(ev_stop_.get(), s)) &&
                        ZONA_CUDA_STEP(step_log_, cudaEventSynchronize(ev_stop_.get()));
  if (!launched) {
    if (!graph)
      std::snprintf(step_log_.message, sizeof step_log_.message, "%s",
                    graph.error().message.c_str());
    step_log_.failed = true;
    // A device failure is reported like a non-finite step: nothing was advanced that the host
    // can trust. The message stays in step_log_ (device_error()).
    report.status = kStepNonFinite;
    diag_.first_nonfinite = 0;
    return report;
  }
  report.device_ms = elapsed_ms(ev_start_, ev_stop_);

  const DeviceStatus st = h_status_out_[0];
  const int64_t steps = st.failed_substep == INT_MAX ? substeps : st.failed_substep;
  report.status = st.flags;
  report.steps = steps;
  for (size_t k = 0; k < k_count; ++k) {
    const Vec3d start = presc_current_[k];
    const Vec3d delta = (presc_target_[k] - start) / n;
    presc_current_[k] = start + static_cast<double>(steps) * delta;
  }
  phase_step_ += steps;
  step_count_ += steps;
  time_ += static_cast<double>(steps) * m.dt;
  if (steps != substeps) {
    // A halted window stops inside a sub-step: its scatter sums (forces, fixed-point forces,
    // the nodal pressure's volume changes) hold what that sub-step added and its update did not
    // take and zero. Zeroed here, the invariant the next window's first sub-step relies on
    // (ordered on the stream).
    const size_t g = static_cast<size_t>(phase_step_ % 2);
    auto clear = [&]() -> Status {
      if (Status a = d_force_[g].fill_bytes_async(0, s); !a) return a;
      if (Status b = d_fixed_[g].fill_bytes_async(0, s); !b) return b;
      return clear_nodal_sums(s);
    };
    if (Status z = clear(); !z) {
      std::snprintf(step_log_.message, sizeof step_log_.message, "%s",
                    z.error().message.c_str());
      step_log_.failed = true;
    }
  }

  StepDiagnostics& d = diag_;
  auto first = [](long long x) { return x == LLONG_MAX ? int64_t{-1} : int64_t{x}; };
  d.inverted_count = static_cast<int64_t>(st.inverted_count);
  d.collapsing_count = static_cast<int64_t>(st.collapsing_count);
  d.clamped_count = static_cast<int64_t>(st.clamped_count);
  d.first_inverted = first(st.first_inverted);
  d.first_collapsing = first(st.first_collapsing);
  d.first_nonfinite = first(st.first_nonfinite);
  d.element_health = 0;
  if (st.flags & kStepInvertedElement) d.element_health |= kElementInverted;
  if (st.flags & kStepCollapsingElement) d.element_health |= kElementCollapsing;
  if (st.flags & kStepClampedElement) d.element_health |= kElementClamped;
  if (steps == substeps) {
    // Energies and residuals are those of the window's last sub-step.
    d.elastic_energy = st.elastic_energy;
    d.kinetic_energy = st.kinetic_energy;
    d.residual_norm = std::sqrt(st.residual_sq);
    d.reference_force_norm = std::sqrt(st.reference_sq);
    d.constraint_force =
        Vec3d{st.constraint_force[0], st.constraint_force[1], st.constraint_force[2]};
    const double energy = d.elastic_energy + d.kinetic_energy;
    if (!std::isfinite(energy)) {
      report.status |= kStepNonFinite;
    } else {
      // The blow-up test runs once per window, on the last sub-step's energy; the work of
      // loads and prescribed vertices is summed over every sub-step.
      if (!budget_valid_) {
        d.energy_budget = energy;
        budget_valid_ = true;
      }
      d.energy_budget += st.input_work;
      if (energy > m.energy_blowup_factor * std::max(d.energy_budget, m.energy_floor))
        report.status |= kStepEnergyBlowUp;
    }
  }
  if (m.dt > m.dt_critical) report.status |= kStepDtAboveCritical;
  report.constraint_force = d.constraint_force;
  report.kinetic_energy = d.kinetic_energy;
  report.elastic_energy = d.elastic_energy;
  report.residual_norm = d.residual_norm;
  return report;
}

Status CudaBackend::set_external_forces(std::span<const Vec3d> forces) {
  if (!model_) return make_error("cuda backend: nothing uploaded");
  if (forces.size() != nv_)
    return make_error("cuda backend: %zu loads given for %zu vertices", forces.size(), nv_);
  if (!has_external_) {
    bool any = false;
    for (const Vec3d& f : forces) any = any || f.x != 0 || f.y != 0 || f.z != 0;
    if (!any) return {};  // still none: no array, no bytes per step
    // The step graphs were captured without loads: allocate, and capture them again.
    if (Status s = d_external_.allocate(nv_, "loads"); !s) return s;
    has_external_ = true;
    graphs_.clear();
  }
  if (h_external_.size() != nv_)
    if (Status s = h_external_.allocate(nv_, "loads"); !s) return s;
  // The previous copy out of the staging buffer must be done before it is overwritten.
  ZONA_CUDA_TRY(cudaStreamSynchronize(stream_.get()));
  for (size_t i = 0; i < nv_; ++i) {
    const Vec3d p = forces[static_cast<size_t>(new_to_old_[i])] / force_unit_;
    h_external_[i] = make_float4(float(p.x), float(p.y), float(p.z), 0.0f);
  }
  ZONA_CUDA_TRY(cudaMemcpyAsync(d_external_.data(), h_external_.data(), d_external_.bytes(),
                                cudaMemcpyHostToDevice, stream_.get()));
  return {};
}

Status CudaBackend::download(State& state) {
  if (!model_) return make_error("cuda backend: nothing uploaded");
  if (step_log_.failed) return make_error("%s", step_log_.message);
  if (state.u.size() != nv_ || state.u_prev.size() != nv_ || state.force.size() != nv_)
    return make_error("cuda backend: download needs a state made for this model (%zu vertices)",
                      nv_);
  ZONA_CUDA_TRY(cudaStreamSynchronize(stream_.get()));
  const int64_t g = phase_step_;
  std::vector<double> u(3 * nv_), up(3 * nv_);
  std::vector<float4> f(nv_);
  ZONA_CUDA_TRY(cudaMemcpy(u.data(), d_u_[g % 3].data(), d_u_[0].bytes(), cudaMemcpyDeviceToHost));
  ZONA_CUDA_TRY(
      cudaMemcpy(up.data(), d_u_[(g + 2) % 3].data(), d_u_[0].bytes(), cudaMemcpyDeviceToHost));
  // The force of the last evaluated configuration, u_{n-1} now, as on the CPU.
  ZONA_CUDA_TRY(cudaMemcpy(f.data(), d_force_[(g + 1) % 2].data(), d_force_[0].bytes(),
                           cudaMemcpyDeviceToHost));
  for (size_t i = 0; i < nv_; ++i) {
    const size_t v = static_cast<size_t>(new_to_old_[i]);
    state.u[v] = Vec3d{u[3 * i], u[3 * i + 1], u[3 * i + 2]} * length_unit_;
    state.u_prev[v] = Vec3d{up[3 * i], up[3 * i + 1], up[3 * i + 2]} * length_unit_;
    state.force[v] = Vec3d{f[i].x, f[i].y, f[i].z} * force_unit_;
  }
  state.prescribed_displacement.assign(presc_current_.begin(), presc_current_.end());
  state.time = time_;
  state.step_count = step_count_;
  state.diag = diag_;
  state.energy_budget_valid = budget_valid_;
  return {};
}

Status CudaBackend::clear_nodal_sums(cudaStream_t s) {
  if (Status z = d_vertex_q_.fill_bytes_async(0, s); !z) return z;
  return d_vertex_q_fixed_.fill_bytes_async(0, s);
}

Status CudaBackend::elastic_forces(std::span<const Vec3d> u, std::span<Vec3d> f) {
  if (!model_) return make_error("cuda backend: nothing uploaded");
  if (f.size() != nv_)
    return make_error("cuda backend: elastic_forces needs %zu force slots, got %zu", nv_, f.size());
  std::vector<double> ud;
  if (Status s = to_device_order(u, length_unit_, ud); !s) return s;
  if (d_scratch_force_.size() != nv_) {
    if (Status s = d_scratch_fixed_.allocate(3 * nv_, "scratch forces"); !s) return s;
    if (Status s = d_scratch_u64_.allocate(3 * nv_, "scratch displacements"); !s) return s;
    if (Status s = d_scratch_force_.allocate(nv_, "scratch forces"); !s) return s;
  }
  if (options_.assembly == Assembly::kGatherStored && d_tet_force_.size() != 4 * nt_)
    if (Status s = d_tet_force_.allocate(4 * nt_, "corner forces"); !s) return s;
  const cudaStream_t s = stream_.get();
  ZONA_CUDA_TRY(cudaMemcpyAsync(d_scratch_u64_.data(), ud.data(), d_scratch_u64_.bytes(),
                                cudaMemcpyHostToDevice, s));
  ZONA_CUDA_TRY(cudaMemcpyAsync(d_scratch_status_.data(), h_status_init_.data(),
                                sizeof(DeviceStatus), cudaMemcpyHostToDevice, s));
  // The scatters accumulate into zeros (then, in fixed point, a conversion pass writes the
  // float forces); the gathers write every entry, so they get NaN when poisoning is asked for
  // and any entry they miss stays NaN.
  const Assembly a = options_.assembly;
  const bool accumulate = a == Assembly::kScatterAtomic;
  const int fill = accumulate || !options_.poison_outputs ? 0 : 0xFF;
  ZONA_CUDA_TRY(cudaMemsetAsync(d_scratch_force_.data(), fill, d_scratch_force_.bytes(), s));
  ZONA_CUDA_TRY(cudaMemsetAsync(d_scratch_fixed_.data(), 0, d_scratch_fixed_.bytes(), s));
  if (a == Assembly::kGatherStored && options_.poison_outputs)
    ZONA_CUDA_TRY(cudaMemsetAsync(d_tet_force_.data(), 0xFF, d_tet_force_.bytes(), s));
  VertexParams vp = vertex_params(phase_step_);
  vp.u = d_scratch_u64_.data();
  vp.force = d_scratch_force_.data();
  vp.fixed = d_scratch_fixed_.data();
  vp.tet_force = d_tet_force_.data();
  DeviceStatus* st = d_scratch_status_.data();
  const unsigned tb = blocks_for(nt_), vb = blocks_for(nv_);
  cudaError_t err = cudaSuccess;
  // Nodal pressure: the first pass's sums from zero, and zero again afterwards (the stepping
  // state's invariant between steps).
  if (has_nodal(tp_)) {
    if (Status z = clear_nodal_sums(s); !z) return z;
    err = launch(false, volume_change_kernel, tb, s, tp_, vp.u, 0, st);
  }
  with_kind(kind_, [&](auto kc) {
    constexpr ElementKind K = decltype(kc)::value;
    if (a != Assembly::kGatherRecompute)
      with_scatter(scatter_of(a, options_.warp_aggregate), [&](auto mc) {
        constexpr Scatter M = decltype(mc)::value;
        if (err == cudaSuccess)
          err = launch(false, tet_pass_kernel<K, false, M>, tb, s, tp_, vp.u, vp.force, vp.fixed,
                       d_tet_force_.data(), 0, st, false);
      });
    if (a == Assembly::kGatherRecompute && err == cudaSuccess)
      err = launch(false, gather_kernel<K, true, false>, vb, s, tp_, vp, 0, st, false);
    if (a == Assembly::kGatherStored && err == cudaSuccess)
      err = launch(false, gather_kernel<ElementKind::kSvkGradient, false, false>, vb, s, tp_, vp, 0,
                   st, false);
  });
  if (err != cudaSuccess) return cuda_error(err, "cudaLaunchKernelEx (forces)", __FILE__, __LINE__);
  ZONA_CUDA_TRY_LAUNCH();
  if (has_nodal(tp_))
    if (Status z = clear_nodal_sums(s); !z) return z;
  std::vector<float4> out(nv_);
  ZONA_CUDA_TRY(cudaMemcpyAsync(out.data(), d_scratch_force_.data(), d_scratch_force_.bytes(),
                                cudaMemcpyDeviceToHost, s));
  ZONA_CUDA_TRY(cudaStreamSynchronize(s));
  if (a == Assembly::kScatterFixed) {
    // The fixed-point sums, converted as the update kernel converts them.
    std::vector<unsigned long long> q(3 * nv_);
    ZONA_CUDA_TRY(cudaMemcpy(q.data(), d_scratch_fixed_.data(), d_scratch_fixed_.bytes(),
                             cudaMemcpyDeviceToHost));
    for (size_t i = 0; i < nv_; ++i) {
      auto c = [&](int k) {
        return static_cast<float>(static_cast<double>(static_cast<long long>(q[3 * i + k])) *
                                  kFixedInverse);
      };
      out[i] = make_float4(c(0), c(1), c(2), 0.0f);
    }
  }
  for (size_t i = 0; i < nv_; ++i)
    f[static_cast<size_t>(new_to_old_[i])] = Vec3d{out[i].x, out[i].y, out[i].z} * force_unit_;
  return {};
}

Result<StateSummary> CudaBackend::summarize() {
  if (!model_) return make_error("cuda backend: nothing uploaded");
  const cudaStream_t s = stream_.get();
  const VertexParams vp = vertex_params(phase_step_);
  summary_terms_kernel<<<blocks_for(nv_), kBlock, 0, s>>>(vp, 1.0 / model_->dt, d_reduce_a_.data(),
                                                          d_reduce_b_.data());
  ZONA_CUDA_TRY_LAUNCH();
  size_t bytes = cub_temp_bytes_;
  ZONA_CUDA_TRY(cub::DeviceReduce::Max(d_cub_temp_.data(), bytes, d_reduce_a_.data(),
                                       d_reduce_out_.data(), static_cast<int>(nv_), s));
  bytes = cub_temp_bytes_;
  ZONA_CUDA_TRY(cub::DeviceReduce::Sum(d_cub_temp_.data(), bytes, d_reduce_b_.data(),
                                       d_reduce_out_.data() + 1, static_cast<int>(nv_), s));
  double out[2] = {0, 0};
  ZONA_CUDA_TRY(cudaMemcpyAsync(out, d_reduce_out_.data(), sizeof out, cudaMemcpyDeviceToHost, s));
  ZONA_CUDA_TRY(cudaStreamSynchronize(s));
  return StateSummary{out[0], out[1]};
}

}  // namespace cuda

Result<std::unique_ptr<Backend>> make_cuda_backend(const BackendOptions& options) {
  cudaDeviceProp prop{};
  if (Status s = cuda::open_device(options.device, &prop); !s) return s.error();
  // The kernels must exist for this device's architecture (built for CMAKE_CUDA_ARCHITECTURES).
  cudaFuncAttributes attributes{};
  const cudaError_t image = cudaFuncGetAttributes(
      &attributes,
      cuda::tet_pass_kernel<ElementKind::kSvkGradient, false, cuda::Scatter::kFloatAtomic>);
  if (image != cudaSuccess) {
    (void)cudaGetLastError();
    return make_error(
        "zona's CUDA kernels do not run on %s (sm_%d%d): %s; rebuild with "
        "-DCMAKE_CUDA_ARCHITECTURES=%d%d",
        prop.name, prop.major, prop.minor, cudaGetErrorString(image), prop.major, prop.minor);
  }
  return std::unique_ptr<Backend>(std::make_unique<cuda::CudaBackend>(options, prop.name));
}

}  // namespace zona
