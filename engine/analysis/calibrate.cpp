// Calibration of scene parameters against force-deformation curves: least squares on the loading
// branch (Levenberg-Marquardt), a bootstrap over curves for the intervals (engine/analysis/calibrate.h).
#include "engine/analysis/calibrate.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <fstream>
#include <limits>
#include <numeric>
#include <random>
#include <sstream>

#include <Eigen/Dense>

#include <nlohmann/json.hpp>

#include "engine/scene/scene.h"

namespace zona {
namespace {

using nlohmann::json;

std::vector<std::string> split_csv_line(const std::string& line) {
  std::vector<std::string> out;
  std::string cell;
  std::istringstream in(line);
  while (std::getline(in, cell, ',')) {
    const size_t b = cell.find_first_not_of(" \t\r");
    const size_t e = cell.find_last_not_of(" \t\r");
    out.push_back(b == std::string::npos ? "" : cell.substr(b, e - b + 1));
  }
  return out;
}

// Linear interpolation in a sorted table, clamped at its ends.
double interpolate(const std::vector<double>& x, const std::vector<double>& y, double at) {
  if (x.empty()) return 0.0;
  if (at <= x.front()) return y.front();
  if (at >= x.back()) return y.back();
  const size_t i = static_cast<size_t>(std::upper_bound(x.begin(), x.end(), at) - x.begin());
  const double t = (at - x[i - 1]) / (x[i] - x[i - 1]);
  return y[i - 1] + t * (y[i] - y[i - 1]);
}

// Normalised coordinate s in [0, 1] to a value: log scale for positive ranges.
double to_value(const FitParameter& p, double s) {
  s = std::clamp(s, 0.0, 1.0);
  if (p.lower > 0) return p.lower * std::pow(p.upper / p.lower, s);
  return p.lower + s * (p.upper - p.lower);
}

}  // namespace

Result<ForceCurve> read_force_curve_csv(const std::string& path) {
  // Before opening: a FIFO blocks the open, a device (/dev/zero) never ends.
  if (Status st = check_regular_file(path); !st) return st.error();
  std::ifstream in(path);
  if (!in) return make_error("%s: cannot open", path.c_str());
  std::string line;
  int line_number = 0, id = -1, iforce = -1, ipunct = -1;
  ForceCurve curve;
  curve.source = path;
  bool in_loading = true;
  while (std::getline(in, line)) {
    ++line_number;
    if (line.empty() || line[0] == '#' || line.find_first_not_of(" \t\r") == std::string::npos) continue;
    const std::vector<std::string> cells = split_csv_line(line);
    if (id < 0) {
      for (size_t i = 0; i < cells.size(); ++i) {
        if (cells[i] == "deformation_m") id = static_cast<int>(i);
        if (cells[i] == "force_N") iforce = static_cast<int>(i);
        if (cells[i] == "punctured") ipunct = static_cast<int>(i);
      }
      if (id < 0 || iforce < 0)
        return make_error("%s:%d: the header needs columns deformation_m and force_N", path.c_str(), line_number);
      continue;
    }
    const int needed = std::max({id, iforce, ipunct});
    if (static_cast<int>(cells.size()) <= needed)
      return make_error("%s:%d: expected at least %d columns", path.c_str(), line_number, needed + 1);
    ++curve.rows;
    char* end = nullptr;
    const double d = std::strtod(cells[static_cast<size_t>(id)].c_str(), &end);
    const bool d_ok = end && *end == '\0' && !cells[static_cast<size_t>(id)].empty();
    const double f = std::strtod(cells[static_cast<size_t>(iforce)].c_str(), &end);
    const bool f_ok = end && *end == '\0' && !cells[static_cast<size_t>(iforce)].empty();
    if (!d_ok || !f_ok || !std::isfinite(d) || !std::isfinite(f))
      return make_error("%s:%d: deformation_m and force_N must be numbers", path.c_str(), line_number);
    if (ipunct >= 0) {
      // zona's force.csv: the loading branch is the rows before the puncture that advance.
      const std::string& p = cells[static_cast<size_t>(ipunct)];
      if (p != "0" && p != "1")
        return make_error("%s:%d: punctured must be 0 or 1, got '%s'", path.c_str(), line_number, p.c_str());
      if (p == "1") in_loading = false;
      if (!in_loading) {
        curve.punctured = true;
        ++curve.after_puncture;
        continue;
      }
      if (!curve.deformation.empty() ? d <= curve.deformation.back() : d <= 0) {
        ++curve.not_advancing;
        continue;
      }
    } else if (!curve.deformation.empty() && d <= curve.deformation.back()) {
      return make_error("%s:%d: deformation_m must increase (%g after %g)", path.c_str(), line_number, d,
                        curve.deformation.back());
    }
    curve.deformation.push_back(d);
    curve.force.push_back(f);
  }
  if (id < 0) return make_error("%s: empty (no header)", path.c_str());
  if (curve.deformation.size() < 2)
    return make_error("%s: needs at least 2 data rows on the loading branch (has %zu)", path.c_str(),
                      curve.deformation.size());
  return curve;
}

SimulatedCurve simulated_curve(const RunResult& run) {
  SimulatedCurve c;
  for (const ForceSample& s : run.samples) {
    if (s.punctured) break;
    if (!std::isfinite(s.deformation) || !std::isfinite(s.force)) break;
    if (!c.loading.deformation.empty() && s.deformation <= c.loading.deformation.back()) continue;
    c.loading.deformation.push_back(s.deformation);
    c.loading.force.push_back(s.force);
  }
  c.loading.punctured = run.puncture.punctured;
  if (run.puncture.punctured) {
    c.puncture_force = run.puncture.force;
    // The puncture point closes the branch (the force the criterion fired at).
    if (c.loading.deformation.empty() || run.puncture.deformation > c.loading.deformation.back()) {
      c.loading.deformation.push_back(run.puncture.deformation);
      c.loading.force.push_back(run.puncture.force);
    }
  }
  c.peak_force = run.peak_force;
  if (quasi_static_measured(run.quasi_limits)) c.quasi_static = run.quasi_static();
  return c;
}

Result<SimulatedCurve> read_simulated_curve(const std::string& folder) {
  const std::string summary_path = folder + "/summary.json";
  std::ifstream in(summary_path);
  if (!in) return make_error("%s: no summary (the run did not finish)", summary_path.c_str());
  std::stringstream text;
  text << in.rdbuf();
  const json j = json::parse(text.str(), nullptr, false);
  if (j.is_discarded() || !j.is_object()) return make_error("%s: not valid JSON", summary_path.c_str());
  const json numerics = j.value("numerics", json::object());
  if (numerics.value("stopped_early", false))
    return make_error("run stopped early: %s", numerics.value("stop_reason", std::string("?")).c_str());
  SimulatedCurve c;
  Result<ForceCurve> loading = read_force_curve_csv(folder + "/force.csv");
  if (loading.ok()) c.loading = *loading;  // fewer than 2 points: an empty branch, not an error
  const json puncture = j.value("puncture", json::object());
  c.loading.punctured = puncture.value("punctured", false);
  if (c.loading.punctured) {
    c.puncture_force = puncture.value("force_N", 0.0);
    const double d = puncture.value("deformation_m", 0.0);
    if (c.loading.deformation.empty() || d > c.loading.deformation.back()) {
      c.loading.deformation.push_back(d);
      c.loading.force.push_back(c.puncture_force);
    }
  }
  c.peak_force = j.value("peak_force_N", 0.0);
  if (j.contains("quasi_static") && j["quasi_static"].is_boolean()) c.quasi_static = j["quasi_static"].get<bool>();
  return c;
}

std::vector<double> curve_residuals(const SimulatedCurve& sim, const ForceCurve& data, int* past_reach) {
  const std::vector<double>& d = sim.loading.deformation;
  const std::vector<double>& f = sim.loading.force;
  const double reach = d.empty() ? 0.0 : d.back();
  std::vector<double> r;
  r.reserve(data.deformation.size() + 1);
  int past = 0;
  for (size_t i = 0; i < data.deformation.size(); ++i) {
    const double at = data.deformation[i];
    double simulated = 0;
    if (at <= reach) {
      simulated = interpolate(d, f, at);
    } else {
      // Past the run's reach: punctured (force 0 after it) or stopped (its last force).
      ++past;
      simulated = sim.loading.punctured ? 0.0 : (f.empty() ? 0.0 : f.back());
    }
    r.push_back(simulated - data.force[i]);
  }
  if (data.punctured && !data.force.empty())
    r.push_back((sim.loading.punctured ? sim.puncture_force : sim.peak_force) - data.force.back());
  if (past_reach) *past_reach = past;
  return r;
}

CurveError force_curve_error(const SimulatedCurve& sim, std::span<const ForceCurve> data) {
  CurveError e;
  double sum = 0, sum_data = 0;
  for (const ForceCurve& curve : data) {
    int past = 0;
    const std::vector<double> r = curve_residuals(sim, curve, &past);
    e.past_reach += past;
    for (double x : r) sum += x * x;
    for (double x : curve.force) sum_data += x * x;
    if (curve.punctured && !curve.force.empty()) {
      sum_data += curve.force.back() * curve.force.back();
      ++e.puncture_terms;
    }
    e.points += static_cast<int>(r.size());
  }
  e.rms = e.points > 0 ? std::sqrt(sum / e.points) : 0.0;
  const double data_rms = e.points > 0 ? std::sqrt(sum_data / e.points) : 0.0;
  e.relative = data_rms > 0 ? e.rms / data_rms : 0.0;
  return e;
}

Result<FitParameter> parse_fit_parameter(const std::string& spec, const json& scene_json) {
  FitParameter p;
  const size_t eq = spec.find('=');
  p.key = spec.substr(0, eq);
  if (p.key.empty()) return make_error("--fit '%s': expected KEY or KEY=LO..HI", spec.c_str());
  if (eq != std::string::npos) {
    const std::string range = spec.substr(eq + 1);
    const size_t dots = range.find("..");
    if (dots == std::string::npos)
      return make_error("--fit %s: expected a range LO..HI, got '%s'", p.key.c_str(), range.c_str());
    Result<Quantity> lo = parse_quantity(range.substr(0, dots));
    Result<Quantity> hi = parse_quantity(range.substr(dots + 2));
    if (!lo.ok()) return make_error("--fit %s: %s", p.key.c_str(), lo.error().message.c_str());
    if (!hi.ok()) return make_error("--fit %s: %s", p.key.c_str(), hi.error().message.c_str());
    if (!(lo->dimension == hi->dimension))
      return make_error("--fit %s: the bounds have different units", p.key.c_str());
    p.lower = lo->value;
    p.upper = hi->value;
    p.dimension = lo->dimension;
  } else {
    // The scene's own value, a factor 4 either way.
    const json* node = &scene_json;
    for (size_t start = 0; start <= p.key.size();) {
      const size_t next = std::min(p.key.find('.', start), p.key.size());
      const std::string segment = p.key.substr(start, next - start);
      if (!node->is_object() || !node->contains(segment))
        return make_error("--fit %s: the scene has no such key (give a range KEY=LO..HI)", p.key.c_str());
      node = &(*node)[segment];
      start = next + 1;
    }
    Quantity q;
    if (node->is_number()) {
      q.value = node->get<double>();
    } else if (node->is_string()) {
      Result<Quantity> parsed = parse_quantity(node->get<std::string>());
      if (!parsed.ok()) return make_error("--fit %s: %s", p.key.c_str(), parsed.error().message.c_str());
      q = *parsed;
    } else {
      return make_error("--fit %s: not a number in the scene (give a range KEY=LO..HI)", p.key.c_str());
    }
    if (!(q.value > 0))
      return make_error("--fit %s: the scene's value %g is not > 0; give a range KEY=LO..HI", p.key.c_str(), q.value);
    p.lower = q.value / 4;
    p.upper = q.value * 4;
    p.dimension = q.dimension;
  }
  if (!(p.upper > p.lower) || !std::isfinite(p.lower) || !std::isfinite(p.upper))
    return make_error("--fit %s: the range must have LO < HI", p.key.c_str());
  return p;
}

std::string fit_override(const FitParameter& p, double value) {
  // Full precision with the SI unit, so the scene reads back exactly this value.
  std::string text = p.key;
  text.append("=").append(format_quantity(value, p.dimension, 0));
  return text;
}

namespace {

// Normalised coordinate of a value (the inverse of to_value).
double to_unit(const FitParameter& p, double v) {
  if (p.lower > 0) return std::log(v / p.lower) / std::log(p.upper / p.lower);
  return (v - p.lower) / (p.upper - p.lower);
}

// Correlation matrix of a covariance matrix (0 where a variance is 0).
std::vector<std::vector<double>> correlation_of(const Eigen::MatrixXd& cov) {
  const Eigen::Index n = cov.rows();
  std::vector<std::vector<double>> c(static_cast<size_t>(n), std::vector<double>(static_cast<size_t>(n), 0.0));
  for (Eigen::Index i = 0; i < n; ++i)
    for (Eigen::Index k = 0; k < n; ++k) {
      const double d = std::sqrt(cov(i, i) * cov(k, k));
      c[static_cast<size_t>(i)][static_cast<size_t>(k)] = d > 0 ? cov(i, k) / d : (i == k ? 1.0 : 0.0);
    }
  return c;
}

// The search and the bootstrap over one scene, its data and its parameters.
class Fitter {
 public:
  Fitter(const std::string& scene_path, const std::vector<std::string>& overrides,
         std::span<const ForceCurve> data, const CalibrateOptions& options, CalibrationResult& result)
      : scene_path_(scene_path), overrides_(overrides), data_(data), options_(options), result_(result) {}

  int budget_left() const { return options_.max_evaluations - static_cast<int>(result_.history.size()); }

  // Runs the points (normalised) as one batch; returns their indices in the history.
  std::vector<size_t> evaluate(const std::vector<std::vector<double>>& xs, const char* role) {
    std::vector<std::vector<std::string>> batch;
    std::vector<CalibrationEvaluation> evs;
    const size_t count = std::min(xs.size(), static_cast<size_t>(std::max(0, budget_left())));
    for (size_t i = 0; i < count; ++i) {
      CalibrationEvaluation ev;
      ev.role = role;
      std::vector<std::string> o = overrides_;
      for (size_t k = 0; k < result_.parameters.size(); ++k) {
        ev.values.push_back(to_value(result_.parameters[k], xs[i][k]));
        o.push_back(fit_override(result_.parameters[k], ev.values.back()));
      }
      batch.push_back(o);
      evs.push_back(ev);
    }
    std::vector<Result<SimulatedCurve>> curves;
    if (options_.evaluate) {
      curves = options_.evaluate(batch);
    } else {
      RunOptions run_options = options_.run;
      if (run_options.stop_after_puncture < 0) run_options.stop_after_puncture = 0;
      for (const std::vector<std::string>& o : batch) {
        const auto start = std::chrono::steady_clock::now();
        Result<Scene> scene = load_scene(scene_path_, o);
        if (!scene.ok()) {
          curves.push_back(scene.error());
          continue;
        }
        Result<RunResult> run = run_scene(*scene, run_options);
        if (!run.ok()) curves.push_back(run.error());
        else if (run->stopped_early) curves.push_back(make_error("run stopped early: %s", run->stop_reason.c_str()));
        else {
          SimulatedCurve c = simulated_curve(*run);
          c.wall_seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
          curves.push_back(c);
        }
      }
    }
    std::vector<size_t> indices;
    for (size_t i = 0; i < evs.size(); ++i) {
      CalibrationEvaluation& ev = evs[i];
      if (i >= curves.size()) {
        ev.message = "not run";
      } else if (!curves[i].ok()) {
        ev.message = curves[i].error().message;
      } else {
        const SimulatedCurve& c = *curves[i];
        ev.ok = true;
        ev.error = force_curve_error(c, data_);
        for (const ForceCurve& curve : data_) ev.residuals.push_back(curve_residuals(c, curve));
        for (const auto& r : ev.residuals)
          for (double x : r) ev.sum_squares += x * x;
        ev.punctured = c.loading.punctured;
        if (ev.punctured) {
          ev.puncture_deformation = c.loading.deformation.empty() ? 0.0 : c.loading.deformation.back();
          ev.puncture_force = c.puncture_force;
        }
        ev.quasi_static = c.quasi_static;
        ev.wall_seconds = c.wall_seconds;
      }
      result_.history.push_back(ev);
      indices.push_back(result_.history.size() - 1);
      if (options_.progress) options_.progress(ev, static_cast<int>(indices.back()));
    }
    return indices;
  }

  double cost(size_t index) const {
    const CalibrationEvaluation& ev = result_.history[index];
    return ev.ok ? ev.sum_squares : std::numeric_limits<double>::infinity();
  }

  static Eigen::VectorXd flat(const CalibrationEvaluation& ev) {
    std::vector<double> all;
    for (const auto& r : ev.residuals) all.insert(all.end(), r.begin(), r.end());
    return Eigen::Map<const Eigen::VectorXd>(all.data(), static_cast<Eigen::Index>(all.size()));
  }

  // The forward-difference Jacobian of the residuals at `x` (its evaluation `at`), in the
  // normalised parameters; false when a run failed or the budget is out.
  bool jacobian(const std::vector<double>& x, size_t at, Eigen::MatrixXd* J) {
    const size_t n = x.size();
    std::vector<std::vector<double>> xs;
    std::vector<double> h(n);
    for (size_t k = 0; k < n; ++k) {
      h[k] = x[k] + kStep <= 1.0 ? kStep : -kStep;  // inside the box
      std::vector<double> xk = x;
      xk[k] += h[k];
      xs.push_back(xk);
    }
    if (budget_left() < static_cast<int>(n)) return false;
    const std::vector<size_t> idx = evaluate(xs, "jacobian");
    const Eigen::VectorXd r0 = flat(result_.history[at]);
    J->resize(r0.size(), static_cast<Eigen::Index>(n));
    for (size_t k = 0; k < n; ++k) {
      if (k >= idx.size() || !result_.history[idx[k]].ok) return false;
      J->col(static_cast<Eigen::Index>(k)) = (flat(result_.history[idx[k]]) - r0) / h[k];
    }
    return true;
  }

  static constexpr double kStep = 0.02;  // Jacobian step in the normalised parameters

 private:
  const std::string& scene_path_;
  const std::vector<std::string>& overrides_;
  std::span<const ForceCurve> data_;
  const CalibrateOptions& options_;
  CalibrationResult& result_;
};

std::vector<double> clamp_unit(std::vector<double> x) {
  for (double& c : x) c = std::clamp(c, 0.0, 1.0);
  return x;
}

}  // namespace

Result<CalibrationResult> calibrate(const std::string& scene_path,
                                    const std::vector<std::string>& overrides,
                                    const std::vector<FitParameter>& parameters,
                                    std::span<const ForceCurve> data, const CalibrateOptions& options) {
  if (parameters.empty()) return make_error("calibrate: no parameter to fit");
  if (data.empty()) return make_error("calibrate: no data curve");
  for (const ForceCurve& c : data)
    if (c.deformation.size() < 2 || c.deformation.size() != c.force.size())
      return make_error("calibrate: %s: the data needs at least 2 points",
                        c.source.empty() ? "a curve" : c.source.c_str());
  const size_t n = parameters.size();
  if (options.max_evaluations < static_cast<int>(n) + 2)
    return make_error("calibrate: max_evaluations must be >= %zu (a point and its Jacobian)", n + 2);
  for (const FitParameter& p : parameters)
    if (!(p.upper > p.lower)) return make_error("calibrate: %s: the range must have LO < HI", p.key.c_str());
  // The scene must load at both ends of every range (a bound it rejects is the user's error).
  for (const FitParameter& p : parameters)
    for (double v : {p.lower, p.upper}) {
      std::vector<std::string> o = overrides;
      o.push_back(fit_override(p, v));
      Result<Scene> s = load_scene(scene_path, o);
      if (!s.ok()) return make_error("calibrate: %s", s.error().message.c_str());
    }

  CalibrationResult result;
  result.parameters = parameters;
  result.curve_count = static_cast<int>(data.size());
  Fitter fit(scene_path, overrides, data, options, result);

  // The start: a scan for one parameter (its best point), the centre of the box for several.
  std::vector<double> x(n, 0.5);
  size_t current = 0;
  if (n == 1 && options.grid_points >= 2) {
    std::vector<std::vector<double>> grid;
    for (int j = 0; j < options.grid_points; ++j) grid.push_back({static_cast<double>(j) / (options.grid_points - 1)});
    const std::vector<size_t> idx = fit.evaluate(grid, "scan");
    current = idx.front();
    for (size_t i : idx)
      if (fit.cost(i) < fit.cost(current)) current = i;
    x = grid[static_cast<size_t>(current - idx.front())];
  } else {
    current = fit.evaluate({x}, "start").front();
  }
  if (!std::isfinite(fit.cost(current))) {
    const std::string why = result.history.empty() ? "no evaluation" : result.history[current].message;
    return make_error("calibrate: no run succeeded at the start (%s)", why.c_str());
  }

  // Levenberg-Marquardt in the normalised box: each iteration a Jacobian (n runs at once),
  // then `batch` trial steps at once, one per damping factor.
  Eigen::MatrixXd J;
  std::vector<double> j_at;  // where J was taken
  double lambda = 1e-2;
  result.stop_reason = "max_evaluations reached";
  while (true) {
    if (fit.budget_left() < static_cast<int>(n) + 1) break;
    if (!fit.jacobian(x, current, &J)) {
      result.stop_reason = "a Jacobian run failed";
      break;
    }
    j_at = x;
    const Eigen::VectorXd r = Fitter::flat(result.history[current]);
    const Eigen::MatrixXd A = J.transpose() * J;
    const Eigen::VectorXd g = J.transpose() * r;
    bool accepted = false, done = false;
    while (!accepted && !done) {
      const int b = std::max(1, std::min({options.batch, 4, fit.budget_left() - static_cast<int>(n)}));
      if (fit.budget_left() < 1) break;
      static constexpr double kFactors[] = {1.0, 10.0, 0.1, 100.0};
      std::vector<std::vector<double>> trials;
      std::vector<double> lambdas;
      double smallest_step = 1e300;
      for (int t = 0; t < b; ++t) {
        const double l = lambda * kFactors[t];
        Eigen::MatrixXd M = A;
        for (Eigen::Index i = 0; i < M.rows(); ++i) M(i, i) += l * std::max(A(i, i), 1e-12 * (A.trace() + 1e-300)) + 1e-300;
        const Eigen::VectorXd step = -M.ldlt().solve(g);
        std::vector<double> xt = x;
        for (size_t k = 0; k < n; ++k) xt[k] += std::isfinite(step(static_cast<Eigen::Index>(k))) ? step(static_cast<Eigen::Index>(k)) : 0.0;
        xt = clamp_unit(xt);
        double moved = 0;
        for (size_t k = 0; k < n; ++k) moved = std::max(moved, std::fabs(xt[k] - x[k]));
        smallest_step = std::min(smallest_step, moved);
        if (moved < options.tolerance) continue;  // too small to be worth a run
        trials.push_back(xt);
        lambdas.push_back(l);
      }
      if (trials.empty()) {
        result.converged = true;
        result.stop_reason = "the next step is below the tolerance";
        done = true;
        break;
      }
      const std::vector<size_t> idx = fit.evaluate(trials, "step");
      size_t best = idx.front();
      for (size_t i : idx)
        if (fit.cost(i) < fit.cost(best)) best = i;
      if (fit.cost(best) < fit.cost(current)) {
        const std::vector<double>& xn = trials[best - idx.front()];
        double moved = 0;
        for (size_t k = 0; k < n; ++k) moved = std::max(moved, std::fabs(xn[k] - x[k]));
        x = xn;
        current = best;
        lambda = std::max(1e-6, lambdas[best - idx.front()] / 3);
        accepted = true;
        if (moved < options.tolerance) {
          result.converged = true;
          result.stop_reason = "the last step is below the tolerance";
          done = true;
        }
      } else {
        lambda *= std::pow(10.0, b);
        if (lambda > 1e8) {
          result.converged = true;
          result.stop_reason = "no step lowers the error";
          done = true;
        }
      }
      if (!accepted && fit.budget_left() < 1) done = true;
    }
    if (done || !accepted) break;
  }
  result.best = result.history[current];
  // The best evaluation over the whole history (a scan point can beat the search's end).
  for (size_t i = 0; i < result.history.size(); ++i)
    if (fit.cost(i) < fit.cost(current)) {
      current = i;
      result.best = result.history[i];
      x.clear();
      for (size_t k = 0; k < n; ++k) x.push_back(to_unit(parameters[k], result.best.values[k]));
    }
  // The Jacobian at the best point, for the intervals (taken again when the search moved on).
  if (j_at != x && !fit.jacobian(x, current, &J)) J.resize(0, 0);
  if (J.size() == 0) {
    result.interval_note = "no Jacobian at the fit (budget out or a run failed): no interval";
    return result;
  }

  // Curvature correlation: (J^T J)^-1 over all points (its scale is meaningless: the points of
  // a curve are correlated; its shape shows which parameters trade off).
  const Eigen::MatrixXd A = J.transpose() * J;
  const Eigen::MatrixXd ridge = 1e-12 * (A.trace() + 1e-300) * Eigen::MatrixXd::Identity(A.rows(), A.cols());
  result.curvature_correlation = correlation_of((A + ridge).inverse());

  // Bootstrap over whole curves: resample the curves with replacement, refit each replicate by
  // Gauss-Newton on the residuals linearised at the fit.
  if (data.size() < 2) {
    result.interval_note =
        "one curve: an interval needs repeated curves (cells or runs), resampled as wholes; "
        "none from the points of one curve, whose errors are correlated";
    return result;
  }
  if (options.bootstrap <= 0) {
    result.interval_note = "no bootstrap (0 replicates)";
    return result;
  }
  std::vector<Eigen::MatrixXd> Jc;
  std::vector<Eigen::VectorXd> rc;
  Eigen::Index row = 0;
  for (const std::vector<double>& r : result.best.residuals) {
    const Eigen::Index m = static_cast<Eigen::Index>(r.size());
    Jc.push_back(J.middleRows(row, m));
    rc.push_back(Eigen::Map<const Eigen::VectorXd>(r.data(), m));
    row += m;
  }
  std::mt19937 rng(options.seed);
  std::uniform_int_distribution<size_t> pick(0, data.size() - 1);
  std::vector<std::vector<double>> replicates(n);  // normalised
  Eigen::MatrixXd samples(options.bootstrap, static_cast<Eigen::Index>(n));
  for (int b = 0; b < options.bootstrap; ++b) {
    std::vector<int> weight(data.size(), 0);
    for (size_t i = 0; i < data.size(); ++i) ++weight[pick(rng)];
    Eigen::MatrixXd Aw = Eigen::MatrixXd::Zero(static_cast<Eigen::Index>(n), static_cast<Eigen::Index>(n));
    Eigen::VectorXd gw = Eigen::VectorXd::Zero(static_cast<Eigen::Index>(n));
    for (size_t c = 0; c < data.size(); ++c) {
      if (!weight[c]) continue;
      Aw += weight[c] * Jc[c].transpose() * Jc[c];
      gw += weight[c] * Jc[c].transpose() * rc[c];
    }
    const Eigen::VectorXd step = -(Aw + ridge).ldlt().solve(gw);
    for (size_t k = 0; k < n; ++k) {
      const double s = std::clamp(x[k] + step(static_cast<Eigen::Index>(k)), 0.0, 1.0);
      replicates[k].push_back(s);
      samples(b, static_cast<Eigen::Index>(k)) = s;
    }
  }
  result.replicates = options.bootstrap;
  const double tail = (1.0 - options.confidence) / 2.0;
  for (size_t k = 0; k < n; ++k) {
    std::vector<double> v = replicates[k];
    std::sort(v.begin(), v.end());
    auto quantile = [&](double q) {
      const double at = q * static_cast<double>(v.size() - 1);
      const size_t i = static_cast<size_t>(std::floor(at));
      const double t = at - static_cast<double>(i);
      return i + 1 < v.size() ? v[i] * (1 - t) + v[i + 1] * t : v.back();
    };
    result.interval_lower.push_back(to_value(parameters[k], quantile(tail)));
    result.interval_upper.push_back(to_value(parameters[k], quantile(1 - tail)));
    double mean = 0, sq = 0;
    for (double s : replicates[k]) mean += to_value(parameters[k], s) / static_cast<double>(v.size());
    for (double s : replicates[k]) sq += std::pow(to_value(parameters[k], s) - mean, 2);
    result.bootstrap_sd.push_back(std::sqrt(sq / std::max<double>(1.0, static_cast<double>(v.size()) - 1.0)));
  }
  const Eigen::MatrixXd centred = samples.rowwise() - samples.colwise().mean();
  result.bootstrap_correlation = correlation_of(centred.transpose() * centred);
  char note[200];
  std::snprintf(note, sizeof note,
                "%d bootstrap replicates over %zu curves (resampled as wholes), each refitted on the "
                "model linearised at the fit; %.0f %% percentile intervals",
                options.bootstrap, data.size(), 100 * options.confidence);
  result.interval_note = note;
  return result;
}

}  // namespace zona
