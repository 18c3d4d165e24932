// The vertices-versus-time scaling benchmark (issue 5, Ladjal et al. Table II): for each backend,
// constitutive model, formulation, thread count and mesh size, the precompute time and the
// median step time on Ladjal et al.'s cell meshes (refined at the puncture point), with the bytes a
// step must move, the floor they set at the machine's measured copy bandwidth, and a hash of
// the final displacements so that runs on different machines and commits can be compared.
//
// Engine-side so that tests can run it on tiny meshes; it sees the GPU only through the Backend
// interface and through hooks the caller fills from kernels/ (the factory, the device copy
// bandwidth), so nothing here depends on CUDA. `zona bench` (apps/cmd_bench.cpp) is its CLI.
#pragma once

#include <cstdint>
#include <cstdio>
#include <functional>
#include <memory>
#include <span>
#include <string>
#include <string_view>
#include <vector>

#include "engine/sim/backend.h"
#include "engine/core/base.h"
#include "engine/fem/fem_element.h"
#include "engine/mesh/mesh.h"
#include "engine/core/vec.h"

namespace zona {

/// One row of Ladjal et al. Table II (non-linear SVK model, Intel Core Duo 3.2 GHz, 2009).
struct SeedTable2Row {
  int64_t vertices = 0;
  int64_t tets = 0;
  double precompute_ms = 0;  ///< off-line pre-computation [ms]
  double step_ms = 0;        ///< on-line simulation time per step [ms]
};

/// The twelve rows of Ladjal et al. Table II, 115 to 1093 vertices, in the paper's order.
std::span<const SeedTable2Row> seed_table2();

/// What to measure. Every list is crossed with every other (rows = backends x models x
/// formulations x threads x vertices).
struct ScalingBenchConfig {
  std::vector<BackendKind> backends{BackendKind::kCpu};  ///< kCpu and/or kCuda
  std::vector<ConstitutiveModel> models{ConstitutiveModel::kSvk};
  std::vector<Formulation> formulations{Formulation::kGradient};
  std::vector<int64_t> vertices;  ///< target vertex counts (table2_spec), ascending or not
  /// CPU thread counts (0: the CPU backend's automatic choice, make_state); the GPU rows use the
  /// first entry (0: all hardware threads) for the host-side precompute.
  std::vector<int> threads{0};
  /// Steps per timed block (one Backend::step call); 0 chooses by size (auto_steps).
  int steps = 0;
  int repeats = 7;  ///< timed blocks after one untimed warm-up block (>= 1)
  /// Most builds of the model timed for precompute_ms (median); fewer when they take long.
  int precompute_repeats = 5;
  /// Assembly of the GPU backend (the CPU reference has one, deterministic).
  Assembly assembly = BackendOptions{}.assembly;
  /// A row whose estimated memory exceeds this is skipped with a notice [bytes]; 0 reads
  /// MemAvailable from /proc/meminfo (and keeps a quarter of it free).
  double memory_limit_bytes = 0;
  /// Bytes of the CPU copy-bandwidth measurement buffer (each of source and destination).
  size_t copy_bytes = size_t{256} << 20;
  /// A backend that cannot be created (no CUDA, no device) is skipped with one notice instead
  /// of failing the run (`--backend all`).
  bool skip_unavailable_backends = false;
  /// Element math precision of the CPU rows (ModelDesc::element_precision); the GPU rows are
  /// float32 elements always.
  ElementPrecision element_precision = ElementPrecision::kFloat64;
};

/// The machine the numbers were taken on; written as the CSV's header comment lines.
struct MachineInfo {
  std::string cpu_model;          ///< /proc/cpuinfo "model name"
  int hardware_threads = 0;       ///< std::thread::hardware_concurrency()
  std::string gpu_name;           ///< "" without a usable GPU
  double gpu_copy_gb_per_s = 0;   ///< device-to-device copy (read + write) [GB/s], 0 if none
  std::string date;               ///< UTC, YYYY-MM-DD
  std::string commit;             ///< source revision when known ("" otherwise)
  std::string command;            ///< the command line that reproduces the run ("" if none)
  std::string zona_version;
};

/// One measured (backend, model, formulation, threads, size) combination.
struct ScalingRow {
  std::string backend;      ///< "cpu" or "cuda"
  std::string model;        ///< "svk" or "linear"
  std::string formulation;  ///< "gradient", "tensor_rebuilt" or "tensor_stored"
  int threads = 0;          ///< CPU threads the step ran on (and the precompute)
  int threads_requested = 0;  ///< as asked: > 0 fixed, 0 the backend's automatic choice
  int64_t target_vertices = 0;  ///< the count asked of table2_spec
  int64_t vertices = 0;     ///< the mesh's count
  int64_t tets = 0;
  double mesh_ms = 0;       ///< mesh generation (once per size, repeated on each row) [ms]
  /// build_model (validation, shapes, masses, critical step and, for tensor_stored on the
  /// CPU, the mass tensors): median over the timed builds [ms]. Ladjal et al. Table II column 3.
  double precompute_ms = 0;
  double tensor_precompute_ms = 0;  ///< the stored tensors alone (CPU tensor_stored), else 0 [ms]
  /// Backend::upload [ms]: the CPU backend's state copy; on the GPU the device layout, the
  /// transfers and, for tensor_stored, the tensors built on the device.
  double upload_ms = 0;
  int steps = 0;            ///< steps per timed block
  int repeats = 0;          ///< timed blocks
  double step_ms_median = 0;  ///< per step, median over blocks (StepReport::device_ms / steps) [ms]
  double step_ms_p10 = 0;     ///< [ms]
  double step_ms_p90 = 0;     ///< [ms]
  double steps_per_s = 0;   ///< steps / median wall time of a block, launches and syncs included [1/s]
  double bytes_per_step = 0;  ///< what one step must move through memory (step_bytes) [bytes]
  double gb_per_s = 0;      ///< bytes_per_step / step_ms_median [GB/s]
  double copy_gb_per_s = 0; ///< measured copy bandwidth of this backend (read + write) [GB/s]
  double floor_ms = 0;      ///< bytes_per_step / copy_gb_per_s [ms]
  double floor_ratio = 0;   ///< step_ms_median / floor_ms [-]
  std::string status;       ///< "ok" or the step flags seen (describe_step_status)
  uint64_t state_hash = 0;  ///< FNV-1a of the final float64 displacements (displacement_hash)
  std::string precision = "float64";  ///< element math: "float64" or "float32"
};

/// What the run is doing, for a progress bar.
struct ScalingProgress {
  int row = 0;         ///< rows finished
  int row_count = 0;   ///< rows planned
  std::string label;   ///< e.g. "cpu svk gradient 2t 131072"
  std::string phase;   ///< "mesh", "precompute", "upload", "steps", "done"
};

/// Everything a run produced.
struct ScalingBenchResult {
  MachineInfo machine;
  /// CPU copy bandwidth (read + write) per thread count measured [GB/s], (threads list).
  std::vector<std::pair<int, double>> cpu_copy_gb_per_s;
  std::vector<ScalingRow> rows;
};

/// Callbacks filled by the caller (the CLI, a test).
struct ScalingBenchHooks {
  /// Creates a backend (kernels/backend_factory.h make_backend). Required.
  std::function<Result<std::unique_ptr<Backend>>(BackendKind, const BackendOptions&)> make_backend;
  /// Device-to-device copy bandwidth of the GPU, read + write [GB/s] (kernels/cuda_probe.h).
  /// Called once when a GPU row is about to run; empty or failing leaves floor_ms at 0.
  std::function<Result<double>()> device_copy_bandwidth;
  /// Called once before the first row, with the machine and the copy bandwidths filled (e.g.
  /// to write the CSV's comment lines and header).
  std::function<void(const ScalingBenchResult&)> started;
  /// Called with each finished row (e.g. to append it to the CSV at once).
  std::function<void(const ScalingRow&)> row;
  /// Progress; called often, keep it cheap.
  std::function<void(const ScalingProgress&)> progress;
  /// One-line notices: skipped backends or rows.
  std::function<void(const std::string&)> notice;
};

// --- Arguments ----------------------------------------------------------------------------

/// The sizes of `--vertices`: "table2" (Ladjal et al. Table II's twelve counts), "sweep" (powers of two from
/// 2^7 up to `max_vertices`) or a comma list of counts ("1000,10000" or "1e3,1e4"), each in
/// [kMinBenchVertices, max_vertices]. Errors name the bad entry.
Result<std::vector<int64_t>> parse_vertex_list(std::string_view text, int64_t max_vertices);
/// Fewest vertices a bench mesh may have (table2_spec's range starts at 100).
inline constexpr int64_t kMinBenchVertices = 100;

/// "cpu", "cuda" or "all" (both).
Result<std::vector<BackendKind>> parse_bench_backends(std::string_view text);
/// "svk", "linear", "all", or a comma list.
Result<std::vector<ConstitutiveModel>> parse_bench_models(std::string_view text);
/// "gradient", "tensor_rebuilt", "tensor_stored", "all", or a comma list.
Result<std::vector<Formulation>> parse_bench_formulations(std::string_view text);
/// Comma list of thread counts >= 0 (0: the CPU backend's automatic choice).
Result<std::vector<int>> parse_thread_list(std::string_view text);

/// "svk" / "linear" / "neohookean".
const char* constitutive_name(ConstitutiveModel model);
/// "gradient" / "tensor_rebuilt" / "tensor_stored".
const char* formulation_name(Formulation formulation);

// --- Pieces of the measurement (public for tests and the micro-benchmarks) ----------------

/// Steps per timed block when none is given: about 2 GB of gradient-form traffic per block on
/// the CPU (tenths of a second from DRAM, less from cache) or 64 GB on the GPU, divided by the
/// formulation's relative cost (the SVK tensor contractions: 40x the gradient form, the linear
/// ones 3x, as measured on the CPU), between 1 (CPU) or 10 (GPU) and 1000 steps. Depends only
/// on the mesh and the choices, never on timings, so the final hash is reproducible.
int auto_steps(BackendKind backend, ConstitutiveModel model, Formulation formulation,
               int64_t vertices, int64_t tets);

/// The benchmark's loaded state: a smooth displacement field [m], (vertex_count), that indents
/// the cell at its top pole by 2 % of the radius over a 0.3-radius patch and stretches it
/// non-uniformly by up to 1 %, vanishing on the held bottom cap. Strains up to about 4 %: the SVK
/// terms of second and third order are exercised, and the undamped oscillation that follows
/// flags no element over thousands of steps (twice the amplitude let single small elements
/// near the pole reach SVK's collapse stretch after ~4000 steps).
std::vector<Vec3d> bench_displacement(const Mesh& mesh);

/// Vertices held fixed by the benchmark: the bottom 5 % of the cell's height (the holding
/// pipette's side), ascending.
std::vector<int32_t> bench_fixed_vertices(const Mesh& mesh);

/// Bytes one step must move through memory on `backend`, counting each array once per pass
/// that streams it (gathered vertex data as if perfectly cached; no write-allocate traffic):
/// the arrays of engine/sim/integrator.cpp and engine/fem/forces_cpu.cpp on the CPU, the default
/// layout of kernels/device_layout.h (with `assembly`) on the GPU.
double step_bytes(BackendKind backend, ConstitutiveModel model, Formulation formulation,
                  Assembly assembly, int64_t vertices, int64_t tets);

/// Host memory a row needs at its peak, estimated from the array sizes [bytes].
double estimate_row_bytes(BackendKind backend, ConstitutiveModel model, Formulation formulation,
                          int64_t vertices, int64_t tets);

/// Tetrahedra per vertex of table2_spec meshes, for estimates before a mesh exists (measured:
/// 4.4 at 1e3 vertices, ~5.8 from 1e5 on; the larger value is used).
inline constexpr double kBenchTetsPerVertex = 6.0;

/// FNV-1a (64-bit) of the displacements' float64 bit patterns, x, y, z of each vertex in
/// order, each value's bytes from least to most significant (the same on every host).
uint64_t displacement_hash(std::span<const Vec3d> u);

/// Copy bandwidth of this machine's memory: `threads` threads (0: hardware count) each copy
/// their slice of a `bytes` buffer; median of `repeats` copies after one warm-up, counting
/// bytes read plus bytes written [GB/s].
double measure_cpu_copy_bandwidth(size_t bytes, int threads, int repeats = 9);

/// Largest power of two n of vertices whose cheapest row of `config` (estimate_row_bytes with
/// kBenchTetsPerVertex n tetrahedra) fits in `memory_bytes` (0: 0.75 MemAvailable): the top of
/// `--vertices sweep` when no --max-vertices is given. At least 128.
int64_t memory_fit_vertices(const ScalingBenchConfig& config, double memory_bytes = 0);

/// MemAvailable from /proc/meminfo [bytes]; 0 when unknown.
double available_memory_bytes();

/// CPU model name, hardware threads, date (the GPU fields are the caller's).
MachineInfo local_machine_info();

/// Median and the q-quantile (nearest rank) of x; 0 for empty x.
double quantile(std::vector<double> x, double q);

// --- Run and CSV --------------------------------------------------------------------------

/// Runs the benchmark. Meshes come from table2_spec (one per size, shared by the rows of that
/// size). Errors: an empty list, a backend that cannot be created (unless
/// skip_unavailable_backends), a mesh or model that cannot be built. Rows that would not fit
/// in memory are skipped with a notice. `machine` supplies the GPU name and commit.
Result<ScalingBenchResult> run_scaling_bench(const ScalingBenchConfig& config,
                                             const ScalingBenchHooks& hooks,
                                             const MachineInfo& machine);

/// The CSV's column names, comma-separated, no newline.
std::string scaling_csv_header();
/// The header comment lines ("# ..."), each ending in a newline: machine, date, commit,
/// copy bandwidths, what the columns mean.
std::string scaling_csv_comments(const ScalingBenchResult& result,
                                 const ScalingBenchConfig& config);
/// One CSV row, no newline.
std::string scaling_csv_row(const ScalingRow& row);

}  // namespace zona
