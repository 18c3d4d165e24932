// Kernels of the device-resident injection step (engine/sim/job.h's stages): the tools over the
// surface vertices, the centred-difference update with the tool loads and stiffness damping,
// and the one-thread record that measures, tests and publishes the step. Thin wrappers: the
// physics is engine/sim/job.h's ZONA_HOST_DEVICE functions, the same the CPU runner calls.
// Included by cuda_job.cu only.
#pragma once

#include <climits>

#include "engine/sim/job.h"
#include "kernels/step_kernels.cuh"

namespace zona::cuda {

/// The tool vertices (the boundary surface) in device order.
struct ToolParams {
  const int32_t* vertex = nullptr;   ///< device vertex index, (count)
  const double* rest = nullptr;      ///< rest position [m], (3 count)
  const double* area = nullptr;      ///< rest tributary area [m^2], (count)
  const double* suction = nullptr;   ///< full suction load [N], (3 count)
  StickAnchor* needle_anchor = nullptr;  ///< friction anchors on the needle, (count)
  StickAnchor* rim_anchor = nullptr;     ///< friction anchors on the rim, (count)
  int count = 0;
  double length_unit = 1;  ///< [m]
  double force_unit = 1;   ///< [N]
};

/// The newest record, double-buffered: `seq` counts the publications, the newest is in
/// slot[(seq - 1) % 2]. The device writes the other slot, fences, then bumps seq, so a reader
/// that sees seq unchanged by less than 2 around its copy has a whole record.
struct LatestRecord {
  unsigned long long seq = 0;
  /// Steps finished (progress for the host's throttle), written at each publication.
  unsigned long long steps_done = 0;
  JobRecord slot[2];
};

/// The needle pose the host hands in (haptics), with a sequence number (odd while written).
struct TipMailbox {
  unsigned long long seq = 0;
  double tip[3] = {0, 0, 0};  ///< [m]
};

/// Device-side counters of the record stage.
struct JobCounters {
  unsigned long long samples = 0;     ///< samples written to the host's ring so far
  unsigned long long staged = 0;      ///< samples waiting in JobHostLink::staged
  unsigned long long latest_seq = 0;  ///< records published so far
  double elastic_energy = 0;          ///< the last evaluated elastic energy [J]
};

/// Where the record kernel publishes: mapped pinned host memory (written over the bus, read by
/// the host without any stream synchronisation), and the device-side staging of the samples.
struct JobHostLink {
  JobRecord* samples = nullptr;               ///< ring of samples, (capacity)
  /// Device memory, (publish_interval): the samples since the last publication, copied to the
  /// ring when it comes. A step whose kernel writes host memory ends only when the bus has taken
  /// the writes, so the steps between publications write none.
  JobRecord* staged = nullptr;
  unsigned long long* sample_count = nullptr; ///< samples written so far
  unsigned long long capacity = 0;
  LatestRecord* latest = nullptr;
  const TipMailbox* tip = nullptr;
  /// The latest record and the samples since the last publication go to the host every this
  /// many steps (and at a puncture and a halt); the pose is read from the host as often. Each
  /// publication costs a system-scope fence (a round trip over the bus): once per step it
  /// would triple a small mesh's step. 16 steps are 0.3-1.6 ms of simulated time.
  int publish_interval = 16;
};

/// One block's share of the sums of job_step_kernel (SI units): each block writes its own,
/// job_record_kernel adds them up in block order (the totals come out the same on every run,
/// and no block waits on a same-address atomic).
struct JobBlockSums {
  double kinetic = 0, work = 0;
  /// Drift damping only: m (u_{n+1} - u_n) / dt [kg m/s] and m [kg] of the free vertices.
  double momentum[3] = {0, 0, 0};
  double mass = 0;
};

/// The sum of two blocks' (or threads') sums.
__device__ __forceinline__ JobBlockSums add_sums(JobBlockSums a, const JobBlockSums& b) {
  a.kinetic += b.kinetic;
  a.work += b.work;
  for (int c = 0; c < 3; ++c) a.momentum[c] += b.momentum[c];
  a.mass += b.mass;
  return a;
}

/// Shuffles every field of a block sum down by `off` lanes.
__device__ __forceinline__ JobBlockSums shfl_down_sums(const JobBlockSums& v, int off) {
  JobBlockSums o;
  o.kinetic = __shfl_down_sync(0xffffffffu, v.kinetic, off);
  o.work = __shfl_down_sync(0xffffffffu, v.work, off);
  for (int c = 0; c < 3; ++c) o.momentum[c] = __shfl_down_sync(0xffffffffu, v.momentum[c], off);
  o.mass = __shfl_down_sync(0xffffffffu, v.mass, off);
  return o;
}

/// The block's total in thread 0 (every thread of the block must call it; it ends with a
/// barrier, so it can be called again). MOMENTUM: also the drift damping's momentum and mass
/// (left zero otherwise).
template <bool MOMENTUM>
__device__ __forceinline__ JobBlockSums block_reduce_sums(JobBlockSums v) {
  constexpr int kWarps = kBlock / 32;
  __shared__ JobBlockSums warp_sums[kWarps];
  const int warp = threadIdx.x / 32, lane = threadIdx.x % 32;
  auto shfl_add = [](JobBlockSums& x, int off) {
    if constexpr (MOMENTUM) {
      x = add_sums(x, shfl_down_sums(x, off));
    } else {
      x.kinetic += __shfl_down_sync(0xffffffffu, x.kinetic, off);
      x.work += __shfl_down_sync(0xffffffffu, x.work, off);
    }
  };
  for (int off = 16; off > 0; off >>= 1) shfl_add(v, off);
  if (lane == 0) warp_sums[warp] = v;
  __syncthreads();
  if (warp == 0) {
    v = lane < kWarps ? warp_sums[lane] : JobBlockSums{};
    for (int off = kWarps / 2; off > 0; off >>= 1) shfl_add(v, off);
  }
  __syncthreads();
  return v;
}

/// Stage 1 for one tool vertex (tool index i, device vertex v): its load [N] and the parts the
/// step sums, with its stick anchors. The rim's damper reads u_{n-1} and the mass.
__device__ __forceinline__ ToolVertexForce tool_stage(const JobParams& p, const ToolParams& tl,
                                                     const VertexParams& vp,
                                                     const ToolPose& pose, int i, int v) {
  const double lu = tl.length_unit;
  const double* un = vp.u + 3 * static_cast<size_t>(v);
  ToolVertexInput in;
  in.x = Vec3d{tl.rest[3 * i] + un[0] * lu, tl.rest[3 * i + 1] + un[1] * lu,
               tl.rest[3 * i + 2] + un[2] * lu};
  in.area = tl.area[i];
  in.suction = Vec3d{tl.suction[3 * i], tl.suction[3 * i + 1], tl.suction[3 * i + 2]};
  if (p.rim.damping > 0) {
    const double* up = vp.u_prev + 3 * static_cast<size_t>(v);
    const double s = lu / p.dt;
    in.velocity = Vec3d{(un[0] - up[0]) * s, (un[1] - up[1]) * s, (un[2] - up[2]) * s};
    in.mass = vp.mass[v];
  }
  return tool_vertex_force(p.needle, p.rim, p.dt, pose, in, tl.needle_anchor + i, tl.rim_anchor + i);
}

/// Threads per triangle in the face part of tool_kernel, each taking every LANES-th point: four
/// on large surfaces (where the threads that only test a far triangle dominate), sixteen, one
/// point each, on small ones (where the few triangles under the needle are the step's critical
/// path: on a 1k-vertex cell the tools run beside the element pass and finish after it).
inline constexpr int kFaceLanes = 4;
inline constexpr int kFaceLanesSmall = 16;
/// Surfaces of at most this many triangles take kFaceLanesSmall.
inline constexpr int kFaceLanesSmallMaxFaces = 16384;

/// Stage 1, every tool load of a step from u_n, in one launch of two parts.
///
/// Blocks [0, face_blocks): the needle on the surface triangles (JobParams::needle_on_faces),
/// LANES threads per triangle, each evaluating every LANES-th quadrature point
/// (needle_face_point), summed over the triangle by shuffles; its first thread adds the corner
/// loads to tool_load (per device vertex, force units; job_step_kernel takes and clears them in
/// the same step). A thread that evaluated all 16 points in float64 made the stage
/// latency-bound (about 20 us per step at 1k vertices); on large surfaces four lanes of four
/// points keep the threads that only test a far triangle few, on small ones one point per
/// thread shortens the chain (kFaceLanes, kFaceLanesSmall).
///
/// The blocks after them: one thread per tool vertex (tool_stage: the rim, the suction, the
/// needle at the vertices, friction), its load added to tool_load. In the vertex kernel this
/// stage made every warp that held a surface vertex wait on it and held the kernel's registers
/// at 132 (one block per SM): the step's vertex kernel took 210 us at 1M vertices, against about
/// 40 us for its own reads and writes. The loads are kept per device vertex so that the vertex
/// kernel reads them in order (read through a tool index, they made it wait on two dependent
/// loads: 83 us at 1M vertices, 44 % of the memory bandwidth).
///
/// Both parts add their needle and rim sums to the step's (block sums, then atomics).
// Two blocks per SM (at most 128 registers): the tool kernel runs beside the element pass on a
// graph branch, and at 153 registers (one block per SM) it took 11 % longer and the 100k job
// 7 % (ncu and zona bench --job, H200).
template <int LANES>
__global__ void __launch_bounds__(kBlock, 2)
    tool_kernel(JobParams p, ToolParams tl, const int4* __restrict__ faces,
                const double* __restrict__ face_area, VertexParams vp,
                const JobState* __restrict__ job, StickAnchor* __restrict__ face_anchor,
                float4* __restrict__ tool_load, JobSums* sums, int face_blocks, int face_count,
                DeviceStatus* st, int substep) {
  static_assert(kFacePoints % LANES == 0 && kBlock % LANES == 0, "lanes per triangle");
  wait_for_previous_kernel();
  allow_next_kernel();
  if (halted(st, substep)) return;  // the same for every thread
  if (static_cast<int>(blockIdx.x) >= face_blocks) {
    const int i = static_cast<int>((blockIdx.x - face_blocks) * blockDim.x + threadIdx.x);
    ToolVertexForce t;
    if (i < tl.count) {
      const int v = tl.vertex[i];
      t = tool_stage(p, tl, vp, job->pose, i, v);
      if (t.force.x != 0 || t.force.y != 0 || t.force.z != 0) {
        const double inv = 1.0 / tl.force_unit;
        atomicAdd(&tool_load[v].x, float(t.force.x * inv));
        atomicAdd(&tool_load[v].y, float(t.force.y * inv));
        atomicAdd(&tool_load[v].z, float(t.force.z * inv));
      }
    }
    if (__syncthreads_or(t.needle_contact > 0 || t.rim_contact > 0 || t.rim.x != 0 ||
                         t.rim.y != 0 || t.rim.z != 0)) {
      for (int c = 0; c < 3; ++c) block_sum_add(t.needle[c], &sums->needle_force[c]);
      for (int c = 0; c < 3; ++c) block_sum_add(t.rim[c], &sums->rim_force[c]);
      if (!p.needle.on_faces) block_max_store(t.needle_depth, &sums->needle_depth);
      using Reduce = cub::BlockReduce<int, kBlock>;
      __shared__ typename Reduce::TempStorage temp;
      const int nc = Reduce(temp).Sum(t.needle_contact);
      __syncthreads();
      const int rc = Reduce(temp).Sum(t.rim_contact);
      if (threadIdx.x == 0) {
        if (nc) atomicAdd(&sums->needle_contacts, nc);
        if (rc) atomicAdd(&sums->rim_contacts, rc);
      }
    }
    return;
  }
  const int t = static_cast<int>(blockIdx.x * blockDim.x + threadIdx.x);
  const int f = t / LANES, lane = t % LANES;
  double load[9] = {0, 0, 0, 0, 0, 0, 0, 0, 0};
  double depth = 0;  // deepest of this thread's points inside the needle
  int contact = 0;
  int corner[3] = {0, 0, 0};  // device vertices
  ToolFaceInput in;
  int k3[3] = {0, 0, 0};
  if (f < face_count) {
    const int4 c4 = faces[f];
    k3[0] = c4.x;
    k3[1] = c4.y;
    k3[2] = c4.z;
    const double lu = tl.length_unit;
    // Positions first: most triangles are far from the needle and need nothing else.
    for (int c = 0; c < 3; ++c) {
      const int k = k3[c];
      corner[c] = tl.vertex[k];
      const double* un = vp.u + 3 * static_cast<size_t>(corner[c]);
      in.x[c] = Vec3d{tl.rest[3 * k] + un[0] * lu, tl.rest[3 * k + 1] + un[1] * lu,
                      tl.rest[3 * k + 2] + un[2] * lu};
    }
    const ToolPose pose = job->pose;
    if (needle_face_may_touch(p.needle, pose, in)) {
      in.area = face_area[f];
      StickAnchor* anchors = face_anchor + static_cast<size_t>(f) * kFacePoints;
      for (int q = lane; q < kFacePoints; q += LANES) {
        Vec3d force;
        double b[3], point_depth = 0;
        if (!needle_face_point(p.needle, pose, in, q, &force, &point_depth, b, anchors + q)) continue;
        for (int c = 0; c < 3; ++c)
          for (int j = 0; j < 3; ++j) load[3 * c + j] += b[c] * force[j];
        ++contact;
        depth = fmax(depth, point_depth);
      }
    }
  }
  // Sum the triangle's lanes onto its first one.
  for (int offset = LANES / 2; offset > 0; offset /= 2) {
    for (int k = 0; k < 9; ++k) load[k] += __shfl_down_sync(0xffffffffu, load[k], offset, LANES);
    contact += __shfl_down_sync(0xffffffffu, contact, offset, LANES);
  }
  double nf[3] = {0, 0, 0};
  int contacts = 0;
  if (lane == 0 && contact > 0) {
    const double inv = 1.0 / tl.force_unit;
    for (int c = 0; c < 3; ++c) {
      atomicAdd(&tool_load[corner[c]].x, float(load[3 * c] * inv));
      atomicAdd(&tool_load[corner[c]].y, float(load[3 * c + 1] * inv));
      atomicAdd(&tool_load[corner[c]].z, float(load[3 * c + 2] * inv));
      for (int j = 0; j < 3; ++j) nf[j] += load[3 * c + j];
    }
    contacts = contact;
  }
  double strain = 0;  // needle_face_strain of a triangle around the tip (strain criterion)
  if (f < face_count && lane == 0 && p.puncture.criterion == kJobCriterionStrain &&
      !job->puncture.punctured && needle_face_near(p.needle, job->pose, in.x)) {
    Vec3d rest[3];
    for (int c = 0; c < 3; ++c)
      rest[c] = Vec3d{tl.rest[3 * k3[c]], tl.rest[3 * k3[c] + 1], tl.rest[3 * k3[c] + 2]};
    strain = needle_face_strain(rest, in.x);
  }
  if (p.puncture.criterion == kJobCriterionStrain && __syncthreads_or(strain > 0))
    block_max_store(strain, &sums->needle_strain);
  if (__syncthreads_or(contacts > 0)) {
    for (int c = 0; c < 3; ++c) block_sum_add(nf[c], &sums->needle_force[c]);
    block_max_store(depth, &sums->needle_depth);
    using Reduce = cub::BlockReduce<int, kBlock>;
    __shared__ typename Reduce::TempStorage temp;
    const int nc = Reduce(temp).Sum(contacts);
    if (threadIdx.x == 0 && nc) atomicAdd(&sums->needle_contacts, nc);
  }
}

/// Stages 5 (the deformation) and 6, run by one thread once every vertex of the step is done:
/// reads the step's sums and status, runs job_finish_step, publishes the record (latest, and a
/// sample when due) to mapped host memory, and resets the sums and the status for the next step.
/// A halted job stays halted: the status keeps failed_substep at 0, which stops every later
/// kernel. momentum, mass: the free vertices' sums for the drift damping.
__device__ void record_stage(const JobParams& p, JobState* job, JobSums* sums, DeviceStatus* st,
                             const double* u_next, double length_unit, bool fresh_energy,
                             JobCounters* counters, const JobHostLink& link, Vec3d momentum,
                             double mass) {
  const bool publish_step = (job->step + 1) % link.publish_interval == 0;
  // (A halted job is not stepped again: its last record is always published.)
  // The pose the host handed in (haptics), when a whole one is there.
  if (publish_step) {
    const volatile TipMailbox* mailbox = link.tip;
    const unsigned long long seq = mailbox->seq;
    if (seq != 0 && (seq & 1ull) == 0) {
      const double t0 = mailbox->tip[0], t1 = mailbox->tip[1], t2 = mailbox->tip[2];
      __threadfence_system();
      if (mailbox->seq == seq) {
        job->external_tip = 1;
        job->external_tip_value = Vec3d{t0, t1, t2};
      }
    }
  }
  JobStepTotals tot;
  // The elastic energy is summed every few steps (JobHostLink's caller decides): in between,
  // the last value stands.
  if (fresh_energy) counters->elastic_energy = st->elastic_energy;
  tot.elastic_energy = counters->elastic_energy;
  tot.status = st->flags;
  tot.first_bad = st->first_nonfinite != LLONG_MAX   ? st->first_nonfinite
                  : st->first_inverted != LLONG_MAX ? st->first_inverted
                                                    : -1;
  if (p.record.has_entry) {
    Vec3d e[3];
    for (int k = 0; k < 3; ++k) {
      const double* x = u_next + 3 * static_cast<size_t>(p.record.entry_vertex[k]);
      e[k] = Vec3d{x[0] * length_unit, x[1] * length_unit, x[2] * length_unit};
    }
    tot.deformation = job_entry_deformation(p, e[0], e[1], e[2]);
  }
  // The sums and u_{n+1} come from the step's earlier kernels (visible past the grid
  // dependency): plain loads, issued together, not a chain of volatile ones.
  const JobSums total = *sums;
  tot.kinetic_energy = st->kinetic_energy;
  tot.momentum = momentum;
  tot.mass = mass;
  // The job's scalars in registers for the stage (one load and one store of the block, not a
  // chain of dependent global accesses on the step's serial tail).
  JobState js = *job;
  const int32_t punctured_before = js.puncture.punctured;
  JobRecord r;
  const bool sample = job_finish_step(p, js, total, tot, &r);
  *job = js;
  const bool publish = publish_step || r.halted || r.puncture.punctured != punctured_before;
  // Samples wait on the device (at most one per step, so publish_interval of them); at a
  // publication they go to the ring, then the latest record, one system fence, the counters.
  JobCounters c = *counters;
  if (sample) link.staged[c.staged++] = r;
  if (publish) {
    for (unsigned long long k = 0; k < c.staged; ++k)
      link.samples[(c.samples + k) % link.capacity] = link.staged[k];
    c.samples += c.staged;
    c.staged = 0;
    link.latest->slot[c.latest_seq % 2] = r;
    __threadfence_system();
    *reinterpret_cast<volatile unsigned long long*>(link.sample_count) = c.samples;
    c.latest_seq += 1;
    *reinterpret_cast<volatile unsigned long long*>(&link.latest->seq) = c.latest_seq;
    // Progress for the throttle (order does not matter for it).
    *reinterpret_cast<volatile unsigned long long*>(&link.latest->steps_done) =
        static_cast<unsigned long long>(r.step);
  }
  *counters = c;
  // The next step starts from clean sums; a halted job keeps every later kernel out.
  *sums = JobSums{};
  DeviceStatus fresh;
  if (job->halted) fresh.failed_substep = 0;
  *st = fresh;
}

/// Everything of a step after the element pass, one thread per vertex: the tool loads of
/// tool_kernel (tool_load, cleared for the next step), stage 2
/// (stiffness damping k (f(u_{n-1}) - f(u_{n-2})), lagged one step as on the CPU), stage 4 (the
/// centred-difference update), and the sums of stage 5 that need u_{n+1} (kinetic energy, the
/// tools' centred work f_n . (u_{n+1} - u_{n-1}) / 2), per block into block_sums for
/// job_record_kernel. With drift damping (`job` non-null) every free vertex also takes
/// m job->drift_accel, and on the steps that sum it (MOMENTUM, every kDriftInterval) adds its
/// momentum and mass to the sums (job_drift_update).
/// FIXED: the fixed-point scatter's sums.
template <bool FIXED, bool MOMENTUM>
__global__ void __launch_bounds__(kBlock)
    job_step_kernel(float4* __restrict__ tool_load, VertexParams vp, float4* damp,
                    float4* force_prev, float damping_rate, int substep, DeviceStatus* st,
                    JobBlockSums* __restrict__ block_sums, const JobState* __restrict__ job) {
  wait_for_previous_kernel();
  allow_next_kernel();
  if (halted(st, substep)) return;  // the same for every block: set by an earlier step
  const int v = blockIdx.x * kBlock + threadIdx.x;
  VertexDiag d;
  double work = 0;
  JobBlockSums mine;
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
    // The tools' load on this vertex (zero off the tools), taken and cleared for the next step.
    const float4 tool = tool_load[v];
    const bool loaded = tool.x != 0 || tool.y != 0 || tool.z != 0;
    if (loaded) tool_load[v] = make_float4(0, 0, 0, 0);
    float4 fe = tool;
    const double* up = vp.u_prev + 3 * static_cast<size_t>(v);
    if (damp) {
      const float4 k = damp[v];
      fe.x += k.x;
      fe.y += k.y;
      fe.z += k.z;
      const float4 fp = force_prev[v];
      damp[v] = make_float4(damping_rate * (f.x - fp.x), damping_rate * (f.y - fp.y),
                            damping_rate * (f.z - fp.z), 0.0f);
      force_prev[v] = f;
    }
    const bool drifting = job != nullptr && vp.update[v].y > 0;  // free vertices only
    if (drifting) {
      const Vec3d a = job->drift_accel;
      const double s = vp.mass[v] / vp.force_unit;
      fe.x += float(s * a.x);
      fe.y += float(s * a.y);
      fe.z += float(s * a.z);
    }
    update_vertex(vp, v, f, fe, substep, st, &d);
    if (MOMENTUM && drifting) {
      const double* un = vp.u + 3 * static_cast<size_t>(v);
      const double* next = vp.u_next + 3 * static_cast<size_t>(v);
      const double m = vp.mass[v], s = m * vp.length_unit * (2.0 * vp.half_inv_dt);
      for (int c = 0; c < 3; ++c) mine.momentum[c] = s * (next[c] - un[c]);
      mine.mass = m;
    }
    if (loaded) {
      const double* next = vp.u_next + 3 * static_cast<size_t>(v);
      work = 0.5 * vp.length_unit * vp.force_unit *
             (double(tool.x) * (next[0] - up[0]) + double(tool.y) * (next[1] - up[1]) +
              double(tool.z) * (next[2] - up[2]));
    }
  }
  // The block's sums into its own slot (no atomics); job_record_kernel adds them up.
  mine.kinetic = d.kinetic;
  mine.work = work;
  mine = block_reduce_sums<MOMENTUM>(mine);
  if (threadIdx.x == 0) block_sums[blockIdx.x] = mine;
}

/// The end of a step, one block: adds job_step_kernel's block sums up in block order, then its
/// first thread runs the record stage (stages 5 and 6, record_stage). A kernel of its own: in
/// the vertex kernel's last block the record stage held the whole grid at 128 registers. (On a
/// branch beside the next step's element pass, with a status per step, it measured slower: the
/// branch's own cost outweighed what it hid.)
// One block, so no occupancy to keep: at the default 128-register budget the record stage
// spilled 284 bytes (its JobState and JobRecord), 0.6 us per step on the critical path.
__global__ void __launch_bounds__(kBlock, 1)
    job_record_kernel(JobParams p, const JobBlockSums* __restrict__ block_sums, int block_count,
                      const double* __restrict__ u_next, double length_unit, bool fresh_energy,
                      DeviceStatus* st, JobState* job, JobSums* sums, JobCounters* counters,
                      JobHostLink link, int substep, bool momentum) {
  wait_for_previous_kernel();
  allow_next_kernel();
  if (halted(st, substep)) return;  // the step kernel did nothing either
  JobBlockSums total;
  for (int b = threadIdx.x; b < block_count; b += kBlock) total = add_sums(total, block_sums[b]);
  total = momentum ? block_reduce_sums<true>(total) : block_reduce_sums<false>(total);
  if (threadIdx.x == 0) {
    // The tool kernel added its sums with atomics: add to them.
    st->kinetic_energy += total.kinetic;
    sums->tool_work += total.work;
    record_stage(p, job, sums, st, u_next, length_unit, fresh_energy, counters, link,
                 Vec3d{total.momentum[0], total.momentum[1], total.momentum[2]}, total.mass);
  }
}

// Dynamic mass scaling (JobParams::mass_interval), element side: each tetrahedron's
// stiffening at u_n; past the gate it asks its corners for growth x its rest need [kg/m^3]
// (atomicMax on the float bits: the values are positive).
__global__ void __launch_bounds__(kBlock)
    mass_check_kernel(TetParams tp, const double* __restrict__ u, const float* __restrict__ tet_need,
                      float* __restrict__ vertex_need, float gate, int law) {
  wait_for_previous_kernel();
  allow_next_kernel();
  const int t = static_cast<int>(blockIdx.x * blockDim.x + threadIdx.x);
  if (t >= tp.tet_count) return;
  const int4 id = tp.vertices[t];
  float lambda, mu;
  const TetShape<float> s = load_shape(tp, t, &lambda, &mu);
  Vec3f du[3];
  load_relative_displacements(u, id, du);
  const Mat3f h = tet_displacement_gradient_from_edges(s, du);
  const float growth = tet_stiffening(s, h, lambda, mu, static_cast<StiffeningLaw>(law));
  if (!(growth > gate)) return;
  const float need = growth * tet_need[t];
  const int corner[4] = {id.x, id.y, id.z, id.w};
  for (int c = 0; c < 4; ++c)
    atomicMax(reinterpret_cast<int*>(vertex_need + corner[c]), __float_as_int(need));
}

// Dynamic mass scaling, vertex side: a free vertex whose mass falls short of its elements' need
// takes it (set_vertex_mass: the damping rate gamma / M is kept, so b stays and c scales with
// 1 / M), keeping its momentum (job_raised_prev, as the CPU job).
__global__ void __launch_bounds__(kBlock)
    mass_raise_kernel(const float* __restrict__ vertex_need, const float* __restrict__ volume,
                      double* __restrict__ mass, float2* __restrict__ update,
                      const double* __restrict__ u, double* __restrict__ u_prev,
                      unsigned long long* __restrict__ raises, int vertex_count) {
  wait_for_previous_kernel();
  allow_next_kernel();
  const int v = static_cast<int>(blockIdx.x * blockDim.x + threadIdx.x);
  if (v >= vertex_count) return;
  const float need = vertex_need[v];
  if (!(need > 0)) return;
  const double m_new = static_cast<double>(need) * static_cast<double>(volume[v]);
  const double m = mass[v];
  float2 k = update[v];
  if (!(m_new > m) || !(k.y > 0)) return;
  k.y = static_cast<float>(k.y * (m / m_new));
  update[v] = k;
  mass[v] = m_new;
  for (int c = 0; c < 3; ++c) {
    const size_t i = 3 * static_cast<size_t>(v) + static_cast<size_t>(c);
    u_prev[i] = job_raised_prev(u[i], u_prev[i], m, m_new);
  }
  atomicAdd(raises, 1ull);
}

}  // namespace zona::cuda
