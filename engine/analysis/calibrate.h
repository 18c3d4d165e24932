// Calibration: fits scene parameters (material moduli, puncture thresholds, any numeric key that
// --set can override) to a measured force-deformation curve by running the scene repeatedly.
//
// The objective is the RMS difference of the needle force at the measured deformations. Both
// curves are taken as zero past their puncture (when the data ends in one): a run that punctures
// early misses the force of the data's later points, one that punctures late is charged its force
// past the data's end. Each parameter moves in [lower, upper], on a log scale when both bounds are
// positive; one parameter is found by a grid scan and golden-section search, several by
// Nelder-Mead (both derivative-free: each evaluation is a whole run, and puncture makes the
// objective step-wise).
#pragma once

#include <functional>
#include <nlohmann/json_fwd.hpp>
#include <string>
#include <vector>

#include "engine/core/base.h"
#include "engine/sim/simulation.h"
#include "engine/core/units.h"

namespace zona {

/// A measured force-deformation curve, (point_count), deformation increasing.
struct ForceCurve {
  std::vector<double> deformation;  ///< membrane deformation at the tip [m], (point_count)
  std::vector<double> force;        ///< axial needle force [N], (point_count)
};

/// Reads a CSV with columns deformation_m and force_N (others ignored; '#' lines are comments).
/// Errors name the file and line.
Result<ForceCurve> read_force_curve_csv(const std::string& path);

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

/// How far a run's curve is from the data.
struct CurveError {
  double rms = 0;         ///< RMS force difference over the compared points [N]
  double relative = 0;    ///< rms over the RMS of the measured forces [-]
  int points = 0;         ///< points compared (the data's, plus those past its puncture)
};

/// Compares a run's loading curve (samples before puncture; force interpolated at each
/// deformation, the largest deformation reached so far for a non-monotonic curve) with the data.
/// `data_punctures`: the data's last point is its puncture (force 0 beyond it).
CurveError force_curve_error(const RunResult& run, const ForceCurve& data, bool data_punctures);

/// One evaluation of the objective: a run at `values`.
struct CalibrationEvaluation {
  std::vector<double> values;  ///< parameter values [SI], (parameter_count)
  CurveError error;
  bool ok = false;             ///< the run was built and advanced to its end or puncture
  std::string message;         ///< why not, when !ok
  PunctureRecord puncture;
  double wall_seconds = 0;
};

/// Options of calibrate().
struct CalibrateOptions {
  int max_evaluations = 40;      ///< runs at most (grid and search included)
  /// Converged when the bracket (1-D) or the simplex (n-D) is this small in the normalised
  /// parameter [0, 1] (log scale: 0.002 is 0.5 % of a factor-10 range) [-].
  double tolerance = 2e-3;
  int grid_points = 7;           ///< 1-D: points of the initial scan, >= 3
  bool data_punctures = true;    ///< the data's last point is its puncture
  RunOptions run;                ///< per run (stop_after_puncture defaults to 0 here)
  /// Called after each evaluation (progress lines; may be empty).
  std::function<void(const CalibrationEvaluation&, int index)> progress;
};

/// What calibrate() found.
struct CalibrationResult {
  std::vector<FitParameter> parameters;
  CalibrationEvaluation best;                 ///< the best evaluation
  std::vector<CalibrationEvaluation> history; ///< every evaluation, in order
  bool converged = false;                     ///< tolerance reached before max_evaluations
};

/// Fits `parameters` of the scene at `scene_path` (with `overrides` applied first) to `data`.
/// Errors: unreadable scene, no parameter, a bound the scene rejects, no run that succeeded.
Result<CalibrationResult> calibrate(const std::string& scene_path,
                                    const std::vector<std::string>& overrides,
                                    const std::vector<FitParameter>& parameters,
                                    const ForceCurve& data, const CalibrateOptions& options = {});

}  // namespace zona
