// `zona calibrate SCENE --data FILE.csv --fit KEY[=LO..HI] ...`: fits scene parameters to a
// measured force-deformation curve by running the scene repeatedly (engine/analysis/calibrate.h).
#include <cmath>
#include <cstdio>
#include <memory>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "apps/commands.h"
#include "engine/analysis/calibrate.h"
#include "engine/scene/scene.h"

namespace zona::cli {
namespace {

struct CalibrateArgs {
  std::string scene;
  std::string data;
  std::vector<std::string> fits;
  std::vector<std::string> sets;
  int max_evaluations = 40;
  double tolerance = 2e-3;
  int threads = 0;
  bool no_puncture = false;
  bool json = false;
  bool quiet = false;
};

std::string values_text(const CalibrationResult& r, const std::vector<double>& values) {
  std::string text;
  for (size_t i = 0; i < values.size(); ++i) {
    if (i) text.append(", ");
    text.append(r.parameters[i].key).append(" = ").append(format_quantity(values[i], r.parameters[i].dimension, 5));
  }
  return text;
}

Status run_calibrate(const CalibrateArgs& a) {
  Result<std::string> path = find_scene_file(a.scene);
  if (!path.ok()) return path.error();
  Result<ForceCurve> data = read_force_curve_csv(a.data);
  if (!data.ok()) return data.error();
  // The scene's JSON after the overrides, for "KEY" alone (range around its value).
  // Read as load_scene reads it (size and depth bounded, duplicate keys refused).
  nlohmann::json doc;
  if (Status st = read_scene_json(*path, &doc); !st) return st;
  for (const std::string& s : a.sets)
    if (Status st = apply_override(doc, s); !st) return st;
  std::vector<FitParameter> parameters;
  for (const std::string& f : a.fits) {
    Result<FitParameter> p = parse_fit_parameter(f, doc);
    if (!p.ok()) return p.error();
    parameters.push_back(*p);
  }

  CalibrateOptions options;
  options.max_evaluations = a.max_evaluations;
  options.tolerance = a.tolerance;
  options.data_punctures = !a.no_puncture;
  options.run.simulation.threads = a.threads;
  options.run.progress_interval = 1e30;
  const bool quiet = a.quiet;
  const std::vector<FitParameter> params_copy = parameters;
  options.progress = [&](const CalibrationEvaluation& ev, int index) {
    if (quiet) return;
    std::string values;
    for (size_t i = 0; i < ev.values.size(); ++i)
      values.append(i ? ", " : "").append(format_quantity(ev.values[i], params_copy[i].dimension, 5));
    if (ev.ok)
      std::fprintf(stderr, "zona calibrate: run %2d: %s -> rms %.4g N (%.2f %%)%s  [%.1f s]\n", index + 1,
                   values.c_str(), ev.error.rms, 100 * ev.error.relative,
                   ev.puncture.punctured ? "" : ", no puncture", ev.wall_seconds);
    else
      std::fprintf(stderr, "zona calibrate: run %2d: %s -> failed: %s\n", index + 1, values.c_str(),
                   ev.message.c_str());
  };

  Result<CalibrationResult> r = calibrate(*path, a.sets, parameters, *data, options);
  if (!r.ok()) return r.error();
  const CalibrationEvaluation& best = r->best;

  if (a.json) {
    nlohmann::json fitted = nlohmann::json::object();
    nlohmann::json ranges = nlohmann::json::object();
    for (size_t i = 0; i < r->parameters.size(); ++i) {
      fitted[r->parameters[i].key] = best.values[i];
      ranges[r->parameters[i].key] = {r->parameters[i].lower, r->parameters[i].upper};
    }
    nlohmann::json j = {
        {"scene", *path},
        {"data", a.data},
        {"data_points", data->deformation.size()},
        {"fitted", fitted},
        {"fitted_text", values_text(*r, best.values)},
        {"ranges_si", ranges},
        {"rms_error_N", best.error.rms},
        {"relative_error", best.error.relative},
        {"points_compared", best.error.points},
        {"evaluations", r->history.size()},
        {"converged", r->converged},
        {"puncture", {{"punctured", best.puncture.punctured},
                      {"deformation_m", best.puncture.deformation},
                      {"force_N", best.puncture.force}}}};
    std::printf("%s\n", j.dump(2).c_str());
  } else {
    std::printf("fitted: %s\n", values_text(*r, best.values).c_str());
    std::printf("fit error: rms %.4g N (%.2f %% of the data's rms force) over %d points\n",
                best.error.rms, 100 * best.error.relative, best.error.points);
    if (best.puncture.punctured)
      std::printf("puncture at the fit: deformation %.2f um, force %.4g uN\n",
                  best.puncture.deformation * 1e6, best.puncture.force * 1e6);
    else
      std::printf("puncture at the fit: none\n");
    std::printf("%zu runs, %s\n", r->history.size(),
                r->converged ? "converged" : "stopped at --max-evaluations before the tolerance");
  }
  return Status::ok_status();
}

}  // namespace

void add_calibrate_command(CLI::App& app) {
  auto args = std::make_shared<CalibrateArgs>();
  auto* cmd = app.add_subcommand(
      "calibrate", "Fit scene parameters to a measured force-deformation curve (CSV deformation_m,force_N)");
  cmd->add_option("scene", args->scene, "Scene file or name")->required();
  cmd->add_option("--data", args->data, "Measured curve: CSV with deformation_m,force_N")->required();
  cmd->add_option("--fit", args->fits,
                  "Parameter to fit: KEY=LO..HI (e.g. materials.default.young=10kPa..80kPa), or KEY "
                  "for a factor 4 around the scene's value (repeatable)")
      ->required();
  cmd->add_option("--set", args->sets, "Override a scene key first: key.path=value (repeatable)");
  cmd->add_option("--max-evaluations", args->max_evaluations, "Runs at most")->capture_default_str();
  cmd->add_option("--tolerance", args->tolerance,
                  "Stop when the search interval is this small (fraction of the range, log scale)")
      ->capture_default_str();
  cmd->add_option("--threads", args->threads, "CPU threads per run (0: all)")->capture_default_str();
  cmd->add_flag("--no-puncture", args->no_puncture,
                "The data's last point is not a puncture (do not charge runs that load past it)");
  cmd->add_flag("--json", args->json, "Print the result as JSON");
  cmd->add_flag("--quiet", args->quiet, "No line per run on stderr");
  cmd->callback([args] {
    if (Status s = run_calibrate(*args); !s) fail(s.error().message);
  });
}

}  // namespace zona::cli
