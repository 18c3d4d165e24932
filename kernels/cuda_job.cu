// The device-resident injection step on the CUDA backend (engine/sim/job.h): per step two kernels
// (the element pass, then tools, update, measurement and record in one) replayed from captured graphs, state in device memory,
// only the fixed-size record crossing to the host through mapped pinned memory. The host never
// synchronises the stream on the step path: it bounds the steps in flight by reading the
// record's sequence number, and waits for the stream only for a frame (download) or finish().
#include <atomic>
#include <chrono>
#include <climits>
#include <cstring>
#include <thread>

#include "kernels/cuda_backend_impl.cuh"
#include "kernels/job_kernels.cuh"

namespace zona::cuda {

class CudaJob final : public JobRunner {
 public:
  explicit CudaJob(CudaBackend& backend) : b_(backend) {}

  Status start(const JobSetup& setup);
  Status advance(int64_t steps) override;
  bool latest(JobRecord* out) override;
  bool take_samples(std::vector<JobRecord>& out) override;
  Status finish() override;
  Status download(State& state) override;
  void set_tip(Vec3d tip) override;
  int64_t steps_advanced() const override { return advanced_; }
  uint64_t host_bytes_moved() const override {
    // Per publication (every few steps) the latest record, the counters and the pose mailbox
    // read; per sample one record.
    const volatile unsigned long long* count = h_sample_count_.data();
    const volatile unsigned long long* published = &h_latest_.data()->seq;
    return static_cast<uint64_t>(*published) *
               (sizeof(JobRecord) + 3 * sizeof(unsigned long long) + sizeof(TipMailbox)) +
           static_cast<uint64_t>(*count) * sizeof(JobRecord);
  }
  int64_t mass_raises() override {
    unsigned long long n = 0;
    if (cudaMemcpy(&n, d_mass_raises_.data(), sizeof n, cudaMemcpyDeviceToHost) != cudaSuccess)
      return -1;
    return static_cast<int64_t>(n);
  }
  std::string description() const override {
    return b_.description() + ", device-resident injection step";
  }

 private:
  struct Graph {
    int steps = 0;
    int phase = 0;
    GraphExec exec;
  };
  Status enqueue_step(int64_t g);
  /// The element pass sums the elastic energy on every kEnergyInterval-th step only (a block
  /// reduction and an atomic per block of tetrahedra); the record carries the last value in
  /// between: the energy criterion and the blow-up test see it at most 3 steps late, the
  /// kinetic energy and non-finite values every step.
  static constexpr int kEnergyInterval = 4;
  /// Graphs depend on the step index modulo this (6 buffer phases, 4 energy phases, 8 phases
  /// of the dynamic mass scaling).
  static constexpr int kPhases = 24;
  static_assert(kPhases % kDriftInterval == 0, "a graph phase starts on a drift-damping step");
  Result<cudaGraphExec_t> graph(int steps, int phase);
  // Steps finished on the device (from the published sequence number; no synchronisation).
  int64_t steps_done() const {
    const volatile unsigned long long* done = &h_latest_.data()->steps_done;
    return static_cast<int64_t>(*done) - start_step_;
  }

  CudaBackend& b_;
  JobParams params_;  // device copy: entry vertices in device order
  ToolParams tl_;
  float damping_rate_ = 0;
  DeviceBuffer<int32_t> d_tool_vertex_;
  DeviceBuffer<double> d_tool_rest_, d_tool_area_, d_tool_suction_;
  DeviceBuffer<StickAnchor> d_tool_anchor_;  // per tool vertex: needle, then rim
  DeviceBuffer<float4> d_damp_, d_force_prev_;
  DeviceBuffer<JobBlockSums> d_block_sums_;  // one per block of job_step_kernel
  DeviceBuffer<JobRecord> d_staged_;         // samples between publications (JobHostLink)
  DeviceBuffer<float4> d_tool_load_;  // tool_kernel's loads per device vertex [force_unit]
  // The branch that runs tool_kernel beside the element pass in the captured graphs.
  Stream side_;
  Event fork_, join_;
  DeviceBuffer<JobState> d_job_;
  DeviceBuffer<JobSums> d_sums_;
  DeviceBuffer<JobCounters> d_counters_;
  // Dynamic mass scaling: rest need per device tet [kg/m^3], need per device vertex (running
  // maximum), lumped volume per device vertex [m^3], and the number of raises.
  DeviceBuffer<float> d_tet_need_, d_vertex_need_, d_vertex_volume_;
  DeviceBuffer<unsigned long long> d_mass_raises_;
  // The needle's face quadrature: corners (tool indices, w unused), rest areas [m^2], and the
  // corner loads of the step [N] (3 per tool vertex).
  DeviceBuffer<int4> d_faces_;
  DeviceBuffer<double> d_face_area_;
  DeviceBuffer<double> d_path_time_;      // NeedleParams::path_time
  DeviceBuffer<Vec3d> d_path_position_;   // NeedleParams::path_position
  DeviceBuffer<StickAnchor> d_face_anchor_;  // kFacePoints per triangle
  PinnedBuffer<JobRecord> h_samples_;
  PinnedBuffer<unsigned long long> h_sample_count_;
  PinnedBuffer<LatestRecord> h_latest_;
  PinnedBuffer<TipMailbox> h_tip_;
  JobHostLink link_;
  std::vector<Graph> graphs_;
  int64_t advanced_ = 0;    // steps asked for
  int64_t launched_ = 0;    // steps enqueued on the stream
  int64_t pending_ = 0;     // asked for, not yet enqueued (fewer than a short graph)
  bool flush_ = false;      // enqueue the pending steps whatever their number
  int64_t start_step_ = 0;  // the job's step count when it started
  unsigned long long taken_ = 0;
  bool halted_seen_ = false;
  /// Steps that may be queued ahead of the device: enough to keep it busy between the host's
  /// launches, few enough that a pose handed in (haptics) acts within a few ms.
  int64_t max_in_flight_ = 96;
};

CudaBackend::~CudaBackend() = default;

Result<JobRunner*> CudaBackend::start_job(const JobSetup& setup) {
  if (!model_) return make_error("cuda backend: nothing uploaded");
  auto job = std::make_unique<CudaJob>(*this);
  if (Status s = job->start(setup); !s) return s.error();
  job_ = std::move(job);
  return static_cast<JobRunner*>(job_.get());
}

Status CudaJob::start(const JobSetup& setup) {
  const Model& m = *b_.model_;
  if (b_.presc_count_ > 0)
    return make_error("cuda job: the uploaded state has prescribed vertices (the penalty step "
                      "has none)");
  if (b_.options_.assembly != Assembly::kScatterAtomic &&
      b_.options_.assembly != Assembly::kScatterFixed)
    return make_error("cuda job: assembly '%s' is not supported by the injection step (use atomic "
                      "or fixed_point)", assembly_name(b_.options_.assembly));
  const size_t n = setup.tool_vertices.size();
  if (setup.tool_area.size() != n || setup.tool_suction.size() != n)
    return make_error("cuda job: tool arrays of different lengths");
  params_ = setup.params;
  if (params_.record.has_entry)
    for (int k = 0; k < 3; ++k)
      params_.record.entry_vertex[k] = b_.old_to_new_[static_cast<size_t>(params_.record.entry_vertex[k])];

  // Tool vertices in device order.
  std::vector<int32_t> vertex(n);
  std::vector<double> rest(3 * n), area(n), suction(3 * n);
  for (size_t i = 0; i < n; ++i) {
    const size_t v = static_cast<size_t>(setup.tool_vertices[i]);
    vertex[i] = b_.old_to_new_[v];
    for (int c = 0; c < 3; ++c) {
      rest[3 * i + c] = m.rest_positions[v][c];
      suction[3 * i + c] = setup.tool_suction[i][c];
    }
    area[i] = setup.tool_area[i];
  }
  if (Status s = d_tool_vertex_.upload(vertex, "tool vertices"); !s) return s;
  if (Status s = d_tool_rest_.upload(rest, "tool rest positions"); !s) return s;
  if (Status s = d_tool_area_.upload(area, "tool areas"); !s) return s;
  // Stick anchors of the friction (zero bytes: void), on the needle and on the rim.
  if (Status s = d_tool_anchor_.allocate(2 * n, "stick anchors"); !s) return s;
  if (Status s = d_tool_anchor_.fill_bytes(0); !s) return s;
  if (Status s = d_tool_suction_.upload(suction, "suction loads"); !s) return s;
  if (Status s = d_block_sums_.allocate(blocks_for(b_.nv_), "job block sums"); !s) return s;
  if (Status s = d_tool_load_.allocate(b_.nv_, "tool loads"); !s) return s;
  if (Status s = d_tool_load_.fill_bytes(0); !s) return s;
  if (Status s = side_.create(); !s) return s;
  if (Status s = fork_.create(false); !s) return s;
  if (Status s = join_.create(false); !s) return s;
  damping_rate_ = static_cast<float>(params_.damping.stiffness_rate);
  if (params_.damping.stiffness_rate > 0) {
    if (Status s = d_damp_.allocate(b_.nv_, "damping loads"); !s) return s;
    if (Status s = d_force_prev_.allocate(b_.nv_, "previous forces"); !s) return s;
    if (Status s = d_damp_.fill_bytes(0); !s) return s;
    if (Status s = d_force_prev_.fill_bytes(0); !s) return s;
  }
  tl_ = ToolParams{};
  tl_.vertex = d_tool_vertex_.data();
  tl_.rest = d_tool_rest_.data();
  tl_.area = d_tool_area_.data();
  tl_.needle_anchor = d_tool_anchor_.data();
  tl_.rim_anchor = d_tool_anchor_.data() + n;
  tl_.suction = d_tool_suction_.data();
  tl_.count = static_cast<int>(n);
  tl_.length_unit = b_.length_unit_;
  tl_.force_unit = b_.force_unit_;

  // The job's scalars: the first pose, as the CPU runner starts.
  // (setup.params: its path arrays are the host's; params_'s become the device's below.)
  JobState js;
  js.pose.tip = params_.needle.start;
  job_follow_tip(setup.params, js);
  job_set_pose(setup.params, js);
  if (params_.needle.path_count > 0) {
    const size_t np = static_cast<size_t>(params_.needle.path_count);
    if (Status s = d_path_time_.upload(std::vector<double>(setup.params.needle.path_time,
                                                           setup.params.needle.path_time + np),
                                       "needle path times");
        !s)
      return s;
    if (Status s = d_path_position_.upload(
            std::vector<Vec3d>(setup.params.needle.path_position,
                               setup.params.needle.path_position + np),
            "needle path positions");
        !s)
      return s;
    params_.needle.path_time = d_path_time_.data();
    params_.needle.path_position = d_path_position_.data();
  }
  if (Status s = d_job_.allocate(1, "job state"); !s) return s;
  ZONA_CUDA_TRY(cudaMemcpy(d_job_.data(), &js, sizeof js, cudaMemcpyHostToDevice));
  if (Status s = d_sums_.allocate(1, "job sums"); !s) return s;
  if (Status s = d_sums_.fill_bytes(0); !s) return s;
  if (Status s = d_counters_.allocate(1, "job counters"); !s) return s;
  if (Status s = d_counters_.fill_bytes(0); !s) return s;
  if (params_.mass.interval > 0) {
    if (kPhases % params_.mass.interval != 0)
      return make_error("cuda job: mass check interval %d does not divide %d", params_.mass.interval,
                        kPhases);
    if (setup.tet_rest_need.size() != b_.nt_ || setup.vertex_volume.size() != b_.nv_)
      return make_error("cuda job: dynamic mass scaling arrays of the wrong size");
    std::vector<float> need(b_.nt_), volume(b_.nv_);
    for (size_t t = 0; t < b_.nt_; ++t)
      need[t] = static_cast<float>(setup.tet_rest_need[static_cast<size_t>(b_.tet_new_to_old_[t])]);
    for (size_t v = 0; v < b_.nv_; ++v)
      volume[v] = static_cast<float>(setup.vertex_volume[static_cast<size_t>(b_.new_to_old_[v])]);
    if (Status s = d_tet_need_.upload(need, "tet mass needs"); !s) return s;
    if (Status s = d_vertex_volume_.upload(volume, "vertex volumes"); !s) return s;
    if (Status s = d_vertex_need_.allocate(b_.nv_, "vertex mass needs"); !s) return s;
    if (Status s = d_vertex_need_.fill_bytes(0); !s) return s;
  }
  if (Status s = d_mass_raises_.allocate(1, "mass raises"); !s) return s;
  if (params_.needle.on_faces) {
    const size_t nf = setup.tool_faces.size();
    if (setup.tool_face_area.size() != nf || nf == 0)
      return make_error("cuda job: face quadrature without faces");
    std::vector<int4> faces(nf);
    for (size_t f = 0; f < nf; ++f)
      faces[f] = make_int4(setup.tool_faces[f][0], setup.tool_faces[f][1], setup.tool_faces[f][2], 0);
    if (Status s = d_faces_.upload(faces, "needle faces"); !s) return s;
    if (Status s = d_face_area_.upload(setup.tool_face_area, "needle face areas"); !s) return s;
    if (Status s = d_face_anchor_.allocate(nf * kFacePoints, "face stick anchors"); !s) return s;
    if (Status s = d_face_anchor_.fill_bytes(0); !s) return s;
  }
  if (Status s = d_mass_raises_.fill_bytes(0); !s) return s;
  const DeviceStatus fresh{};
  ZONA_CUDA_TRY(cudaMemcpy(b_.d_status_.data(), &fresh, sizeof fresh, cudaMemcpyHostToDevice));

  // Mapped pinned memory (unified addressing: the device writes it through the same pointer).
  const size_t capacity = std::max<size_t>(setup.sample_capacity, 16);
  if (Status s = h_samples_.allocate(capacity, "job samples"); !s) return s;
  if (Status s = h_sample_count_.allocate(1, "job sample count"); !s) return s;
  if (Status s = h_latest_.allocate(1, "job record"); !s) return s;
  if (Status s = h_tip_.allocate(1, "needle pose"); !s) return s;
  link_ = JobHostLink{h_samples_.data(), nullptr, h_sample_count_.data(), capacity,
                      h_latest_.data(), h_tip_.data()};
  if (Status s = d_staged_.allocate(static_cast<size_t>(link_.publish_interval), "staged samples");
      !s)
    return s;
  link_.staged = d_staged_.data();
  ZONA_CUDA_TRY(cudaDeviceSynchronize());
  return {};
}

// The kernels of global step g (buffer roles rotate with g, as in the sub-step graphs), enqueued
// while a graph is captured: the tool loads (tool_kernel) on a side branch beside the element
// pass, then everything else of the step in one kernel (job_step_kernel). Stages
// (engine/sim/step_stage.h): masses = mass_check_kernel + mass_raise_kernel; tools = tool_kernel;
// elastic = volume_change_kernel (nodal pressure) + tet_pass_kernel; loads, integrate and
// measure = job_step_kernel; record, commit and puncture = job_record_kernel.
Status CudaJob::enqueue_step(int64_t g) {
  const VertexParams vp = b_.vertex_params(g);
  const cudaStream_t s = b_.stream_.get();
  const bool pdl = b_.options_.programmatic_launch;
  const unsigned tb = blocks_for(b_.nt_), vb = blocks_for(b_.nv_);
  DeviceStatus* st = b_.d_status_.data();
  // Sub-step index 1 of a one-step window: a job halted by an earlier step sets the status's
  // failed_substep to 0, which stops every kernel of every later step.
  constexpr int kSubstep = 1;
  cudaError_t err = cudaSuccess;
  auto keep = [&err](cudaError_t e) {
    if (err == cudaSuccess) err = e;
  };
  const Scatter mode = scatter_of(b_.options_.assembly, b_.options_.warp_aggregate);
  const bool energy = g % kEnergyInterval == 0;
  // StepStage::kMasses first: it changes the masses and u_{n-1} that the rim's damper reads.
  if (params_.mass.interval > 0 && g % params_.mass.interval == 0) {
    keep(launch(pdl, mass_check_kernel, tb, s, b_.tp_, vp.u,
                static_cast<const float*>(d_tet_need_.data()), d_vertex_need_.data(),
                static_cast<float>(params_.mass.gate), params_.mass.law));
    keep(launch(pdl, mass_raise_kernel, vb, s, static_cast<const float*>(d_vertex_need_.data()),
                static_cast<const float*>(d_vertex_volume_.data()), b_.d_mass_.data(),
                b_.d_update_.data(), vp.u,
                // The step's u_{n-1} buffer (the vertex view only reads it).
                const_cast<double*>(vp.u_prev), d_mass_raises_.data(),
                static_cast<int>(b_.nv_)));
  }
  // StepStage::kTools, every tool load (the needle on the triangles, then the tool vertices):
  // it reads only u_n, u_{n-1}, the masses and the pose, so it runs on a branch of its own
  // beside the element pass (at 1k vertices the two are about 10 us each, and one after the other they
  // were the step).
  keep(cudaEventRecord(fork_.get(), s));
  keep(cudaStreamWaitEvent(side_.get(), fork_.get(), 0));
  const int nf = params_.needle.on_faces ? static_cast<int>(d_faces_.size()) : 0;
  const bool small = nf <= kFaceLanesSmallMaxFaces;
  const int lanes = small ? kFaceLanesSmall : kFaceLanes;
  const int face_blocks = static_cast<int>(blocks_for(static_cast<size_t>(nf) * lanes));
  const unsigned tool_blocks =
      static_cast<unsigned>(face_blocks) + blocks_for(static_cast<size_t>(tl_.count));
  keep(launch(false, small ? tool_kernel<kFaceLanesSmall> : tool_kernel<kFaceLanes>, tool_blocks,
              side_.get(), params_, tl_,
              static_cast<const int4*>(d_faces_.data()),
              static_cast<const double*>(d_face_area_.data()), vp,
              static_cast<const JobState*>(d_job_.data()), d_face_anchor_.data(),
              d_tool_load_.data(), d_sums_.data(), face_blocks, nf, st, kSubstep));
  keep(cudaEventRecord(join_.get(), side_.get()));
  if (has_nodal(b_.tp_))
    keep(launch(pdl, volume_change_kernel, tb, s, b_.tp_, vp.u, kSubstep, st));
  with_kind(b_.kind_, [&](auto kc) {
    constexpr ElementKind K = decltype(kc)::value;
    with_bool(energy, [&](auto dc) {
      constexpr bool D = decltype(dc)::value;
      with_scatter(mode, [&](auto mc) {
        constexpr Scatter M = decltype(mc)::value;
        if constexpr (M != Scatter::kStore)
          keep(launch(pdl, tet_pass_kernel<K, D, M>, tb, s, b_.tp_, vp.u, vp.force, vp.fixed,
                      static_cast<float4*>(nullptr), kSubstep, st, true));
      });
    });
  });
  // The tool loads join here.
  keep(cudaStreamWaitEvent(s, join_.get(), 0));
  const bool drift = params_.damping.drift > 0;
  const bool momentum = drift && g % kDriftInterval == 0;  // kPhases is a multiple of it
  const bool fixed = b_.options_.assembly == Assembly::kScatterFixed;
  auto step_kernel = fixed ? (momentum ? job_step_kernel<true, true> : job_step_kernel<true, false>)
                           : (momentum ? job_step_kernel<false, true> : job_step_kernel<false, false>);
  keep(launch(pdl, step_kernel, vb, s, d_tool_load_.data(), vp, d_damp_.data(),
              d_force_prev_.data(), damping_rate_, kSubstep, st, d_block_sums_.data(),
              drift ? static_cast<const JobState*>(d_job_.data())
                    : static_cast<const JobState*>(nullptr)));
  keep(launch(pdl, job_record_kernel, 1, s, params_,
              static_cast<const JobBlockSums*>(d_block_sums_.data()), static_cast<int>(vb),
              static_cast<const double*>(vp.u_next), b_.length_unit_, energy, st, d_job_.data(),
              d_sums_.data(), d_counters_.data(), link_, kSubstep, momentum));
  if (err != cudaSuccess) return cuda_error(err, "cudaLaunchKernelEx (job step)", __FILE__, __LINE__);
  return {};
}

// A graph of `steps` steps starting at phase `phase` (mod kPhases), captured on first use.
Result<cudaGraphExec_t> CudaJob::graph(int steps, int phase) {
  for (Graph& g : graphs_)
    if (g.steps == steps && g.phase == phase) return g.exec.get();
  const cudaStream_t s = b_.stream_.get();
  ZONA_CUDA_TRY(cudaStreamBeginCapture(s, cudaStreamCaptureModeThreadLocal));
  int failed = -1;
  for (int i = 0; i < steps && failed < 0; ++i)
    if (!enqueue_step(phase + i).ok()) failed = i;
  cudaGraph_t captured = nullptr;
  const cudaError_t end = cudaStreamEndCapture(s, &captured);
  if (failed >= 0) {
    if (captured) (void)cudaGraphDestroy(captured);
    return make_error("cuda job: capturing step %d of a %d-step graph failed", failed, steps);
  }
  if (end != cudaSuccess) return cuda_error(end, "cudaStreamEndCapture", __FILE__, __LINE__);
  graphs_.push_back(Graph{steps, phase, GraphExec{}});
  if (Status st = graphs_.back().exec.instantiate(captured); !st) {
    graphs_.pop_back();
    return st.error();
  }
  return graphs_.back().exec.get();
}

Status CudaJob::advance(int64_t steps) {
  constexpr int kLong = 48;   // steps per long graph: a multiple of kPhases
  constexpr int kShort = 8;   // steps handed over one at a time (the haptic loop) go in eights
  const cudaStream_t s = b_.stream_.get();
  advanced_ += steps;
  pending_ += steps;
  while (pending_ >= kShort || (flush_ && pending_ > 0)) {
    if (halted_seen_) {
      pending_ = 0;
      break;
    }
    // Bound what is queued ahead of the device by its published progress (no synchronisation).
    const auto wait_start = std::chrono::steady_clock::now();
    while (launched_ - steps_done() > max_in_flight_) {
      JobRecord r;
      if (latest(&r) && r.halted) {
        halted_seen_ = true;
        pending_ = 0;
        return {};
      }
      const cudaError_t q = cudaStreamQuery(s);
      if (q != cudaSuccess && q != cudaErrorNotReady)
        return cuda_error(q, "cudaStreamQuery (job)", __FILE__, __LINE__);
      if (std::chrono::steady_clock::now() - wait_start > std::chrono::seconds(60))
        return make_error("cuda job: the device made no progress for 60 s");
      std::this_thread::yield();
    }
    const int chunk = pending_ >= kLong ? kLong : (pending_ >= kShort ? kShort : 1);
    const int phase = static_cast<int>(b_.phase_step_ % kPhases);
    Result<cudaGraphExec_t> exec = graph(chunk, phase);
    if (!exec) return exec.error();
    ZONA_CUDA_TRY(cudaGraphLaunch(*exec, s));
    b_.phase_step_ += chunk;
    launched_ += chunk;
    pending_ -= chunk;
  }
  return {};
}

bool CudaJob::latest(JobRecord* out) {
  const LatestRecord* l = h_latest_.data();
  const volatile unsigned long long* seq = &l->seq;
  for (;;) {
    const unsigned long long s1 = *seq;
    if (s1 == 0) return false;
    std::atomic_thread_fence(std::memory_order_acquire);
    std::memcpy(static_cast<void*>(out), static_cast<const void*>(&l->slot[(s1 - 1) % 2]),
                sizeof(JobRecord));
    std::atomic_thread_fence(std::memory_order_acquire);
    const unsigned long long s2 = *seq;
    if (s2 - s1 < 2) {
      if (out->halted) halted_seen_ = true;
      return true;
    }
  }
}

bool CudaJob::take_samples(std::vector<JobRecord>& out) {
  const unsigned long long count = *reinterpret_cast<const volatile unsigned long long*>(
      h_sample_count_.data());
  std::atomic_thread_fence(std::memory_order_acquire);
  const unsigned long long capacity = link_.capacity;
  bool complete = true;
  if (count - taken_ > capacity) {
    taken_ = count - capacity;
    complete = false;
  }
  for (; taken_ < count; ++taken_) out.push_back(h_samples_[taken_ % capacity]);
  return complete;
}

Status CudaJob::finish() {
  // Steps still pending (fewer than a short graph) go out one by one first.
  flush_ = true;
  const Status launched = advance(0);
  flush_ = false;
  if (!launched) return launched;
  ZONA_CUDA_TRY(cudaStreamSynchronize(b_.stream_.get()));
  return {};
}

Status CudaJob::download(State& state) {
  if (Status s = finish(); !s) return s;
  JobRecord r;
  if (latest(&r)) {
    b_.step_count_ = r.step;
    b_.time_ = r.time;
  }
  return b_.download(state);
}

void CudaJob::set_tip(Vec3d tip) {
  // A seqlock the record kernel reads: odd while the three components are written.
  TipMailbox* m = h_tip_.data();
  volatile unsigned long long* seq = &m->seq;
  const unsigned long long s = *seq;
  *seq = s + 1;
  std::atomic_thread_fence(std::memory_order_release);
  volatile double* out = m->tip;
  out[0] = tip.x;
  out[1] = tip.y;
  out[2] = tip.z;
  std::atomic_thread_fence(std::memory_order_release);
  *seq = s + 2;
}

}  // namespace zona::cuda
