// Calibration: fits scene parameters (material moduli, puncture thresholds, any numeric key that
// --set can override) to one or several force-deformation curves by running the scene repeatedly.
//
// Least squares on the loading branch: the residuals are the simulated force minus the measured
// one at every measured point before the puncture (plus, for a curve that ends at its puncture,
// the puncture force), over all curves at once. Each parameter moves in [lower, upper], on a log
// scale when both bounds are positive. The search is Levenberg-Marquardt with forward-difference
// Jacobians (each a batch of runs that can go in parallel), after a scan for one parameter.
// Uncertainty: a bootstrap over whole curves (cells or repeated runs), never over the points of
// one curve, whose errors are correlated; each replicate is refitted by Gauss-Newton on the
// model linearised at the fit (no new runs). docs/sweeps.md has the method and its limits.
#pragma once

#include <functional>
#include <nlohmann/json_fwd.hpp>
#include <optional>
#include <span>
#include <string>
#include <vector>

#include "engine/core/base.h"
#include "engine/sim/simulation.h"
#include "engine/core/units.h"

namespace zona {

/// The loading branch of a force-deformation curve (measured, or a run's), deformation
/// increasing, (point_count).
struct ForceCurve {
  std::vector<double> deformation;  ///< membrane deformation at the tip [m], (point_count)
  std::vector<double> force;        ///< axial needle force [N], (point_count)
  /// The curve ends at its puncture: its last point is the puncture (a `punctured` column said
  /// so, or the user did). Never assumed from the data alone.
  bool punctured = false;
  std::string source;      ///< the file it was read from ("" when built in memory)
  int rows = 0;            ///< data rows in the file
  int after_puncture = 0;  ///< rows left out: at or after the puncture (a `punctured` column)
  /// Rows left out because their deformation did not pass the largest before them (zona's
  /// force.csv: the unloaded rows at 0, the tip sliding back).
  int not_advancing = 0;
};

/// Reads a CSV with columns deformation_m and force_N (others ignored; '#' lines are comments).
/// A file with a `punctured` column (zona's own force.csv, docs/outputs.md) gives its loading
/// branch: the rows before the first punctured one that reach a new largest deformation, the
/// curve marked punctured when a punctured row follows. Without that column the deformation
/// must increase from row to row (a measured curve). Errors name the file and line.
Result<ForceCurve> read_force_curve_csv(const std::string& path);

/// A simulated curve: the run's loading branch (samples before puncture at each new largest
/// deformation, then the puncture point) and how the run ended.
struct SimulatedCurve {
  ForceCurve loading;               ///< punctured = the run punctured
  double puncture_force = 0;        ///< [N], when punctured
  double peak_force = 0;            ///< [N]
  std::optional<bool> quasi_static; ///< the run's quasi-static check (nullopt: not judged)
  double wall_seconds = 0;          ///< of the run [s]
};

/// A run's simulated curve.
SimulatedCurve simulated_curve(const RunResult& run);

/// The simulated curve of a `zona run` output folder (force.csv and summary.json).
Result<SimulatedCurve> read_simulated_curve(const std::string& run_folder);

/// Residuals of one measured curve against a simulated one [N]: at each data point, the
/// simulated force there minus the measured one (the simulated loading branch interpolated;
/// past its reach 0 when the run punctured, else its last force); for a punctured data curve one
/// more, the run's puncture force (its peak force when it did not puncture) minus the data's
/// last force. `past_reach` (may be null) counts data points beyond the run's reach.
std::vector<double> curve_residuals(const SimulatedCurve& simulated, const ForceCurve& data,
                                    int* past_reach = nullptr);

/// One parameter to fit: a scene key and its range.
struct FitParameter {
  std::string key;           ///< scene key path, as for --set ("materials.default.young")
  double lower = 0;          ///< lower bound in SI [unit of the key]
  double upper = 0;          ///< upper bound in SI, > lower
  Dimension dimension;       ///< dimension of the key's value (written back with its SI unit)
};

/// Parses "KEY=LO..HI" ("materials.default.young=10kPa..100kPa"); "KEY" alone takes the range
/// [v / 4, 4 v] around the key's value v in `scene_json` (the scene after overrides).
Result<FitParameter> parse_fit_parameter(const std::string& spec, const nlohmann::json& scene_json);

/// The "key=value" override that sets a parameter to `value` [SI].
std::string fit_override(const FitParameter& parameter, double value);

/// How far a run's curves are from the data.
struct CurveError {
  double rms = 0;         ///< RMS of the residuals [N]
  double relative = 0;    ///< rms over the RMS of the measured forces compared [-]
  int points = 0;         ///< residuals: loading points plus puncture forces
  int puncture_terms = 0; ///< of which puncture forces (one per punctured data curve)
  int past_reach = 0;     ///< data points beyond the run's reach (its puncture, or its end)
};

/// The error of one simulated curve against all the data curves.
CurveError force_curve_error(const SimulatedCurve& simulated, std::span<const ForceCurve> data);

/// One evaluation of the objective: a run at `values`.
struct CalibrationEvaluation {
  std::vector<double> values;  ///< parameter values [SI], (parameter_count)
  std::string role;            ///< "scan", "jacobian" or "step": why it ran
  CurveError error;
  double sum_squares = 0;      ///< of the residuals [N^2]
  bool ok = false;             ///< the run was built and advanced to its end or puncture
  std::string message;         ///< why not, when !ok
  bool punctured = false;
  double puncture_deformation = 0;  ///< [m]
  double puncture_force = 0;        ///< [N]
  std::optional<bool> quasi_static;
  double wall_seconds = 0;
  std::vector<std::vector<double>> residuals;  ///< per data curve [N], (curve_count x its points)
};

/// Runs a batch of evaluations at once: each entry the overrides of one run; the results in the
/// same order. The CLI runs them as `zona run` children of a worker pool (--jobs).
using EvaluateBatch = std::function<std::vector<Result<SimulatedCurve>>(
    const std::vector<std::vector<std::string>>& overrides)>;

/// Options of calibrate().
struct CalibrateOptions {
  int max_evaluations = 40;      ///< runs at most (scan, Jacobians and steps included)
  /// Converged when an accepted step moves every normalised parameter (in [0, 1], log scale
  /// for positive ranges) by less than this [-].
  double tolerance = 2e-3;
  int grid_points = 5;           ///< one parameter: points of the initial scan (0: none)
  int batch = 1;                 ///< evaluations that run at once (--jobs): trial steps per iteration
  int bootstrap = 200;           ///< bootstrap replicates over curves (0: none)
  double confidence = 0.95;      ///< of the intervals
  unsigned seed = 1;             ///< of the bootstrap's resampling
  RunOptions run;                ///< in-process runs (when `evaluate` is empty)
  EvaluateBatch evaluate;        ///< empty: run_scene in this process, one run after another
  /// Called after each evaluation (progress lines; may be empty).
  std::function<void(const CalibrationEvaluation&, int index)> progress;
};

/// What calibrate() found.
struct CalibrationResult {
  std::vector<FitParameter> parameters;
  CalibrationEvaluation best;                 ///< the best evaluation
  std::vector<CalibrationEvaluation> history; ///< every evaluation, in order
  bool converged = false;                     ///< tolerance reached before max_evaluations
  std::string stop_reason;                    ///< in words
  int curve_count = 0;
  /// Bootstrap intervals [SI], (parameter_count) each; empty without a bootstrap (one curve).
  std::vector<double> interval_lower, interval_upper;
  std::vector<double> bootstrap_sd;           ///< spread of the replicates [SI]
  int replicates = 0;
  std::string interval_note;                  ///< why there is no interval, or how it was made
  /// Parameter correlations (parameter_count x parameter_count), in the normalised (log)
  /// parameters: from the bootstrap replicates, and from the fit's curvature (J^T J)^-1.
  std::vector<std::vector<double>> bootstrap_correlation, curvature_correlation;
};

/// Fits `parameters` of the scene at `scene_path` (with `overrides` applied first) to `data`.
/// Errors: unreadable scene, no parameter, a bound the scene rejects, no run that succeeded.
Result<CalibrationResult> calibrate(const std::string& scene_path,
                                    const std::vector<std::string>& overrides,
                                    const std::vector<FitParameter>& parameters,
                                    std::span<const ForceCurve> data, const CalibrateOptions& options = {});

}  // namespace zona
