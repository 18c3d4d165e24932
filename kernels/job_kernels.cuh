// Kernels of the device-resident injection step (engine/job.h's stages): the tools over the
// surface vertices, the centred-difference update with the tool loads and stiffness damping,
// and the one-thread record that measures, tests and publishes the step. Thin wrappers: the
// physics is engine/job.h's ZONA_HOST_DEVICE functions, the same the CPU runner calls.
// Included by cuda_job.cu only.
#pragma once

#include <climits>

#include "engine/job.h"
#include "kernels/step_kernels.cuh"

namespace zona::cuda {

/// The tool vertices (the boundary surface) in device order.
struct ToolParams {
  const int32_t* vertex = nullptr;   ///< device vertex index, (count)
  const double* rest = nullptr;      ///< rest position [m], (3 count)
  const double* area = nullptr;      ///< rest tributary area [m^2], (count)
  const double* mass = nullptr;      ///< lumped mass [kg], (count)
  const double* suction = nullptr;   ///< full suction load [N], (3 count)
  float4* tool_force = nullptr;      ///< tool load per device vertex [force_unit], (vertex_count)
  int count = 0;
  double length_unit = 1;  ///< [m]
  double force_unit = 1;   ///< [N]
};

/// The newest record, published with a sequence number (odd while it is being written).
struct LatestRecord {
  unsigned long long seq = 0;
  JobRecord record;
};

/// The needle pose the host hands in (haptics), with a sequence number (odd while written).
struct TipMailbox {
  unsigned long long seq = 0;
  double tip[3] = {0, 0, 0};  ///< [m]
};

/// Device-side counters of the record kernel.
struct JobCounters {
  unsigned long long samples = 0;  ///< samples written so far
  unsigned long long latest_seq = 0;
};

/// Where the record kernel publishes: mapped pinned host memory (written over the bus, read by
/// the host without any stream synchronisation).
struct JobHostLink {
  JobRecord* samples = nullptr;               ///< ring of samples, (capacity)
  unsigned long long* sample_count = nullptr; ///< samples written so far
  unsigned long long capacity = 0;
  LatestRecord* latest = nullptr;
  const TipMailbox* tip = nullptr;
};

/// Stage 1 (tools), one thread per tool vertex: its load into tool_force, the sums of the
/// step (needle and rim forces, contacts, the tools' work) into `sums`.
__global__ void __launch_bounds__(kBlock)
    job_tool_kernel(JobParams p, ToolParams tl, const double* __restrict__ u,
                    const double* __restrict__ u_prev, const JobState* job, JobSums* sums) {
  wait_for_previous_kernel();
  allow_next_kernel();
  if (job->halted) return;  // the same for every thread: the last record kernel wrote it
  const int i = blockIdx.x * kBlock + threadIdx.x;
  double nf[3] = {0, 0, 0}, rf[3] = {0, 0, 0};
  double needle_contacts = 0, rim_contacts = 0;
  if (i < tl.count) {
    const int v = tl.vertex[i];
    const double lu = tl.length_unit;
    const double* un = u + 3 * static_cast<size_t>(v);
    const double* up = u_prev + 3 * static_cast<size_t>(v);
    const Vec3d du{(un[0] - up[0]) * lu, (un[1] - up[1]) * lu, (un[2] - up[2]) * lu};
    ToolVertexInput in;
    in.x = Vec3d{tl.rest[3 * i] + un[0] * lu, tl.rest[3 * i + 1] + un[1] * lu,
                 tl.rest[3 * i + 2] + un[2] * lu};
    in.velocity = (1.0 / p.dt) * du;
    in.area = tl.area[i];
    in.mass = tl.mass[i];
    in.suction = Vec3d{tl.suction[3 * i], tl.suction[3 * i + 1], tl.suction[3 * i + 2]};
    const ToolVertexForce f = tool_vertex_force(p, job->pose, in);
    const double inv = 1.0 / tl.force_unit;
    tl.tool_force[v] = make_float4(float(f.force.x * inv), float(f.force.y * inv),
                                   float(f.force.z * inv), 0.0f);
    for (int c = 0; c < 3; ++c) {
      nf[c] = f.needle[c];
      rf[c] = f.rim[c];
    }
    needle_contacts = f.needle_contact;
    rim_contacts = f.rim_contact;
  }
  // Block sums, one atomic each (the order of the blocks varies: the last bits of the sums do).
  for (int c = 0; c < 3; ++c) block_sum_add(nf[c], &sums->needle_force[c]);
  for (int c = 0; c < 3; ++c) block_sum_add(rf[c], &sums->rim_force[c]);
  using Reduce = cub::BlockReduce<int, kBlock>;
  __shared__ typename Reduce::TempStorage temp;
  const int nc = Reduce(temp).Sum(static_cast<int>(needle_contacts));
  __syncthreads();
  const int rc = Reduce(temp).Sum(static_cast<int>(rim_contacts));
  if (threadIdx.x == 0) {
    if (nc) atomicAdd(&sums->needle_contacts, nc);
    if (rc) atomicAdd(&sums->rim_contacts, rc);
  }
}

/// Stages 2 and 4 after the element pass, one thread per vertex: the loads (tool load plus the
/// stiffness damping k (f(u_{n-1}) - f(u_{n-2})), lagged one step as on the CPU), the
/// centred-difference update, the kinetic energy, the tools' work over the step (centred,
/// f_n . (u_{n+1} - u_{n-1}) / 2, as on the CPU). FIXED: the fixed-point scatter's sums.
template <bool FIXED>
__global__ void __launch_bounds__(kBlock)
    job_update_kernel(VertexParams vp, const float4* __restrict__ tool_force, float4* damp,
                      float4* force_prev, float damping_rate, int substep, DeviceStatus* st,
                      JobSums* sums) {
  wait_for_previous_kernel();
  allow_next_kernel();
  if (halted(st, substep)) return;
  const int v = blockIdx.x * kBlock + threadIdx.x;
  VertexDiag d;
  double work = 0;
  if (v < vp.vertex_count) {
    const float4 f = scattered_force<FIXED>(vp, v);
    if constexpr (FIXED) {
      vp.force[v] = f;
      unsigned long long* clear = vp.fixed_clear + 3 * static_cast<size_t>(v);
      clear[0] = clear[1] = clear[2] = 0;
    } else {
      vp.force_clear[v] = make_float4(0, 0, 0, 0);
    }
    const float4 tool = tool_force[v];
    float4 fe = tool;
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
    update_vertex(vp, v, f, fe, substep, st, &d);
    if (tool.x != 0 || tool.y != 0 || tool.z != 0) {
      const double* up = vp.u_prev + 3 * static_cast<size_t>(v);
      const double* un = vp.u_next + 3 * static_cast<size_t>(v);
      work = 0.5 * vp.force_unit * vp.length_unit *
             (double(tool.x) * (un[0] - up[0]) + double(tool.y) * (un[1] - up[1]) +
              double(tool.z) * (un[2] - up[2]));
    }
  }
  block_sum_add(d.kinetic, &st->kinetic_energy);
  block_sum_add(work, &sums->tool_work);
}

/// Stages 5 (the deformation) and 6, one thread: reads the step's sums and status, runs
/// job_finish_step, publishes the record (latest, and a sample when due) to mapped host memory,
/// and resets the sums for the next step. A halted job stays halted: every kernel of a later
/// step returns at once (the status keeps failed_substep at 0).
__global__ void __launch_bounds__(kBlock)
    job_record_kernel(JobParams p, JobState* job, JobSums* sums, DeviceStatus* st,
                      const double* __restrict__ u_next, double length_unit,
                      JobCounters* counters, JobHostLink link) {
  wait_for_previous_kernel();
  allow_next_kernel();
  if (threadIdx.x != 0 || blockIdx.x != 0) return;
  if (job->halted) return;
  // The pose the host handed in (haptics), when a whole one is there.
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
  JobStepTotals tot;
  tot.elastic_energy = st->elastic_energy;
  tot.kinetic_energy = st->kinetic_energy;
  tot.status = st->flags;
  tot.first_bad = st->first_nonfinite != LLONG_MAX   ? st->first_nonfinite
                  : st->first_inverted != LLONG_MAX ? st->first_inverted
                                                    : -1;
  if (p.has_entry) {
    Vec3d e[3];
    for (int k = 0; k < 3; ++k) {
      const double* x = u_next + 3 * static_cast<size_t>(p.entry_vertex[k]);
      e[k] = Vec3d{x[0] * length_unit, x[1] * length_unit, x[2] * length_unit};
    }
    tot.deformation = job_entry_deformation(p, e[0], e[1], e[2]);
  }
  JobRecord r;
  const bool sample = job_finish_step(p, *job, *sums, tot, &r);
  if (sample) {
    const unsigned long long n = counters->samples;
    link.samples[n % link.capacity] = r;
    __threadfence_system();
    counters->samples = n + 1;
    *reinterpret_cast<volatile unsigned long long*>(link.sample_count) = n + 1;
  }
  const unsigned long long s = counters->latest_seq;
  volatile unsigned long long* out_seq = &link.latest->seq;
  *out_seq = s + 1;
  __threadfence_system();
  link.latest->record = r;
  __threadfence_system();
  *out_seq = s + 2;
  counters->latest_seq = s + 2;
  // The next step starts from clean sums; a halted job keeps every later kernel out.
  *sums = JobSums{};
  DeviceStatus fresh;
  if (job->halted) fresh.failed_substep = 0;
  *st = fresh;
}

}  // namespace zona::cuda
