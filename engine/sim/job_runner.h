// Who runs the injection step's stages (engine/sim/job.h): the CPU runner here, on the State's
// thread pool, or the CUDA runner (kernels/), where the state lives in device memory. Both take
// the same JobSetup and produce the same JobRecords; the simulation never looks at which.
#pragma once

#include <array>
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "engine/core/base.h"
#include "engine/sim/job.h"
#include "engine/fem/model.h"
#include "engine/fem/state.h"
#include "engine/fem/step_status.h"

namespace zona {

/// What a runner needs besides the model: the parameters and the tool vertices.
struct JobSetup {
  JobParams params;
  /// Vertices the tools can touch (the boundary surface), model indices, ascending.
  std::vector<int32_t> tool_vertices;
  std::vector<double> tool_area;    ///< rest tributary area [m^2], (tool vertex count)
  std::vector<Vec3d> tool_suction;  ///< full suction load [N], (tool vertex count)
  /// Surface triangles for the needle's face quadrature (JobParams::needle_on_faces): corners as
  /// indices into tool_vertices, and rest areas [m^2], (triangle count).
  std::vector<std::array<int32_t, 3>> tool_faces;
  std::vector<double> tool_face_area;
  /// Dynamic mass scaling (JobParams::mass_interval > 0): the density [kg/m^3] each element
  /// needs at rest for the scaling's safety, (S_e (dt / safety)^2 with S_e its stiffness
  /// measure), (tet_count); and each vertex's lumped volume [m^3], (vertex_count).
  std::vector<double> tet_rest_need;
  std::vector<double> vertex_volume;
  /// Most samples kept before the host takes them (a full buffer is reported, never grown).
  size_t sample_capacity = 1 << 16;
};

/// The records a host-side runner (the CPU job's, the prescribed boundary's) keeps for the run
/// driver between its reads: the newest step's record and the samples, in a buffer sized once (a
/// full buffer is reported by take, never grown).
class HostRecords {
 public:
  explicit HostRecords(size_t capacity) { samples_.reserve(capacity); }
  /// Publishes a step's record, and keeps `sample` as a sample when `keep` (usually the record
  /// itself).
  void publish(const JobRecord& record, bool keep, const JobRecord& sample) {
    latest_ = record;
    has_latest_ = true;
    if (!keep) return;
    if (samples_.size() < samples_.capacity())
      samples_.push_back(sample);
    else
      lost_ = true;
  }
  /// JobRunner::latest.
  bool latest(JobRecord* out) const {
    if (!has_latest_) return false;
    *out = latest_;
    return true;
  }
  /// JobRunner::take_samples.
  bool take(std::vector<JobRecord>& out) {
    out.insert(out.end(), samples_.begin(), samples_.end());
    samples_.clear();
    const bool ok = !lost_;
    lost_ = false;
    return ok;
  }

 private:
  std::vector<JobRecord> samples_;
  JobRecord latest_;
  bool has_latest_ = false, lost_ = false;
};

/// Runs the step's stages where the state lives. Nothing on the step path allocates.
class JobRunner {
 public:
  virtual ~JobRunner() = default;
  /// Advances `steps` steps: the CPU runs them; the GPU enqueues them and returns while they
  /// run (it waits only when more than a bounded number of steps are in flight). A halted job
  /// (a step failed its health check) advances no further.
  virtual Status advance(int64_t steps) = 0;
  /// The newest finished step's record; false before the first.
  virtual bool latest(JobRecord* out) = 0;
  /// Appends the samples recorded since the last call to `out`; false when samples were lost
  /// because the buffer filled up between two calls.
  virtual bool take_samples(std::vector<JobRecord>& out) = 0;
  /// Waits until every step asked for has finished.
  virtual Status finish() = 0;
  /// Copies u, u_prev, force, time and step count into `state` (after finish()).
  virtual Status download(State& state) = 0;
  /// Sets the needle tip [m] for the steps advanced from now on (haptics); the script is not
  /// used any more.
  virtual void set_tip(Vec3d tip) = 0;
  /// Steps asked for so far.
  virtual int64_t steps_advanced() const = 0;
  /// Bytes that crossed between host and device memory for the steps so far (records,
  /// samples, poses; 0 where the state lives on the host).
  virtual uint64_t host_bytes_moved() const = 0;
  /// One line: where the stages run.
  virtual std::string description() const = 0;
  /// Vertex masses the dynamic mass scaling raised so far (call after finish()).
  virtual int64_t mass_raises() = 0;
};

/// A runner that steps on the host over the simulation's own state (the CPU job's, the
/// prescribed boundary's): its records are a HostRecords, and nothing is in flight or elsewhere.
class HostJobRunner : public JobRunner {
 public:
  explicit HostJobRunner(size_t sample_capacity) : records_(sample_capacity) {}
  bool latest(JobRecord* out) override { return records_.latest(out); }
  bool take_samples(std::vector<JobRecord>& out) override { return records_.take(out); }
  Status finish() override { return {}; }
  Status download(State&) override { return {}; }  // the state is the simulation's own
  uint64_t host_bytes_moved() const override { return 0; }

 protected:
  HostRecords records_;
};

/// Which surface vertices the tools touch in a state (for written frames, off the step path):
/// marks[v] is 1 where the needle acts on vertex v (inside the needle, or a corner of a triangle
/// with a quadrature point inside it), 2 where the holding pipette's rim does, else 0; tip is
/// the needle's load pose [m]. (vertex_count)
std::vector<uint8_t> job_contact_marks(const JobSetup& setup, const Model& model,
                                       const State& state, Vec3d tip);

/// The elastic and integrate stages of a body whose internal forces are not the FEM element
/// pass (the particle model's springs, dashpots and hydraulic pressure): one explicit step with
/// zona::step's contract over `state` (the tools' loads in state.external_force; u, u_prev,
/// force, diag and time advanced in place, also when the body runs on a Backend).
class BodyStep {
 public:
  virtual ~BodyStep() = default;
  virtual StepStatus step(const Model& model, State& state) = 0;
  /// One line: where the body's stages run.
  virtual std::string description() const = 0;
};

/// The CPU runner over the simulation's own model and state (kept by reference). `body`, when
/// given (and kept by reference), runs the elastic and integrate stages instead of the FEM
/// element pass (zona::step).
std::unique_ptr<JobRunner> make_cpu_job_runner(Model& model, State& state, const JobSetup& setup,
                                               BodyStep* body = nullptr);

}  // namespace zona
