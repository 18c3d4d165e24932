// `zona calibrate SCENE --data F.csv [--data G.csv ...] --fit KEY[=LO..HI] ...`: fits scene
// parameters to measured (or zona's own) force-deformation curves, least squares on the loading
// branch, each evaluation a `zona run` child of a worker pool (--jobs at once), with bootstrap
// intervals over the curves (engine/analysis/calibrate.h, docs/sweeps.md).
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <memory>
#include <sstream>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "apps/commands.h"
#include "engine/analysis/calibrate.h"
#include "engine/analysis/worker_pool.h"
#include "engine/core/thread_pool.h"
#include "engine/scene/scene.h"
#include "kernels/backend_info.h"

namespace zona::cli {
namespace {

namespace fs = std::filesystem;

struct CalibrateArgs {
  std::string scene;
  std::vector<std::string> data;
  std::vector<std::string> fits;
  std::vector<std::string> sets;
  std::string backend = "cpu";
  std::string solver;
  int jobs = 1;
  int threads = -1;  // -1: the cores over the jobs
  int max_evaluations = 40;
  double tolerance = 2e-3;
  int grid_points = 5;
  int bootstrap = 200;
  double confidence = 0.95;
  unsigned seed = 1;
  bool puncture_at_end = false;
  std::string keep_runs;
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

std::string read_text(const fs::path& p) {
  std::ifstream in(p, std::ios::binary);
  std::ostringstream s;
  s << in.rdbuf();
  return s.str();
}

// The error line of a run's log ("zona: error: ..."), else its last line.
std::string log_error(const std::string& log) {
  std::istringstream in(log);
  std::string line, last, error;
  while (std::getline(in, line)) {
    if (line.find_first_not_of(" \t\r") == std::string::npos) continue;
    last = line;
    if (line.rfind("zona: error: ", 0) == 0) error = line.substr(13);
  }
  return error.empty() ? last : error;
}

// The evaluations of a batch as `zona run` children, `jobs` at once (one GPU each with cuda).
EvaluateBatch process_evaluator(const CalibrateArgs& a, const std::string& scene, const std::string& work,
                                int threads, std::vector<std::string> devices) {
  auto counter = std::make_shared<size_t>(0);
  return [a, scene, work, threads, devices, counter](const std::vector<std::vector<std::string>>& batch) {
    std::vector<WorkerJob> jobs;
    std::vector<std::string> folders;
    for (const std::vector<std::string>& overrides : batch) {
      char name[32];
      std::snprintf(name, sizeof name, "eval_%04zu", (*counter)++);
      const std::string folder = (fs::path(work) / name).string();
      std::error_code ec;
      fs::create_directories(folder, ec);
      WorkerJob job;
      job.argv = {self_executable(), "run", scene, "--out", folder, "--quiet", "--no-frames", "--no-plot",
                  "--stop-after-puncture", "0", "--backend", a.backend, "--threads", std::to_string(threads)};
      for (const std::string& o : overrides) job.argv.insert(job.argv.end(), {"--set", o});
      job.log_path = folder + "/run.log";
      jobs.push_back(job);
      folders.push_back(folder);
    }
    std::vector<Result<SimulatedCurve>> out(batch.size(), make_error("not run"));
    WorkerPoolOptions options;
    options.workers = a.jobs;
    if (!devices.empty())
      options.slot_env = [devices](int slot) {
        return std::vector<std::string>{"CUDA_VISIBLE_DEVICES=" + devices[static_cast<size_t>(slot) % devices.size()]};
      };
    run_worker_pool(jobs, options, [&](size_t i, const WorkerOutcome& o) {
      // A run that was not quasi-static exits 1 with its outputs written: its curve counts,
      // flagged in the history.
      Result<SimulatedCurve> curve = read_simulated_curve(folders[i]);
      if (!curve.ok() || !o.started || o.signal) {
        const std::string why = log_error(read_text(fs::path(folders[i]) / "run.log"));
        out[i] = make_error("%s%s%s", describe_outcome(o).c_str(), why.empty() ? "" : ": ", why.c_str());
        return;
      }
      curve->wall_seconds = o.wall_seconds;
      out[i] = *curve;
    });
    return out;
  };
}

std::string role_counts(const CalibrationResult& r) {
  std::string text;
  for (const char* role : {"scan", "start", "jacobian", "step"}) {
    const auto n = std::count_if(r.history.begin(), r.history.end(),
                                 [&](const CalibrationEvaluation& e) { return e.role == role; });
    if (n) text += (text.empty() ? "" : ", ") + std::to_string(n) + " " + role;
  }
  return text;
}

Status run_calibrate(const CalibrateArgs& a) {
  Result<std::string> path = find_scene_file(a.scene);
  if (!path.ok()) return path.error();
  if (a.jobs < 1) return make_error("--jobs must be >= 1");
  if (a.backend != "cpu" && a.backend != "cuda" && a.backend != "auto")
    return make_error("--backend '%s': expected auto, cpu or cuda", a.backend.c_str());
  if (!(a.confidence > 0 && a.confidence < 1)) return make_error("--confidence must be in (0, 1)");
  std::vector<ForceCurve> curves;
  for (const std::string& file : a.data) {
    Result<ForceCurve> c = read_force_curve_csv(file);
    if (!c.ok()) return c.error();
    // A measured file says nothing of a puncture unless told: its last point is one only then.
    if (a.puncture_at_end && c->after_puncture == 0) c->punctured = true;
    curves.push_back(*c);
  }
  // The scene's JSON after the overrides, for "KEY" alone (range around its value).
  // Read as load_scene reads it (size and depth bounded, duplicate keys refused).
  nlohmann::json doc;
  if (Status st = read_scene_json(*path, &doc); !st) return st;
  std::vector<std::string> sets = a.sets;
  if (!a.solver.empty()) sets.push_back("solver.method=" + a.solver);
  for (const std::string& s : sets)
    if (Status st = apply_override(doc, s); !st) return st;
  std::vector<FitParameter> parameters;
  for (const std::string& f : a.fits) {
    Result<FitParameter> p = parse_fit_parameter(f, doc);
    if (!p.ok()) return p.error();
    parameters.push_back(*p);
  }

  // Each evaluation a `zona run` child in a work folder (kept with --keep-runs).
  std::string work = a.keep_runs;
  bool remove_work = false;
  if (work.empty()) {
    std::string pattern = (fs::temp_directory_path() / "zona_calibrate_XXXXXX").string();
    if (!mkdtemp(pattern.data())) return make_error("cannot create a work folder in %s", fs::temp_directory_path().c_str());
    work = pattern;
    remove_work = true;
  }
  std::vector<std::string> devices;
  if (a.backend == "cuda") {
    for (const DeviceInfo& d : cuda_devices(nullptr)) devices.push_back(std::to_string(d.ordinal));
    if (devices.empty()) return make_error("--backend cuda: no CUDA device (zona info lists them)");
  }
  const int cores = available_cores();
  const int threads = a.threads >= 0 ? a.threads : std::max(1, cores / a.jobs);

  CalibrateOptions options;
  options.max_evaluations = a.max_evaluations;
  options.tolerance = a.tolerance;
  options.grid_points = a.grid_points;
  options.batch = a.jobs;
  options.bootstrap = a.bootstrap;
  options.confidence = a.confidence;
  options.seed = a.seed;
  options.evaluate = process_evaluator(a, *path, work, threads, devices);
  const bool quiet = a.quiet;
  const std::vector<FitParameter> params_copy = parameters;
  options.progress = [&](const CalibrationEvaluation& ev, int index) {
    if (quiet) return;
    std::string values;
    for (size_t i = 0; i < ev.values.size(); ++i)
      values.append(i ? ", " : "").append(format_quantity(ev.values[i], params_copy[i].dimension, 5));
    if (ev.ok)
      std::fprintf(stderr, "zona calibrate: run %2d (%s): %s -> rms %.4g N (%.2f %%)%s%s  [%.1f s]\n", index + 1,
                   ev.role.c_str(), values.c_str(), ev.error.rms, 100 * ev.error.relative,
                   ev.punctured ? "" : ", no puncture",
                   ev.quasi_static && !*ev.quasi_static ? ", not quasi-static" : "", ev.wall_seconds);
    else
      std::fprintf(stderr, "zona calibrate: run %2d (%s): %s -> failed: %s\n", index + 1, ev.role.c_str(),
                   values.c_str(), ev.message.c_str());
  };

  const auto start = std::chrono::steady_clock::now();
  Result<CalibrationResult> r = calibrate(*path, sets, parameters, curves, options);
  const double wall = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  if (remove_work) {
    std::error_code ec;
    fs::remove_all(work, ec);
  }
  if (!r.ok()) return r.error();
  const CalibrationEvaluation& best = r->best;
  int loading_points = 0, puncture_terms = 0;
  for (const ForceCurve& c : curves) {
    loading_points += static_cast<int>(c.deformation.size());
    puncture_terms += c.punctured ? 1 : 0;
  }
  const bool has_interval = !r->interval_lower.empty();

  if (a.json) {
    using nlohmann::json;
    json data = json::array();
    for (const ForceCurve& c : curves)
      data.push_back({{"file", c.source}, {"rows", c.rows}, {"loading_points", c.deformation.size()},
                      {"punctured", c.punctured}, {"rows_after_puncture", c.after_puncture},
                      {"rows_not_advancing", c.not_advancing}});
    json params = json::array();
    json fitted = json::object();
    for (size_t i = 0; i < r->parameters.size(); ++i) {
      const FitParameter& p = r->parameters[i];
      fitted[p.key] = best.values[i];
      json e = {{"key", p.key}, {"value", best.values[i]}, {"range", {p.lower, p.upper}},
                {"text", format_quantity(best.values[i], p.dimension, 5)}};
      e["interval"] = has_interval ? json{r->interval_lower[i], r->interval_upper[i]} : json(nullptr);
      e["bootstrap_sd"] = has_interval ? json(r->bootstrap_sd[i]) : json(nullptr);
      params.push_back(e);
    }
    json history = json::array();
    for (size_t i = 0; i < r->history.size(); ++i) {
      const CalibrationEvaluation& ev = r->history[i];
      json values = json::object();
      for (size_t k = 0; k < ev.values.size(); ++k) values[r->parameters[k].key] = ev.values[k];
      json h = {{"index", i}, {"role", ev.role}, {"values", values}, {"ok", ev.ok}, {"wall_s", ev.wall_seconds}};
      if (ev.ok) {
        h["sum_squares_N2"] = ev.sum_squares;
        h["rms_error_N"] = ev.error.rms;
        h["relative_error"] = ev.error.relative;
        h["punctured"] = ev.punctured;
        if (ev.punctured) h["puncture"] = {{"deformation_m", ev.puncture_deformation}, {"force_N", ev.puncture_force}};
        h["quasi_static"] = ev.quasi_static ? json(*ev.quasi_static) : json(nullptr);
      } else {
        h["message"] = ev.message;
      }
      history.push_back(h);
    }
    json j = {{"scene", *path},
              {"data", data},
              {"parameters", params},
              {"fitted", fitted},
              {"fitted_text", values_text(*r, best.values)},
              {"rms_error_N", best.error.rms},
              {"relative_error", best.error.relative},
              {"points", {{"curves", curves.size()}, {"loading_points", loading_points},
                          {"puncture_forces", puncture_terms}, {"residuals", best.error.points},
                          {"past_the_runs_reach", best.error.past_reach}}},
              {"interval", {{"confidence", a.confidence}, {"replicates", r->replicates},
                            {"seed", a.seed}, {"note", r->interval_note}}},
              {"correlation", {{"keys", json::array()},
                               {"bootstrap", r->bootstrap_correlation},
                               {"curvature", r->curvature_correlation}}},
              {"evaluations", r->history.size()},
              {"jobs", a.jobs},
              {"wall_s", wall},
              {"converged", r->converged},
              {"stop_reason", r->stop_reason},
              {"puncture", {{"punctured", best.punctured},
                            {"deformation_m", best.puncture_deformation},
                            {"force_N", best.puncture_force}}},
              {"history", history}};
    for (const FitParameter& p : r->parameters) j["correlation"]["keys"].push_back(p.key);
    std::printf("%s\n", j.dump(2).c_str());
    return Status::ok_status();
  }

  std::printf("data: %zu curve%s, %d points on the loading branch%s\n", curves.size(),
              curves.size() == 1 ? "" : "s", loading_points,
              puncture_terms ? (", " + std::to_string(puncture_terms) + " ending at a puncture").c_str() : "");
  for (const ForceCurve& c : curves) {
    std::printf("  %s: %d rows, %zu on the loading branch", c.source.c_str(), c.rows, c.deformation.size());
    if (c.after_puncture) std::printf(", %d at or after the puncture", c.after_puncture);
    if (c.not_advancing) std::printf(", %d not advancing the deformation", c.not_advancing);
    std::printf("%s\n", c.punctured ? "; its last point is its puncture" : "");
  }
  for (size_t i = 0; i < r->parameters.size(); ++i) {
    const FitParameter& p = r->parameters[i];
    std::printf("fitted: %s = %s", p.key.c_str(), format_quantity(best.values[i], p.dimension, 5).c_str());
    if (has_interval)
      std::printf("  (%.0f %% interval %s .. %s)", 100 * a.confidence,
                  format_quantity(r->interval_lower[i], p.dimension, 4).c_str(),
                  format_quantity(r->interval_upper[i], p.dimension, 4).c_str());
    std::printf("\n");
  }
  std::printf("interval: %s\n", r->interval_note.c_str());
  std::printf("fit error: rms %.4g N (%.2f %% of the data's rms force) over %d residuals: %d loading "
              "points of %zu curve%s%s\n",
              best.error.rms, 100 * best.error.relative, best.error.points, loading_points, curves.size(),
              curves.size() == 1 ? "" : "s",
              puncture_terms ? (" and " + std::to_string(puncture_terms) + " puncture force(s)").c_str() : "");
  if (best.error.past_reach)
    std::printf("note: %d data points lie past the fitted run's %s\n", best.error.past_reach,
                best.punctured ? "puncture (compared with force 0)" : "end (compared with its last force)");
  const auto& corr = has_interval ? r->bootstrap_correlation : r->curvature_correlation;
  for (size_t i = 0; i < corr.size(); ++i)
    for (size_t k = i + 1; k < corr.size(); ++k)
      std::printf("correlation (%s): %s ~ %s: %+.3f\n", has_interval ? "bootstrap" : "curvature of the fit",
                  r->parameters[i].key.c_str(), r->parameters[k].key.c_str(), corr[i][k]);
  if (best.punctured)
    std::printf("puncture at the fit: deformation %.2f um, force %.4g uN\n", best.puncture_deformation * 1e6,
                best.puncture_force * 1e6);
  else
    std::printf("puncture at the fit: none\n");
  if (best.quasi_static && !*best.quasi_static)
    std::printf("warning: the run at the fit was not quasi-static (summary.json's check)\n");
  std::printf("%zu runs (%s), %d at once, wall %.1f s; %s\n", r->history.size(), role_counts(*r).c_str(),
              a.jobs, wall, r->converged ? ("converged: " + r->stop_reason).c_str()
                                         : ("not converged: " + r->stop_reason).c_str());
  return Status::ok_status();
}

}  // namespace

void add_calibrate_command(CLI::App& app) {
  auto args = std::make_shared<CalibrateArgs>();
  auto* cmd = app.add_subcommand(
      "calibrate", "Fit scene parameters to force-deformation curves (CSV deformation_m,force_N, or zona's force.csv)");
  cmd->add_option("scene", args->scene, "Scene file or name")->required();
  cmd->add_option("--data", args->data,
                  "A curve: CSV with deformation_m,force_N, or a zona force.csv (its loading branch); "
                  "repeat for several cells or runs, fitted jointly")
      ->required();
  cmd->add_option("--fit", args->fits,
                  "Parameter to fit: KEY=LO..HI (e.g. materials.default.young=10kPa..80kPa), or KEY "
                  "for a factor 4 around the scene's value (repeatable)")
      ->required();
  cmd->add_option("--set", args->sets, "Override a scene key first: key.path=value (repeatable)");
  cmd->add_option("--backend", args->backend, "Compute backend of the runs: auto, cpu or cuda")->capture_default_str();
  cmd->add_option("--solver", args->solver, "Solver of the runs: sets solver.method (explicit, static)");
  cmd->add_option("--jobs", args->jobs, "Runs at once (with --backend cuda: one GPU each)")->capture_default_str();
  cmd->add_option("--threads", args->threads, "CPU threads per run (default: the cores over --jobs)");
  cmd->add_option("--max-evaluations", args->max_evaluations, "Runs at most")->capture_default_str();
  cmd->add_option("--tolerance", args->tolerance,
                  "Converged when a step moves every parameter by less than this fraction of its range (log scale)")
      ->capture_default_str();
  cmd->add_option("--grid-points", args->grid_points, "One parameter: points of the first scan (0: none)")
      ->capture_default_str();
  cmd->add_option("--bootstrap", args->bootstrap, "Bootstrap replicates over the curves (0: none)")
      ->capture_default_str();
  cmd->add_option("--confidence", args->confidence, "Of the intervals")->capture_default_str();
  cmd->add_option("--seed", args->seed, "Of the bootstrap's resampling")->capture_default_str();
  cmd->add_flag("--puncture-at-end", args->puncture_at_end,
                "The last point of each measured curve is its puncture (fit the puncture force too); "
                "zona's force.csv says so itself");
  cmd->add_option("--keep-runs", args->keep_runs, "Keep every evaluation's zona run folder here");
  cmd->add_flag("--json", args->json, "Print the result, intervals and the evaluation history as JSON");
  cmd->add_flag("--quiet", args->quiet, "No line per run on stderr");
  cmd->callback([args] {
    if (Status s = run_calibrate(*args); !s) fail(s.error().message);
  });
}

}  // namespace zona::cli
