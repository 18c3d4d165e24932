// The compute backend seen by the rest of zona: one interface over the CPU reference
// (engine/sim/integrator.h) and the CUDA kernels (kernels/). A backend owns a copy of the state
// where it computes (host memory or device memory); the simulation loop hands it sub-step
// counts and prescribed targets and gets back status flags and the needle's force, nothing
// else. The factory that picks one lives in kernels/backend_factory.h.
#pragma once

#include <cstdint>
#include <memory>
#include <span>
#include <string>
#include <string_view>
#include <vector>

#include "engine/core/base.h"
#include "engine/sim/integrator.h"
#include "engine/sim/job_runner.h"
#include "engine/fem/model.h"
#include "engine/fem/state.h"
#include "engine/core/vec.h"

namespace zona {

/// Which backend `--backend` asks for.
enum class BackendKind : int32_t {
  kAuto = 0,  ///< the GPU when one is usable, else the CPU (with a one-line notice)
  kCpu = 1,   ///< the CPU reference
  kCuda = 2,  ///< the CUDA backend; an error when it is not compiled in or no device is usable
};

/// Parses "auto", "cpu" or "cuda"; anything else is an error naming the accepted values.
Result<BackendKind> parse_backend_kind(std::string_view text);
/// "auto", "cpu" or "cuda".
const char* backend_kind_name(BackendKind kind);

/// How the GPU assembles per-tetrahedron forces into vertex forces (docs/performance.md has the
/// cost of each).
enum class Assembly : int32_t {
  /// Each tetrahedron adds its corner forces with float4 atomics (after summing runs of equal
  /// vertices within a warp, see BackendOptions::warp_aggregate). The order of the additions
  /// varies from run to run, so the last bits of the result do too.
  kScatterAtomic = 0,
  /// Deterministic: as kScatterAtomic in 64-bit fixed point (2^-40 force units); integer sums do
  /// not depend on their order, so runs are bitwise identical.
  kScatterFixed = 1,
  /// Deterministic: each vertex recomputes the tetrahedra around it (gather list, ascending)
  /// and sums its corner forces in that order, fused with the update (one pass, four element
  /// evaluations per tetrahedron).
  kGatherRecompute = 2,
  /// Deterministic: an element pass writes the four corner forces of each tetrahedron, then a
  /// vertex pass sums them in gather-list order and updates (the CPU reference's scheme).
  kGatherStored = 3,
};

/// "atomic", "fixed_point", "gather_recompute" or "gather_stored".
const char* assembly_name(Assembly assembly);
/// Parses the names above.
Result<Assembly> parse_assembly(std::string_view text);

/// Options of a backend. Defaults are the measured best choice (docs/performance.md).
struct BackendOptions {
  /// Threads of the CPU backend (0: one per hardware thread).
  int cpu_threads = 0;
  /// GPU assembly; Assembly::kScatterAtomic is not bitwise reproducible, the others are.
  Assembly assembly = Assembly::kScatterAtomic;
  /// GPU: renumber vertices along a Morton curve and sort tetrahedra for locality.
  bool reorder = true;
  /// GPU: the formulation the kernels evaluate; the model's own when left at its default
  /// (-1). Stored tensors are built on the device from the shapes (float32).
  int32_t formulation = -1;
  /// GPU, atomic scatter: sum the corner forces of neighbouring threads that go to the same
  /// vertex with warp shuffles first (tetrahedra are sorted so that such runs are common), one
  /// atomic per run. The fixed-point scatter always does.
  bool warp_aggregate = true;
  /// GPU: launch each kernel while the previous one finishes (programmatic dependent launch,
  /// sm_90), hiding launch latency on small meshes.
  bool programmatic_launch = true;
  /// GPU: CUDA device ordinal.
  int device = 0;
  /// Debug: fill every device output buffer with NaN before the pass that must write all of it,
  /// so an entry a kernel forgets shows up as NaN (tests).
  bool poison_outputs = false;
};

/// What one call of Backend::step returns.
struct StepReport {
  StepStatus status = kStepOk;  ///< OR of the sub-steps' StepStatusBits
  int64_t steps = 0;            ///< sub-steps taken (fewer than asked after kStepNotAdvanced)
  /// Sum over prescribed vertices of the force the constraint applies to the body at the last
  /// sub-step [N] (StepDiagnostics::constraint_force); the needle feels minus this.
  Vec3d constraint_force{0, 0, 0};
  double kinetic_energy = 0;  ///< at the last sub-step [J]
  double elastic_energy = 0;  ///< at the last sub-step [J]
  double residual_norm = 0;   ///< |f_el + f_ext| over free vertices at the last sub-step [N]
  double device_ms = 0;  ///< time of the sub-steps: CUDA events on the GPU, wall on the CPU [ms]
};

/// Reductions over the whole state, on demand (not on the step path).
struct StateSummary {
  double max_displacement = 0;  ///< max |u| [m]
  double kinetic_energy = 0;    ///< sum M |v|^2 / 2 with v = (u_n - u_{n-1}) / dt [J]
};

/// Where a GPU backend keeps its current displacements, for device code outside it (the
/// CUDA-Vulkan surface writer of kernels/surface_interop.h). Valid until the next step() or
/// upload(). The CPU backends return an empty view (u == nullptr).
struct DeviceStateView {
  const double* u = nullptr;  ///< device memory, 3 per vertex in device order [length_unit]
  double length_unit = 1;     ///< metres per device length unit [m]
  /// Model vertex -> device index (host memory), (vertex_count).
  std::span<const int32_t> vertex_old_to_new;
  void* stream = nullptr;  ///< the cudaStream_t that step() enqueues on
  int device = -1;         ///< CUDA device ordinal
};

/// A compute backend. Setup calls return Status; step() never allocates and never throws.
class Backend {
 public:
  virtual ~Backend() = default;

  /// "cpu" or "cuda".
  virtual const char* name() const = 0;
  /// One line: backend, device, formulation, assembly.
  virtual std::string description() const = 0;

  /// Takes the model (kept by reference: it must outlive the backend) and a starting state
  /// (displacements, loads, prescribed set and targets). Allocates everything step() needs.
  virtual Status upload(const Model& model, const State& state) = 0;

  /// Sets the prescribed targets [m], (prescribed count, in the order of the uploaded state's
  /// prescribed_vertices) to be reached at the end of the next step() call; the sub-steps in
  /// between move each vertex linearly from its current target. Does not allocate.
  virtual Status set_prescribed_targets(std::span<const Vec3d> targets) = 0;

  /// Replaces the external nodal forces [N], (vertex_count), from the next step() on, without a
  /// new upload: loads that change every step (suction ramps, the punctured tip's released load,
  /// the stiffness-damping term). Does not allocate after the first call with a non-zero load.
  /// The default answers "not supported" (the caller then uploads the whole state).
  virtual Status set_external_forces(std::span<const Vec3d> forces);

  /// Advances `substeps` steps of model.dt (>= 1). Stops early at a sub-step that was not
  /// advanced (kStepNonFinite: the state keeps the last good step). Only the report comes back
  /// from the device.
  virtual StepReport step(int substeps) = 0;

  /// Copies the backend's state into `state` (u, u_prev, force, time, step count; the
  /// diagnostics of the last sub-step). Not on the step path.
  virtual Status download(State& state) = 0;

  /// Elastic forces -dW/du [N], (vertex_count), at displacements u [m], (vertex_count), without
  /// stepping or touching the backend's state. For tests and `zona forces`.
  virtual Status elastic_forces(std::span<const Vec3d> u, std::span<Vec3d> f) = 0;

  /// Max |u| and kinetic energy of the current state.
  virtual Result<StateSummary> summarize() = 0;

  /// The device-side state for interop (DeviceStateView); empty on the CPU.
  virtual DeviceStateView device_state() const { return {}; }

  /// Starts the injection step's stages (engine/sim/job.h) on the uploaded model and state and
  /// returns their runner, owned by the backend (valid until the next upload). From then on
  /// the runner steps the state; step() and set_* are not to be called. The default answers
  /// "not supported".
  virtual Result<JobRunner*> start_job(const JobSetup& setup);
};

}  // namespace zona
