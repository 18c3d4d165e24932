// Mesh-convergence study of the injection experiment (`zona study convergence`): the same scene
// run at a list of generated mesh sizes, each force-deformation curve read at fixed
// deformations and compared with the finest mesh's, written as two CSVs and one plot
// (docs/validation.md, "Convergence study").
//
// The pure parts (the loading branch, interpolation at a deformation, the force-drop metric,
// the relative differences, the CSV text and the plot) are separate functions so that tests can
// feed them hand-made curves; run_convergence_study strings them together with the simulation.
#pragma once

#include <atomic>
#include <cstdint>
#include <functional>
#include <optional>
#include <span>
#include <string>
#include <string_view>
#include <vector>

#include "engine/core/base.h"
#include "engine/analysis/plot.h"
#include "engine/tools/puncture.h"
#include "engine/scene/scene.h"
#include "engine/sim/simulation.h"

namespace zona {

// --- Arguments --------------------------------------------------------------------------------

/// The sizes of `--vertices`: a comma list of counts ("300,600" or "1e3,4e3,1e6"), each at least
/// the mesher's minimum (kMinCellMeshVertices) and at most its limit. Errors name the entry.
Result<std::vector<int64_t>> parse_study_vertices(std::string_view text);

/// The deformations of `--deformations`: a comma list of positive numbers in um ("10,20,30,40"),
/// returned in [m]. Errors name the entry.
Result<std::vector<double>> parse_study_deformations(std::string_view text);

// --- One curve --------------------------------------------------------------------------------

/// A point of a force-deformation curve.
struct CurvePoint {
  double deformation = 0;  ///< membrane deformation at the entry point [m]
  double force = 0;        ///< filtered axial needle force [N]
  double holding = 0;      ///< holding pipette force along the needle axis [N]
};

/// The loading branch of a run: its samples before puncture, in time order, then the puncture
/// point itself (the force the criterion fired at, before any release). Without a puncture, all
/// samples. Non-finite samples end the branch (a run that blew up).
std::vector<CurvePoint> loading_branch(std::span<const ForceSample> samples,
                                       const PunctureRecord& puncture);

/// The force where the branch first reaches `deformation` [m], linearly interpolated between
/// the two points that bracket it [N]; nullopt when the branch never reaches it.
std::optional<double> force_at_deformation(std::span<const CurvePoint> branch, double deformation);

/// How far the run is from static equilibrium where the branch first reaches `deformation`:
/// (force + holding) / force, both interpolated as force_at_deformation does [-]. The needle's
/// resistance (force, positive) and the holding pipette's force along the axis (negative when it
/// holds the cell against the needle) cancel in a quasi-static injection; what is left is carried
/// by inertia and damping. nullopt where the level is not reached or the force is not positive.
std::optional<double> imbalance_at_deformation(std::span<const CurvePoint> branch,
                                               double deformation);

/// The largest point-to-point fall of the force along the branch, over `reference_force` [-]
/// (0 when the force never falls, or the reference is not positive). The study uses the
/// puncture force as the reference, the peak force without a puncture: a coarse mesh whose
/// tip jumps from vertex to vertex shows up as large drops.
double largest_force_drop(std::span<const CurvePoint> branch, double reference_force);

// --- The study --------------------------------------------------------------------------------

/// One mesh size's run and its summary numbers.
struct ConvergenceRun {
  int64_t target_vertices = 0;  ///< the count asked of the mesher
  int64_t vertices = 0;         ///< the mesh's count (0 when setup failed)
  int64_t tets = 0;
  double dt = 0;  ///< [s]; 0 for a static run (its steps are load steps)
  int64_t steps = 0;
  double setup_seconds = 0;  ///< mesh, model and backend [s]
  double wall_seconds = 0;   ///< the run [s]
  std::string backend;       ///< Simulation::backend_description()
  bool punctured = false;
  double puncture_deformation = 0;  ///< [m]
  double puncture_force = 0;        ///< [N]
  double peak_force = 0;            ///< [N]
  /// Force at each requested deformation [N], (deformation count); nullopt: not reached.
  std::vector<std::optional<double>> force_at;
  /// (force_at - finest's) / finest's [-], (deformation count); nullopt where either is
  /// missing or the finest's is zero. Filled by fill_relative_differences.
  std::vector<std::optional<double>> relative_to_finest;
  /// imbalance_at_deformation at each requested deformation [-], (deformation count).
  std::vector<std::optional<double>> imbalance_at;
  double largest_drop = 0;           ///< largest_force_drop of the branch [-]
  /// Deformation of the first sample before puncture with an inverted element [m]; nullopt:
  /// none on the loading branch.
  std::optional<double> inverted_from;
  std::string step_flags;            ///< step_flag_names of the run, joined by '|'
  bool stopped_early = false;        ///< a step was not advanced, setup failed, or interrupted
  std::string stop_reason;           ///< why (empty when the run reached its end)
  /// ConvergenceOptions::stop ended the run before its end: its curve is a result up to there.
  bool interrupted = false;
  std::vector<std::string> notes;    ///< Simulation::notes() (backend fallback, ...)
  std::vector<ForceSample> samples;  ///< the recorded curve, (sample count)
};

/// A whole study.
struct ConvergenceStudy {
  std::string scene_name;
  std::vector<double> deformations;  ///< [m]
  std::vector<ConvergenceRun> runs;  ///< in the order of the vertex list
};

/// Summary numbers of one finished run: puncture, peak, forces at `deformations` [m], the
/// largest drop, flags and stop reason. relative_to_finest is left for
/// fill_relative_differences.
ConvergenceRun summarize_convergence_run(int64_t target_vertices, const RunResult& run,
                                         std::span<const double> deformations);

/// Fills each run's relative_to_finest against the run with the most mesh vertices.
void fill_relative_differences(ConvergenceStudy& study);

/// The scene at each size: `overrides`, then mesh.generate.vertices = N and output.frames = 0.
/// Errors (one line): the scene does not load at some size, or its mesh is a file.
Result<std::vector<Scene>> convergence_scenes(const std::string& scene_path,
                                              const std::vector<std::string>& overrides,
                                              std::span<const int64_t> vertices);

/// How run_convergence_study runs.
struct ConvergenceOptions {
  /// Backend factory and threads, as for run_simulation (kernels/ is not a dependency).
  SimulationOptions simulation;
  /// Progress while a size runs (may be empty).
  std::function<void(const RunProgress&)> progress;
  /// Called before each size and with each finished run (may be empty).
  std::function<void(const Scene&)> started;
  std::function<void(const ConvergenceRun&)> finished;
  /// Read once per step (RunOptions::stop); when set, the running size ends there (a row marked
  /// interrupted) and no further size starts. May be null.
  const std::atomic<bool>* stop = nullptr;
};

/// Runs every scene (from convergence_scenes) to puncture (stop_after_puncture = 0) or its
/// end. A size that fails to set up or stops early becomes a run with its reason; the study
/// itself does not fail. With options.stop set, the study ends after the size it interrupted.
/// Relative differences are filled at the end.
ConvergenceStudy run_convergence_study(std::span<const Scene> scenes,
                                       std::span<const double> deformations,
                                       const ConvergenceOptions& options);

// --- Output -----------------------------------------------------------------------------------

/// convergence.csv: comment lines (`comments`, each line prefixed "# "), the header, and one row
/// per (size, sample): target_vertices, vertices, tets, time_s, travel_um, deformation_um,
/// force_un, punctured.
std::string convergence_csv(const ConvergenceStudy& study, std::span<const std::string> comments);

/// convergence_summary.csv: comment lines, the header and one row per size (columns in
/// docs/validation.md). Empty fields where a value does not exist; free text (backend, flags,
/// stop reason) has its commas replaced by ';' so that every line splits on commas.
std::string convergence_summary_csv(const ConvergenceStudy& study,
                                    std::span<const std::string> comments);

/// The built-in writer's plot (python/zona_plot.py draws the same curves when Python and
/// matplotlib are there): every size's loading branch (deformation [um] against force [uN]),
/// one colour per size with its vertex count in the legend, puncture points as discs of the
/// same colour, the deformation axis from the smallest deformation drawn.
PlotSpec convergence_plot(const ConvergenceStudy& study);

}  // namespace zona
