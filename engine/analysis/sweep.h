// Parameter sweeps (`zona sweep`, docs/sweeps.md): the points (a product of --set lists, a CSV
// manifest, or both), the sweep folder's files, one point's run as a worker job, the point's
// completion marker, and the table of results.
//
// A sweep folder holds sweep.json (the scene and what every point shares), manifest.csv (one row
// per point), points/NNNNN/ (one `zona run` output folder per point, with run.log and, written
// last and atomically, point.json: the marker that the point is done) and sweep.csv (the table).
// Whoever runs a point (a local worker, a SLURM array task) runs the same job and writes the
// same marker, so a sweep can be resumed by either and `zona sweep collect` reads them all.
#pragma once

#include <cstddef>
#include <optional>
#include <span>
#include <string>
#include <vector>

#include <nlohmann/json_fwd.hpp>

#include "engine/analysis/worker_pool.h"
#include "engine/core/base.h"

namespace zona {

// --- Points -----------------------------------------------------------------------------------

/// The parameter points: one column per scene key, one row per point.
struct SweepPoints {
  std::vector<std::string> keys;                 ///< scene key paths, (key_count)
  std::vector<std::vector<std::string>> values;  ///< as --set takes them, (point_count x key_count)
};

/// Splits `--set KEY=A,B,C` options: a single value is a fixed override of every point
/// (appended to `fixed` as "KEY=A"), several make a swept key. Returns the product of the swept
/// keys, the first key varying slowest (no swept key: no point). Errors name the option.
Result<SweepPoints> sweep_points_from_sets(std::span<const std::string> sets,
                                           std::vector<std::string>* fixed);

/// Reads a manifest: a CSV whose header names the scene keys (a column `point` is ignored),
/// one point per row; fields may be double-quoted (a value with commas); '#' lines are comments.
/// Errors name the file and line.
Result<SweepPoints> read_sweep_manifest(const std::string& path);

/// Every point of `a` with every point of `b` (a's order slowest); either may be empty (no key).
/// Errors: a key in both.
Result<SweepPoints> combine_sweep_points(const SweepPoints& a, const SweepPoints& b);

/// manifest.csv's text: `point` then the keys; fields with a comma or quote are quoted.
std::string sweep_manifest_csv(const SweepPoints& points);

// --- The sweep folder -------------------------------------------------------------------------

/// What every point of a sweep shares (sweep.json).
struct SweepConfig {
  std::string scene;               ///< the scene file, absolute
  std::vector<std::string> fixed;  ///< "key=value" overrides of every point, before the point's
  std::string backend = "cpu";     ///< zona run --backend
  int threads = 0;                 ///< zona run --threads of each point (0: all)
  std::string solver;              ///< "" or solver.method's value for every point
  std::vector<double> deformations = {10e-6, 20e-6, 30e-6, 40e-6};  ///< table columns [m]
  size_t point_count = 0;
};

nlohmann::json sweep_config_json(const SweepConfig& config);
/// Reads sweep.json of the folder `dir`. Errors name the file and key.
Result<SweepConfig> read_sweep_config(const std::string& dir);

/// "points/00042": a point's folder relative to the sweep folder.
std::string sweep_point_folder(size_t index);

/// The `zona run` of point `index`: `zona` the program, `dir` the sweep folder; its output
/// folder is dir/points/NNNNN, its stdout and stderr go to run.log there.
WorkerJob sweep_point_job(const std::string& zona, const std::string& dir, const SweepConfig& config,
                          const SweepPoints& points, size_t index);

// --- Completion -------------------------------------------------------------------------------

/// point.json: how a point's run ended. Written last, atomically, by whoever ran it.
struct PointRecord {
  size_t index = 0;
  std::string status;       ///< "ok" (exit 0), "failed" (an error exit), "crashed" (a signal)
  int exit_code = -1;       ///< -1 when ended by a signal
  int signal = 0;
  double wall_seconds = 0;  ///< of the run's process [s]
  std::string message;      ///< the run's error line ("" when ok)
};

/// Whether an ending is final, i.e. marks the point done. A run killed from outside (SIGKILL,
/// SIGTERM, SIGINT, SIGHUP, or zona run's own exit 130 / 143 after one) is not: its point runs
/// again when the sweep is resumed. A crash (SIGSEGV, SIGABRT, ...) or an error exit is final.
bool sweep_outcome_is_final(const WorkerOutcome& outcome);

/// The record of a final outcome; `log` is run.log's text (the error line is taken from it).
PointRecord sweep_point_record(size_t index, const WorkerOutcome& outcome, const std::string& log);

/// Writes dir/points/NNNNN/point.json atomically.
Status write_point_record(const std::string& dir, const PointRecord& record);

/// Reads a point's marker: nullopt when absent (not done). Errors: a marker that does not parse.
Result<std::optional<PointRecord>> read_point_record(const std::string& dir, size_t index);

// --- The table --------------------------------------------------------------------------------

/// One row of sweep.csv.
struct SweepRow {
  size_t index = 0;
  std::string status = "pending";  ///< a PointRecord status, or "pending" (no marker)
  int exit_code = -1;
  bool punctured = false;
  std::optional<double> puncture_deformation;  ///< [m]
  std::optional<double> puncture_force;        ///< [N]
  std::optional<double> peak_force;            ///< [N]
  std::optional<bool> quasi_static;            ///< summary.json's quasi_static (null: not judged)
  std::vector<std::optional<double>> force_at; ///< on the loading branch [N], (deformation count)
  std::optional<double> wall_seconds;          ///< [s]
  std::string message;
};

/// The row of point `index` from its folder (marker, summary.json, force.csv). A missing or
/// unreadable summary or curve leaves those fields empty, with a message.
SweepRow read_sweep_row(const std::string& dir, const SweepConfig& config, size_t index);

/// sweep.csv's text: point, the keys, status, exit_code, punctured, puncture_deformation_m,
/// puncture_force_N, peak_force_N, force_at_<D>um_N..., quasi_static, wall_s, folder, message.
std::string sweep_table_csv(const SweepConfig& config, const SweepPoints& points,
                            std::span<const SweepRow> rows);

// --- SLURM ------------------------------------------------------------------------------------

/// Options of the job-array script.
struct SlurmOptions {
  std::string job_name = "zona_sweep";
  std::string time = "01:00:00";        ///< per task (--time)
  int cpus_per_task = 2;                ///< --cpus-per-task
  int gpus_per_task = 0;                ///< --gres=gpu:N (1 with --backend cuda)
  int max_parallel = 0;                 ///< the array's %N throttle, 0: none
  std::vector<std::string> extra;       ///< further "#SBATCH" lines' options (--partition=gpu)
};

/// sweep.sbatch: an sbatch job array of `count` tasks, each running
/// `zona sweep --task $SLURM_ARRAY_TASK_ID --out DIR`; `zona` and `dir` absolute.
std::string slurm_script(const std::string& zona, const std::string& dir, size_t count,
                         const SlurmOptions& options);

}  // namespace zona
