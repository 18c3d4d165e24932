// The CPU runner of the injection step: engine/sim/job.h's stages over the State, in place.
#include "engine/sim/job_runner.h"

#include <algorithm>
#include <cmath>

#include "engine/fem/fem_element.h"
#include "engine/sim/integrator.h"
#include "engine/fem/mass_scaling.h"
#include "engine/sim/step_stage.h"

namespace zona {

// The record stage's status bits are the integrator's.
static_assert(kJobNonFinite == kStepNonFinite && kJobBlowUp == kStepEnergyBlowUp &&
              kJobToolBreach == kStepToolBreach && kJobNotQuasiStatic == kStepNotQuasiStatic);

namespace {

class CpuJobRunner final : public HostJobRunner {
 public:
  CpuJobRunner(Model& model, State& state, const JobSetup& setup, BodyStep* body)
      : HostJobRunner(setup.sample_capacity), model_(model), state_(state), setup_(setup),
        body_(body) {
    tool_force_.assign(setup.tool_vertices.size(), Vec3d{0, 0, 0});
    tool_u_before_.assign(setup.tool_vertices.size(), Vec3d{0, 0, 0});
    face_force_.assign(setup.tool_vertices.size(), Vec3d{0, 0, 0});
    needle_anchor_.assign(setup.tool_vertices.size(), StickAnchor{});
    tool_chunk_sums_.assign((setup.tool_vertices.size() + kToolChunk - 1) / kToolChunk, JobSums{});
    rim_anchor_.assign(setup.tool_vertices.size(), StickAnchor{});
    if (setup.params.needle.on_faces) {
      face_anchor_.assign(setup.tool_faces.size() * kFacePoints, StickAnchor{});
      face_out_.assign(setup.tool_faces.size(), ToolFaceForce{});
      face_hit_.assign(setup.tool_faces.size(), 0);
      if (setup.params.puncture.criterion == kJobCriterionStrain)
        face_strain_.assign(setup.tool_faces.size(), 0.0);
    }
    force_prev_.assign(model.vertex_count(), Vec3d{0, 0, 0});
    drift_chunks_.assign((model.vertex_count() + kDriftChunk - 1) / kDriftChunk, DriftChunk{});
    if (setup.params.mass.interval > 0) growth_.assign(model.tet_count(), 1.0);
    job_.pose.tip = setup.params.needle.start;
    job_follow_tip(setup_.params, job_);
    job_set_pose(setup_.params, job_);
    // The state starts without loads: the stages own external_force from here on.
    std::fill(state_.external_force.begin(), state_.external_force.end(), Vec3d{0, 0, 0});
  }

  Status advance(int64_t steps) override {
    for (int64_t i = 0; i < steps && !job_.halted; ++i) step_once();
    advanced_ += steps;
    return {};
  }

  void set_tip(Vec3d tip) override {
    // Taken up at the end of the step, as the GPU's record stage takes up its mailbox.
    job_.external_tip = 1;
    job_.external_tip_value = tip;
  }

  int64_t steps_advanced() const override { return advanced_; }
  int64_t mass_raises() override { return mass_raises_; }

  std::string description() const override {
    if (body_) return "cpu: tool stages on the host; body: " + body_->description();
    return "cpu: " + std::to_string(state_.pool->thread_count()) +
           " thread(s), float64, stages in place";
  }

 private:
  // Dynamic mass scaling (JobParams::mass_interval): every element's stiffening at u_n, in
  // parallel; then, serially, the elements past the gate raise their corners' masses.
  void raise_masses() {
    const size_t nt = model_.tet_count();
    constexpr int64_t kChunk = 2048;
    const int64_t chunks = static_cast<int64_t>((nt + kChunk - 1) / kChunk);
    state_.pool->run(
        chunks,
        [](void* context, int64_t begin, int64_t end) {
          auto* self = static_cast<CpuJobRunner*>(context);
          const Model& m = self->model_;
          const auto law = static_cast<StiffeningLaw>(self->setup_.params.mass.law);
          const size_t last = std::min(m.tet_count(), static_cast<size_t>(end * kChunk));
          for (size_t t = static_cast<size_t>(begin * kChunk); t < last; ++t) {
            Vec3d u[4];
            for (int c = 0; c < 4; ++c) u[c] = self->state_.u[static_cast<size_t>(m.tets[t][c])];
            const Mat3d h = tet_displacement_gradient(m.tet_shape[t], u);
            const Lame& lame = m.tet_lame(t);
            self->growth_[t] = tet_stiffening(m.tet_shape[t], h, lame.lambda, lame.mu, law);
          }
        },
        this);
    for (size_t t = 0; t < nt; ++t) {
      const double need = job_mass_need(setup_.params, growth_[t], setup_.tet_rest_need[t]);
      if (!(need > 0)) continue;
      for (int32_t corner : model_.tets[t]) {
        const size_t v = static_cast<size_t>(corner);
        const double mass = need * setup_.vertex_volume[v];
        const double before = model_.vertex_mass[v];
        if (mass > before && !model_.vertex_fixed[v]) {
          Vec3d& prev = state_.u_prev[v];
          for (int k = 0; k < 3; ++k)
            prev[k] = job_raised_prev(state_.u[v][k], prev[k], before, mass);
          set_vertex_mass(model_, v, mass);
          ++mass_raises_;
        }
      }
    }
  }

  // The needle's load on tool faces [begin, end) into face_out_ / face_hit_.
  void needle_faces(size_t begin, size_t end) {
    const JobParams& p = setup_.params;
    for (size_t f = begin; f < end; ++f) {
      face_hit_[f] = 0;
      // Positions first: most triangles are far from the needle and need nothing else.
      ToolFaceInput in;
      for (int c = 0; c < 3; ++c) {
        const size_t k = static_cast<size_t>(setup_.tool_faces[f][static_cast<size_t>(c)]);
        const size_t v = static_cast<size_t>(setup_.tool_vertices[k]);
        in.x[c] = model_.rest_positions[v] + state_.u[v];
      }
      if (p.puncture.criterion == kJobCriterionStrain) {
        face_strain_[f] = 0;
        if (!job_.puncture.punctured && needle_face_near(p.needle, job_.pose, in.x)) {
          Vec3d rest[3];
          for (int c = 0; c < 3; ++c)
            rest[c] = model_.rest_positions[static_cast<size_t>(
                setup_.tool_vertices[static_cast<size_t>(setup_.tool_faces[f][static_cast<size_t>(c)])])];
          face_strain_[f] = needle_face_strain(rest, in.x);
        }
      }
      if (!needle_face_may_touch(p.needle, job_.pose, in)) continue;
      in.area = setup_.tool_face_area[f];
      face_out_[f] = needle_face_force(p.needle, job_.pose, in, &face_anchor_[f * kFacePoints]);
      face_hit_[f] = face_out_[f].contacts > 0 ? 1 : 0;
    }
  }

  // Chunks [0, count) of a per-chunk stage on the pool, each writing only its own vertices or
  // slot; callers sum the slots in chunk order (the same sums on any thread count).
  template <void (CpuJobRunner::*kStage)(size_t)>
  void run_chunks(size_t count) {
    state_.pool->run(
        static_cast<int64_t>(count),
        [](void* context, int64_t begin, int64_t end) {
          auto* self = static_cast<CpuJobRunner*>(context);
          for (int64_t c = begin; c < end; ++c) (self->*kStage)(static_cast<size_t>(c));
        },
        this);
  }

  // Drift damping on the vertices of chunk `chunk` (kDriftChunk of them): the step's load
  // m drift_accel into external_force (after the stiffness damping's, which it adds to), and
  // after the update the chunk's momentum m (u_{n+1} - u_n) / dt and mass.
  void drift_load(size_t chunk) {
    const bool add = setup_.params.damping.stiffness_rate > 0;
    const Vec3d a = job_.drift_accel;
    const size_t end = std::min(model_.vertex_count(), (chunk + 1) * kDriftChunk);
    for (size_t v = chunk * kDriftChunk; v < end; ++v) {
      const Vec3d f = model_.vertex_fixed[v] ? Vec3d{0, 0, 0} : model_.vertex_mass[v] * a;
      Vec3d& ext = state_.external_force[v];
      ext = add ? ext + f : f;
    }
  }
  void drift_momentum(size_t chunk) {
    const double inv_dt = 1.0 / setup_.params.dt;
    DriftChunk sum;
    const size_t end = std::min(model_.vertex_count(), (chunk + 1) * kDriftChunk);
    for (size_t v = chunk * kDriftChunk; v < end; ++v) {
      if (model_.vertex_fixed[v]) continue;
      const double m = model_.vertex_mass[v];
      sum.momentum += (m * inv_dt) * (state_.u[v] - state_.u_prev[v]);
      sum.mass += m;
    }
    drift_chunks_[chunk] = sum;
  }

  // Stage 1 on the tool vertices of chunk `chunk` (kToolChunk of them): the vertex tools plus the
  // faces' loads gathered before, into external_force, and the chunk's sums.
  void tool_vertices(size_t chunk) {
    const JobParams& p = setup_.params;
    const bool damping = p.damping.stiffness_rate > 0 || p.damping.drift > 0;
    JobSums& sums = tool_chunk_sums_[chunk];
    sums = JobSums{};
    const size_t end = std::min(setup_.tool_vertices.size(), (chunk + 1) * kToolChunk);
    for (size_t i = chunk * kToolChunk; i < end; ++i) {
      const size_t v = static_cast<size_t>(setup_.tool_vertices[i]);
      ToolVertexInput in;
      in.x = model_.rest_positions[v] + state_.u[v];
      in.area = setup_.tool_area[i];
      in.suction = setup_.tool_suction[i];
      if (p.rim.damping > 0) {
        in.velocity = (1.0 / p.dt) * (state_.u[v] - state_.u_prev[v]);
        in.mass = model_.vertex_mass[v];
      }
      ToolVertexForce f = tool_vertex_force(p.needle, p.rim, p.dt, job_.pose, in, &needle_anchor_[i], &rim_anchor_[i]);
      f.force += face_force_[i];
      Vec3d& ext = state_.external_force[v];
      ext = damping ? ext + f.force : f.force;
      for (int c = 0; c < 3; ++c) {
        sums.needle_force[c] += f.needle[c];
        sums.rim_force[c] += f.rim[c];
      }
      sums.needle_contacts += f.needle_contact;
      sums.needle_depth = std::max(sums.needle_depth, f.needle_depth);
      sums.rim_contacts += f.rim_contact;
      tool_force_[i] = f.force;
      tool_u_before_[i] = state_.u_prev[v];
    }
  }

  // One step as its stages (engine/sim/step_stage.h), one per line.
  void step_once() {
    const JobParams& p = setup_.params;
    if (p.mass.interval > 0 && steps_run_ % p.mass.interval == 0) raise_masses();  // masses
    ++steps_run_;
    apply_loads();                                        // loads
    JobSums sums = tool_forces();                         // tools (anchors committed in place)
    const StepStatus status = elastic_and_integrate();    // elastic, integrate
    const JobStepTotals tot = measure(status, sums);      // measure
    record(sums, tot);                                    // record, commit, puncture
  }

  // StepStage::kLoads: stiffness damping, lagged one step (f(u_{n-1}) - f(u_{n-2})), on every
  // vertex, and the drift damping's load (job_drift_update) on every free vertex.
  void apply_loads() {
    const JobParams& p = setup_.params;
    if (p.damping.stiffness_rate > 0) {
      const double k = p.damping.stiffness_rate;
      std::vector<Vec3d>& ext = state_.external_force;
      for (size_t v = 0; v < model_.vertex_count(); ++v)
        ext[v] = job_stiffness_damping_load(k, state_.force[v], &force_prev_[v]);
    }
    if (p.damping.drift > 0) run_chunks<&CpuJobRunner::drift_load>(drift_chunks_.size());
  }

  // StepStage::kTools: the needle on the surface triangles (face quadrature), then every tool on
  // the surface vertices, into external_force; returns the step's sums.
  JobSums tool_forces() {
    const JobParams& p = setup_.params;
    JobSums sums;
    if (p.needle.on_faces) {
      // Every triangle on the pool (each owns its anchors and its output slot), then the few
      // that touch the needle are gathered in order (the same sums on any thread count).
      const size_t nf = setup_.tool_faces.size();
      constexpr int64_t kChunk = 1024;
      state_.pool->run(
          static_cast<int64_t>((nf + kChunk - 1) / kChunk),
          [](void* context, int64_t begin, int64_t end) {
            auto* self = static_cast<CpuJobRunner*>(context);
            self->needle_faces(static_cast<size_t>(begin * kChunk),
                               std::min(self->face_out_.size(), static_cast<size_t>(end * kChunk)));
          },
          this);
      std::fill(face_force_.begin(), face_force_.end(), Vec3d{0, 0, 0});
      const bool strain = p.puncture.criterion == kJobCriterionStrain;
      for (size_t f = 0; f < nf; ++f) {
        if (strain) sums.needle_strain = std::max(sums.needle_strain, face_strain_[f]);
        if (!face_hit_[f]) continue;
        const ToolFaceForce& ff = face_out_[f];
        for (int c = 0; c < 3; ++c) {
          face_force_[static_cast<size_t>(setup_.tool_faces[f][static_cast<size_t>(c)])] += ff.corner[c];
          for (int k = 0; k < 3; ++k) sums.needle_force[k] += ff.corner[c][k];
        }
        sums.needle_contacts += ff.contacts;
        sums.needle_depth = std::max(sums.needle_depth, ff.depth);
      }
    }
    // Every tool vertex on the pool, summed per fixed chunk, the chunks then in order (the same
    // sums on any thread count).
    run_chunks<&CpuJobRunner::tool_vertices>(tool_chunk_sums_.size());
    for (const JobSums& c : tool_chunk_sums_) {
      for (int k = 0; k < 3; ++k) {
        sums.needle_force[k] += c.needle_force[k];
        sums.rim_force[k] += c.rim_force[k];
      }
      sums.needle_contacts += c.needle_contacts;
      sums.rim_contacts += c.rim_contacts;
      sums.needle_depth = std::max(sums.needle_depth, c.needle_depth);
    }
    return sums;
  }

  // StepStage::kElastic and kIntegrate: the element pass and the centred-difference update
  // (integrator.cpp's step), or the body's own (the particle model).
  StepStatus elastic_and_integrate() {
    StepStatus status = body_ ? body_->step(model_, state_) : step(model_, state_);
    // The integrator's own energy test counts the damping loads as work put in; the job's
    // budget (tools only) replaces it.
    status &= ~static_cast<StepStatus>(kStepEnergyBlowUp);
    return status;
  }

  // StepStage::kMeasure: the tools' work over the step, the energies, the deformation at the
  // entry point and (every kDriftInterval steps with drift damping) the cell's momentum.
  JobStepTotals measure(StepStatus status, JobSums& sums) {
    const JobParams& p = setup_.params;
    // The tools' work over the step, centred: f_n . (u_{n+1} - u_{n-1}) / 2.
    for (size_t i = 0; i < setup_.tool_vertices.size(); ++i) {
      const size_t v = static_cast<size_t>(setup_.tool_vertices[i]);
      sums.tool_work += 0.5 * dot(tool_force_[i], state_.u[v] - tool_u_before_[i]);
    }
    JobStepTotals tot;
    tot.elastic_energy = state_.diag.elastic_energy;
    tot.kinetic_energy = state_.diag.kinetic_energy;
    tot.status = status;
    tot.first_bad = state_.diag.first_nonfinite >= 0 ? state_.diag.first_nonfinite
                                                     : state_.diag.first_inverted;
    if (p.damping.drift > 0 && (steps_run_ - 1) % kDriftInterval == 0) {
      // Per fixed chunk on the pool, the chunks then in order (the same sums on any thread
      // count).
      run_chunks<&CpuJobRunner::drift_momentum>(drift_chunks_.size());
      for (const DriftChunk& c : drift_chunks_) {
        tot.momentum += c.momentum;
        tot.mass += c.mass;
      }
    }
    if (p.record.has_entry) {
      const auto& u = state_.u;
      tot.deformation = job_entry_deformation(p, u[static_cast<size_t>(p.record.entry_vertex[0])],
                                              u[static_cast<size_t>(p.record.entry_vertex[1])],
                                              u[static_cast<size_t>(p.record.entry_vertex[2])]);
    }
    return tot;
  }

  // StepStage::kRecord, kCommit and kPuncture (job_finish_step), and the sample.
  void record(const JobSums& sums, const JobStepTotals& tot) {
    JobRecord r;
    const bool sample = job_finish_step(setup_.params, job_, sums, tot, &r);
    records_.publish(r, sample, r);
  }

  Model& model_;
  State& state_;
  JobSetup setup_;
  BodyStep* body_ = nullptr;  // the body's elastic and integrate stages, else the FEM pass
  JobState job_;
  std::vector<Vec3d> force_prev_;  // f(u_{n-2}) for the damping stage [N], (vertex_count)
  std::vector<Vec3d> tool_force_;     // this step's tool loads [N], (tool vertex count)
  std::vector<Vec3d> face_force_;     // the needle's face-quadrature loads [N], (tool vertex count)
  // Stick anchors of the friction: per tool vertex on the needle and on the rim, and per face
  // quadrature point (kFacePoints per triangle).
  std::vector<StickAnchor> needle_anchor_, rim_anchor_, face_anchor_;
  static constexpr size_t kToolChunk = 1024;  // tool vertices per chunk of stage 1
  std::vector<JobSums> tool_chunk_sums_;      // stage 1's sums per chunk
  struct DriftChunk {
    Vec3d momentum{0, 0, 0};
    double mass = 0;
  };
  static constexpr size_t kDriftChunk = 4096;  // vertices per chunk of the drift damping
  std::vector<DriftChunk> drift_chunks_;      // its momentum and mass per chunk
  std::vector<ToolFaceForce> face_out_;  // the step's load per face (valid where face_hit_)
  std::vector<uint8_t> face_hit_;        // the face had points inside the needle this step
  std::vector<double> face_strain_;      // needle_face_strain around the tip (strain criterion)
  std::vector<Vec3d> tool_u_before_;  // their u_{n-1} [m], (tool vertex count)
  std::vector<double> growth_;  // each element's stiffening at the last check, (tet_count)
  int64_t steps_run_ = 0;
  int64_t mass_raises_ = 0;     // vertex mass raises by the dynamic scaling
  int64_t advanced_ = 0;
};

}  // namespace

std::vector<uint8_t> job_contact_marks(const JobSetup& setup, const Model& model,
                                       const State& state, Vec3d tip) {
  const JobParams& p = setup.params;
  std::vector<uint8_t> marks(model.vertex_count(), 0);
  auto position = [&](size_t v) { return model.rest_positions[v] + state.u[v]; };
  auto in_needle = [&](Vec3d x) {
    return needle_sdf(tip, p.needle.direction, p.needle.radius, p.needle.flat != 0, x).distance < 0;
  };
  for (size_t i = 0; i < setup.tool_vertices.size(); ++i) {
    const size_t v = static_cast<size_t>(setup.tool_vertices[i]);
    const Vec3d x = position(v);
    if (p.rim.on && holding_sdf(p.rim.mouth, p.rim.axis, p.rim.inner_radius,
                                 p.rim.outer_radius, x, p.rim.edge_radius).distance < 0)
      marks[v] = 2;
    if (p.needle.on && !p.needle.on_faces && in_needle(x)) marks[v] = 1;
  }
  if (!p.needle.on || !p.needle.on_faces) return marks;
  for (const std::array<int32_t, 3>& f : setup.tool_faces) {
    Vec3d x[3];
    size_t v[3];
    for (int c = 0; c < 3; ++c) {
      const size_t k = static_cast<size_t>(f[static_cast<size_t>(c)]);
      v[c] = static_cast<size_t>(setup.tool_vertices[k]);
      x[c] = position(v[c]);
    }
    for (int q = 0; q < kFacePoints; ++q) {
      double b[3];
      if (!in_needle(face_point(x, q, b))) continue;
      for (size_t c : v) marks[c] = 1;
      break;
    }
  }
  return marks;
}

std::unique_ptr<JobRunner> make_cpu_job_runner(Model& model, State& state, const JobSetup& setup,
                                               BodyStep* body) {
  return std::make_unique<CpuJobRunner>(model, state, setup, body);
}

}  // namespace zona
