// The injection experiment: a Scene turned into a running simulation (mesh, model, backend,
// needle, holding pipette, contact, puncture) by a list of named setup stages (build,
// simulation.cpp), stepped in two halves so that the haptic thread can hand in the needle pose
// between them (as mj_step1 / mj_step2 do in MuJoCo; simulation_step.cpp).
//
// The step is the job's (engine/sim/job.h, stages named in step_stage.h) for every scene with a
// tool, the particle model's too (its body stages: particle_body.h): step2 hands one step to the
// runner, the pose entering through JobRunner::set_tip. A scene whose only load is an
// indentation boundary (a prescribed patch, no tool) takes the host step of the prescribed
// boundary (docs/architecture.md, "One engine"):
//
//   step1:  (nothing: the job's tool stage takes the script's pose)
//           -- set_needle_tip() may hand the hand's pose in here --
//   step2:  loads      stiffness damping
//           targets    the indented patch's displacement at t_{n+1}
//           integrate  internal forces + centred difference, the patch prescribed (the backend)
//           measure    the patch's reaction, the holder's force, energies
//           publish    the report (force, local stiffness)
//
// Nothing on the step path allocates: every buffer is sized at creation.
#pragma once

#include <atomic>
#include <cstdint>
#include <functional>
#include <memory>
#include <optional>
#include <span>
#include <string>
#include <vector>

#include "engine/sim/backend.h"
#include "engine/tools/contact.h"
#include "engine/tools/holding.h"
#include "engine/sim/integrator.h"
#include "engine/sim/job_runner.h"
#include "engine/mesh/mesh.h"
#include "engine/fem/model.h"
#include "engine/tools/needle.h"
#include "engine/particles/particle_model.h"
#include "engine/sim/particle_body.h"
#include "engine/tools/puncture.h"
#include "engine/sim/quasi_static.h"
#include "engine/scene/scene.h"
#include "engine/fem/state.h"

namespace zona {

/// How a Simulation is built. Defaults: the CPU reference, inversion-safe SVK.
struct SimulationOptions {
  /// Compute backend: empty steps the CPU reference in place (no copies). Otherwise called once
  /// at creation (e.g. with kernels/backend_factory.h's make_backend; the engine does not
  /// depend on kernels/): a returned CPU backend is dropped for the in-place path, any other
  /// runs the job's step on the device (engine/sim/job_runner.h), or the prescribed boundary's
  /// host step through the Backend interface.
  /// `notice` receives a one-line note (e.g. the auto fallback to the CPU).
  std::function<Result<std::unique_ptr<Backend>>(std::string* notice)> backend_factory;
  /// Compute backend of the particle model (scene model "particles"), called once at creation
  /// with the built particle model (kernels/particle_backend.h's make_particle_backend): a
  /// returned "cpu" backend is dropped for the in-place CPU reference, any other is driven
  /// through the Backend interface. Empty: the CPU reference in place. `backend_factory` is
  /// not used for the particle model.
  std::function<Result<std::unique_ptr<Backend>>(const ParticleModel&, std::string* notice)>
      particle_backend_factory;
  /// Threads of the CPU reference (0: one per hardware thread). Results do not depend on it.
  int threads = 0;
  /// Integrator sub-steps per host step on the Backend path of the prescribed boundary (>= 1).
  int backend_substeps = 1;
  /// SVK inversion remedy (ignored by the linear model, which cannot invert its stiffness).
  InversionHandling inversion = InversionHandling::kClampStretch;
  /// Travel over which the local stiffness estimate is taken [m].
  double stiffness_window = 20e-9;
  /// The device-resident job follows a tip handed in by set_needle_tip at most at this speed
  /// [m/s], one step at a time (JobParams::external_tip_max_speed); 0: it takes the tip as is.
  double external_tip_max_speed = 0;
  /// Tests: drive a CPU backend from the factory through the Backend interface (uploads,
  /// targets, downloads) instead of dropping it for the in-place path, so that the path the GPU
  /// backends take can be checked against the in-place reference on any machine.
  bool keep_cpu_backend = false;
};

/// What step2 publishes for the haptic and render threads (and the recorder).
struct NeedleReport {
  double time = 0;              ///< simulated time t_{n+1} [s]
  int64_t step = 0;             ///< steps taken
  Vec3d tip{0, 0, 0};           ///< needle tip [m]
  double travel = 0;            ///< tip travel from its start along the axis [m]
  double deformation = 0;       ///< membrane indentation at the tip along the axis [m]
  /// Axial reaction on the needle, resistance positive [N]; low-passed by needle.force_filter.
  double force = 0;
  double raw_force = 0;         ///< the same before the filter [N]
  /// Force the needle applies to the cell [N] (the indented patch's reaction where the scene
  /// has no needle).
  Vec3d force_vector{0, 0, 0};
  double stiffness = 0;         ///< local d force / d travel [N/m]
  int32_t contacts = 0;         ///< contact points inside the needle (face quadrature points or vertices)
  int32_t holding_contacts = 0; ///< vertices inside the holding pipette's rim
  Vec3d holding_force{0, 0, 0}; ///< force the holding pipette applies to the cell [N]
  double max_strain = 0;        ///< the zona's stretch around the tip (strain criterion) [-]
  double elastic_energy = 0;    ///< [J]
  double kinetic_energy = 0;    ///< [J]
  bool punctured = false;
  StepStatus status = kStepOk;  ///< the integrator's flags of this step
  /// The quasi-static check: this step's imbalance and kinetic share, the run's worst and its
  /// first failed step (engine/sim/quasi_static.h).
  QuasiStaticState quasi;
};

/// The axial force a haptic device renders [N], resistance positive: the load cell's filtered
/// force (needle.force_filter) while the needle loads the cell, the raw reaction from the
/// puncture on. The raw reaction jitters while a hand moves the tip against the membrane, and a
/// force that changes on its own is an active source to the coupling (docs/haptics.md); after the
/// puncture the load is the prescribed release (force_drop over drop_time, then the shaft's
/// drag), smooth by construction, and the filter would only delay the drop by its time constant
/// in simulated time, which a simulation slower than real time stretches in wall time (the 200k
/// cell at 0.04x real time: 2 ms of filter, 50 ms of wall).
inline double haptic_axial_force(const NeedleReport& r) {
  return r.punctured ? r.raw_force : r.force;
}

struct RunOptions;
struct RunResult;

/// Angular frequency [rad/s] of a cell of total (scaled) mass `mass` [kg] swinging on a suction
/// holder of bore radius `bore_radius` [m]: the held side's stiffness taken as Boussinesq's
/// rigid flat punch of that radius on an elastic half-space of the stiffest material,
/// k = 2 E a / (1 - nu^2), and omega = sqrt(k / mass); 0 without a material or a mass. On the
/// mouse cells it is within a factor of about 1.5 of the swing the runs show (docs/injection.md).
double holder_swing_omega(const std::vector<Material>& materials, double bore_radius, double mass);

/// One injection experiment. Create with Simulation::create; step with step() or step1/step2.
class Simulation {
 public:
  /// Builds mesh, model, backend and tools from a scene. Errors (one line): unsupported model,
  /// bad materials, holding patch empty, backend unavailable, nothing that ends the run.
  static Result<std::unique_ptr<Simulation>> create(const Scene& scene,
                                                    const SimulationOptions& options = {});
  ~Simulation();
  Simulation(const Simulation&) = delete;
  Simulation& operator=(const Simulation&) = delete;

  /// First half: nothing to do before the pose is handed in. The tool stage takes the needle's
  /// pose itself, from its script (needle_scripted_tip) or from set_needle_tip.
  void step1() {}
  /// Between the halves: replace the needle tip pose for this step [m] (haptic coupling).
  void set_needle_tip(Vec3d tip);
  /// Second half: the job's step, or the prescribed boundary's (above).
  StepStatus step2();
  /// step1 then step2.
  StepStatus step() {
    step1();
    return step2();
  }

  /// Simulated time at which the scene's experiment ends [s].
  double end_time() const { return end_time_; }
  /// True once time has reached end_time (or a step was not advanced).
  bool finished() const;

  const Scene& scene() const { return scene_; }
  const Mesh& mesh() const { return mesh_; }
  const Model& model() const { return model_; }
  /// The host state (on the Backend path: as of the last download, i.e. the last step).
  const State& state() const { return state_; }
  const ContactSurface& surface() const { return surface_; }
  const NeedleScript& needle_script() const { return script_; }
  const NeedleReport& report() const { return report_; }
  const PunctureRecord& puncture() const { return job_puncture_; }
  const std::optional<HoldingSetup>& holding() const { return holding_; }
  /// Rest position where the needle axis enters the cell [m].
  Vec3d entry_point() const { return entry_point_; }
  /// Cell extent along the needle axis at rest [m] (the diameter for a ball).
  double cell_diameter() const { return cell_diameter_; }
  /// Backend description ("cpu reference: 2 thread(s), float64", ...).
  const std::string& backend_description() const { return backend_description_; }
  /// The backend driven through the Backend interface (the GPU), or null on the in-place CPU
  /// path: for kernels reading its device state (kernels/surface_interop.h). Do not step it.
  const Backend* backend() const { return backend_.get(); }
  /// Notes from setup (skipped materials, backend fallback), one line each.
  const std::vector<std::string>& notes() const { return notes_; }
  /// True when the step runs as the device-resident job (penalty contact, engine/sim/job.h): the
  /// stages run where the state lives, and state() is brought up to date by sync_state().
  bool job_mode() const { return job_ != nullptr; }
  /// The job's runner, or null on the prescribed boundary's path.
  JobRunner* job() { return job_; }
  /// The runner the run driver steps: the job's, or the prescribed boundary's host step
  /// (engine/sim/boundary_runner.h).
  JobRunner& runner() { return job_ ? *job_ : *boundary_runner_; }
  /// Samples a runner keeps between two takes (JobSetup::sample_capacity on the job path; the
  /// whole run's rows on the host path).
  size_t sample_capacity() const { return sample_capacity_; }
  /// The needle's direction of travel (unit) [-].
  Vec3d needle_direction() const {
    return job_ ? job_setup_.params.needle.direction : script_.direction;
  }
  /// The job's setup (tool vertices, parameters); empty on the host path.
  const JobSetup& job_setup() const { return job_setup_; }
  /// The static solver (engine/sim/static_run.h) publishes its accepted state: the host
  /// state's displacement and time, the report and the puncture, for frames and outputs.
  void publish_static_state(std::span<const Vec3d> u, const NeedleReport& report,
                            const PunctureRecord& puncture);
  /// Makes state() current: on the job path waits for the steps in flight and downloads the
  /// state from where it lives (a frame, a test); otherwise nothing to do. Not on the step path.
  Status sync_state();
  /// The quasi-static check's limits (engine/sim/quasi_static.h), the same on both step paths.
  const QuasiStaticLimits& quasi_limits() const { return quasi_limits_; }
  /// The particle model (scene model "particles"), else null.
  const ParticleModel* particle_model() const { return particles_.get(); }
  /// Particle model: relative change of the enclosed volume at the last step, (V - V0) / V0 [-].
  double volume_change_rel() const {
    return particle_body_ ? particle_body_->volume_change_rel() : volume_change_rel_;
  }
  /// Particle model: largest |V - V0| / V0 seen so far [-].
  double volume_change_max_rel() const {
    return particle_body_ ? particle_body_->volume_change_max_rel() : volume_change_max_rel_;
  }

 private:
  Simulation() = default;
  /// Setup: the named setup stages below, in order (simulation.cpp).
  Status build(const Scene& scene, const SimulationOptions& options);

  // What the setup stages hand on to later ones.
  struct SetupContext {
    Vec3d direction{1, 0, 0};    // the needle's axis (unit) [-]
    std::vector<int32_t> fixed;  // fixed vertices, ascending
    bool job_path = false;       // the penalty step (the job) runs this scene
  };
  // Setup stages (one line each in build).
  Status setup_body(SetupContext& setup);
  Status setup_surface(SetupContext& setup);
  Status setup_needle(SetupContext& setup);
  Status setup_holding(SetupContext& setup);
  Status setup_model(SetupContext& setup);
  Status setup_mass_scaling(SetupContext& setup);
  Status setup_state(SetupContext& setup);
  Status setup_end_time(SetupContext& setup);
  Status setup_scratch(SetupContext& setup);
  Status setup_quasi_static(SetupContext& setup);
  Status setup_job(SetupContext& setup);
  Status setup_backend(SetupContext& setup);
  Status setup_damping(SetupContext& setup);
  Status setup_runner(SetupContext& setup);

  // Stages of the prescribed boundary's step2 (one line each there; simulation_step.cpp).
  void apply_loads();
  void set_targets();
  StepStatus integrate();
  void measure();
  void publish();
  // The host paths' blow-up verdict against the tools' work (the stiffness damping's load work
  // taken out of the integrator's budget).
  StepStatus energy_verdict(StepStatus status);
  // The job path (simulation_job.cpp).
  Status prepare_job();
  Status start_job();
  StepStatus step_job();
  void report_from_record(const JobRecord& r);

  Scene scene_;
  SimulationOptions options_;
  Mesh mesh_;
  Model model_;
  State state_;
  ContactSurface surface_;
  std::unique_ptr<Backend> backend_;  // null on the in-place CPU path
  std::unique_ptr<ParticleModel> particles_;  // scene model "particles" (engine/particles/particle_model.h)
  double volume_change_rel_ = 0, volume_change_max_rel_ = 0;
  std::string backend_description_;
  std::vector<std::string> notes_;
  // A note about the explicit step's own setup (mass scaling, contact masses, drift damping,
  // the target step): left out of a static run's notes, which uses none of it.
  void note_explicit(std::string line);

  // Tools.
  bool has_needle_ = false;
  NeedleScript script_;
  std::optional<HoldingSetup> holding_;
  std::vector<int32_t> indent_vertices_;  // prescribed indentation patches
  std::vector<Vec3d> indent_direction_;   // per indent vertex [-]
  std::vector<double> indent_depth_, indent_speed_;  // per indent vertex [m], [m/s]

  // Geometry of the measurement.
  Vec3d entry_point_{0, 0, 0};
  Vec3d centre_{0, 0, 0};
  double cell_diameter_ = 0;
  int32_t rest_hit_triangle_ = -1;  // the rest surface's triangle where the axis enters
  double end_time_ = 0;

  // The host step's scratch, sized at creation.
  std::vector<Vec3d> targets_;             // the indented patch's targets at t_{n+1}
  bool uploaded_ = false;                  // Backend path: the patch is on the backend
  std::vector<Vec3d> indent_before_;       // indent vertices' u_{n-1} [m]
  std::vector<Vec3d> force_prev_;          // stiffness damping: f(u_{n-2}) [N]
  std::vector<Vec3d> damping_load_;        // stiffness damping: this step's loads [N]
  double stiffness_damping_ = 0;           // [s]
  double damping_work_ = 0;                // the damping loads' work so far [J]
  double damping_before_ = 0;              // sum of load . (u + u_prev) before the step [J]

  // Published.
  NeedleReport report_;
  // The host step's local stiffness: the job's job_local_stiffness (engine/sim/job.h) over
  // these parameters (the stiffness window) and this state.
  JobParams record_params_;
  JobState record_state_;
  QuasiStaticLimits quasi_limits_;
  StepStatus last_status_ = kStepOk;

  // Job path.
  JobSetup job_setup_;
  std::unique_ptr<ParticleBody> particle_body_;  // the particle model's stages on the job step
  std::unique_ptr<JobRunner> cpu_job_;  // the CPU runner (a GPU backend owns its own)
  JobRunner* job_ = nullptr;
  PunctureRecord job_puncture_;
  bool job_halted_ = false;
  std::unique_ptr<JobRunner> boundary_runner_;  // the prescribed boundary's host step
  size_t sample_capacity_ = 0;
  friend RunResult run_simulation(Simulation&, const RunOptions&);
};

/// A row of force.csv.
struct ForceSample {
  double time = 0;          ///< [s]
  double travel = 0;        ///< needle travel [m]
  double deformation = 0;   ///< membrane indentation at the tip [m]
  double force = 0;         ///< axial needle force (filtered) [N]
  double raw_force = 0;     ///< axial needle force before the filter [N]
  Vec3d force_vector{0, 0, 0};  ///< force the needle applies to the cell [N]
  double holding_force = 0; ///< holding pipette force along the needle axis [N]
  int32_t contacts = 0;     ///< needle contact vertices
  int32_t holding_contacts = 0;  ///< the holding pipette's rim contact points (its vertices)
  double elastic_energy = 0;  ///< [J]
  double kinetic_energy = 0;  ///< [J]
  bool punctured = false;
  StepStatus status = kStepOk;  ///< the integrator's flags of the sampled step
  /// |needle + holder| / needle axial force at the sampled step, 0 while not judged (before
  /// the needle force reaches the check's floor, after puncture) [-].
  double imbalance = 0;
  /// Kinetic / (kinetic + elastic) energy at the sampled step, 0 while not judged [-].
  double kinetic_share = 0;
  /// The static solver's row: its Newton and CG iterations and the force imbalance it
  /// converged to [N] (docs/static.md, "Converged"); 0 on the explicit path.
  int32_t newton_iterations = 0;
  int64_t krylov_iterations = 0;
  double residual = 0;
};

/// Progress of a run, passed to RunOptions::progress.
struct RunProgress {
  double time = 0;        ///< simulated [s]
  double end_time = 0;    ///< [s]
  double wall_seconds = 0;
  const NeedleReport* report = nullptr;
};

/// Options of run_simulation / run_scene.
struct RunOptions {
  SimulationOptions simulation;
  /// Stop this long (simulated) after puncture; negative: run to the scene's end.
  double stop_after_puncture = -1;
  /// Wall-clock seconds between progress calls.
  double progress_interval = 0.25;
  /// Called from the simulation thread every progress_interval (may be empty).
  std::function<void(const RunProgress&)> progress;
  /// Called at each output frame time with the simulation (VTU writing; may be empty).
  std::function<void(const Simulation&, int frame)> frame;
  /// Called from the simulation thread with each sample as it is recorded, in order (streaming
  /// force.csv; may be empty). Samples dropped by a full buffer are not passed.
  std::function<void(const ForceSample&)> on_sample;
  /// Called once, from the simulation thread, when the run is first seen to fail the
  /// quasi-static check (one line, quasi_static_warning; may be empty).
  std::function<void(const std::string&)> warning;
  /// Read once per step (may be null): when true, the run ends before the next step and the
  /// result says interrupted. Set it from a signal handler or another thread.
  const std::atomic<bool>* stop = nullptr;
};

/// What a run returns: the recorded curve and the summary numbers.
struct RunResult {
  std::vector<ForceSample> samples;  ///< one per output.sample_interval, (sample_count)
  PunctureRecord puncture;
  double peak_force = 0;              ///< [N]
  double peak_deformation = 0;        ///< [m]
  int64_t steps = 0;
  double simulated_time = 0;          ///< [s]
  double wall_seconds = 0;
  /// The static solver: wall time from the run's start to the puncture's state, before its
  /// release [s] (-1: no puncture, or the explicit path).
  double puncture_wall_seconds = -1;
  StepStatus status = kStepOk;        ///< OR of every step's flags
  bool stopped_early = false;         ///< a step was not advanced
  std::string stop_reason;            ///< describe_step_status of the failing step
  bool sample_buffer_full = false;    ///< output.sample_interval too small for the buffer
  /// Vertex masses raised by the dynamic mass scaling (penalty step; 0 elsewhere).
  int64_t mass_raises = 0;
  bool interrupted = false;           ///< RunOptions::stop ended the run before its end
  /// The static solver's direct oracle (solver.oracle): load steps solved both ways, the ones
  /// where the direct Newton did not converge, and the largest difference of the two solutions
  /// over all of them, max_v |u_cg - u_direct| / max_v |u_direct| [-] (-1: none compared).
  int64_t oracle_solves = 0, oracle_failures = 0;
  /// The static solver's work over the run, every solve counted (those that failed and were
  /// retried with a shorter load step, the bisections' and the release's included).
  int64_t newton_iterations = 0, krylov_iterations = 0, failed_solves = 0;
  double oracle_max_difference = -1;
  /// The quasi-static check over the run (the last report's): worst values, first failure.
  QuasiStaticState quasi;
  /// The limits it was judged by; quasi_limits.enforce: the experiment is quasi-static.
  QuasiStaticLimits quasi_limits;
  /// The run was quasi-static: no step failed the check.
  bool quasi_static() const { return quasi.failed_steps == 0; }
};

/// Runs a built simulation to its end (or stop_after_puncture) and records the curve: the one
/// run driver (engine/sim/run.cpp), on every path.
RunResult run_simulation(Simulation& simulation, const RunOptions& options = {});

/// When a run of length `end` [s] writes its frames: `count` frames `interval` [s] apart, the
/// first at t = 0 (output.frame_interval, or output.frames spread over the run with the end
/// included).
struct FrameSchedule {
  int count = 0;
  double interval = 0;
};
FrameSchedule frame_schedule(const Scene& scene, double end);

/// Builds a simulation from `scene` and runs it: the reusable driver behind `zona run` and
/// calibration.
Result<RunResult> run_scene(const Scene& scene, const RunOptions& options = {});

}  // namespace zona
