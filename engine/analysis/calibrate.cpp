// Calibration of scene parameters against a force-deformation curve (golden section / Nelder-Mead).
#include "engine/analysis/calibrate.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <fstream>
#include <limits>
#include <numeric>
#include <sstream>

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

// The loading part of a run: (deformation, force) at each new largest deformation before puncture.
void loading_curve(const RunResult& run, std::vector<double>* d, std::vector<double>* f) {
  d->clear();
  f->clear();
  for (const ForceSample& s : run.samples) {
    if (s.punctured) break;
    if (!d->empty() && s.deformation <= d->back()) continue;
    d->push_back(s.deformation);
    f->push_back(s.force);
  }
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
  int line_number = 0, id = -1, iforce = -1;
  ForceCurve curve;
  while (std::getline(in, line)) {
    ++line_number;
    if (line.empty() || line[0] == '#' || line.find_first_not_of(" \t\r") == std::string::npos) continue;
    const std::vector<std::string> cells = split_csv_line(line);
    if (id < 0) {
      for (size_t i = 0; i < cells.size(); ++i) {
        if (cells[i] == "deformation_m") id = static_cast<int>(i);
        if (cells[i] == "force_N") iforce = static_cast<int>(i);
      }
      if (id < 0 || iforce < 0)
        return make_error("%s:%d: the header needs columns deformation_m and force_N", path.c_str(), line_number);
      continue;
    }
    if (static_cast<int>(cells.size()) <= std::max(id, iforce))
      return make_error("%s:%d: expected at least %d columns", path.c_str(), line_number, std::max(id, iforce) + 1);
    char* end = nullptr;
    const double d = std::strtod(cells[static_cast<size_t>(id)].c_str(), &end);
    const bool d_ok = end && *end == '\0' && !cells[static_cast<size_t>(id)].empty();
    const double f = std::strtod(cells[static_cast<size_t>(iforce)].c_str(), &end);
    const bool f_ok = end && *end == '\0' && !cells[static_cast<size_t>(iforce)].empty();
    if (!d_ok || !f_ok || !std::isfinite(d) || !std::isfinite(f))
      return make_error("%s:%d: deformation_m and force_N must be numbers", path.c_str(), line_number);
    if (!curve.deformation.empty() && d <= curve.deformation.back())
      return make_error("%s:%d: deformation_m must increase (%g after %g)", path.c_str(), line_number, d,
                        curve.deformation.back());
    curve.deformation.push_back(d);
    curve.force.push_back(f);
  }
  if (id < 0) return make_error("%s: empty (no header)", path.c_str());
  if (curve.deformation.size() < 2) return make_error("%s: needs at least 2 data rows", path.c_str());
  return curve;
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

CurveError force_curve_error(const RunResult& run, const ForceCurve& data, bool data_punctures) {
  std::vector<double> d, f;
  loading_curve(run, &d, &f);
  const double reach = d.empty() ? 0.0 : d.back();
  // Past its reach the run has either punctured (force 0) or stopped (its last force).
  auto simulated = [&](double at) {
    if (at <= reach) return interpolate(d, f, at);
    return run.puncture.punctured ? 0.0 : (f.empty() ? 0.0 : f.back());
  };
  CurveError e;
  double sum = 0, sum_data = 0;
  for (size_t i = 0; i < data.deformation.size(); ++i) {
    const double r = simulated(data.deformation[i]) - data.force[i];
    sum += r * r;
    sum_data += data.force[i] * data.force[i];
    ++e.points;
  }
  // A run still loading past the data's puncture: its force there against the data's 0, at the
  // data's mean spacing (at most 5 % of its range, so that a late puncture is charged even
  // when the data is a few points).
  if (data_punctures && !data.deformation.empty()) {
    const double last = data.deformation.back();
    const double spacing = last / static_cast<double>(std::max<size_t>(20, data.deformation.size()));
    for (double at = last + spacing; spacing > 0 && at <= reach; at += spacing) {
      const double r = interpolate(d, f, at);
      sum += r * r;
      ++e.points;
    }
  }
  e.rms = e.points > 0 ? std::sqrt(sum / e.points) : 0.0;
  const double data_rms = std::sqrt(sum_data / static_cast<double>(std::max<size_t>(1, data.deformation.size())));
  e.relative = data_rms > 0 ? e.rms / data_rms : 0.0;
  return e;
}

Result<CalibrationResult> calibrate(const std::string& scene_path,
                                    const std::vector<std::string>& overrides,
                                    const std::vector<FitParameter>& parameters,
                                    const ForceCurve& data, const CalibrateOptions& options) {
  if (parameters.empty()) return make_error("calibrate: no parameter to fit");
  if (data.deformation.size() < 2 || data.deformation.size() != data.force.size())
    return make_error("calibrate: the data needs at least 2 points");
  if (options.max_evaluations < 1) return make_error("calibrate: max_evaluations must be >= 1");
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
  RunOptions run_options = options.run;
  if (run_options.stop_after_puncture < 0) run_options.stop_after_puncture = 0;
  const double infinity = std::numeric_limits<double>::infinity();

  // The objective: relative RMS error of one run (infinite when it fails).
  auto evaluate = [&](const std::vector<double>& s) -> double {
    CalibrationEvaluation ev;
    std::vector<std::string> o = overrides;
    for (size_t i = 0; i < parameters.size(); ++i) {
      ev.values.push_back(to_value(parameters[i], s[i]));
      o.push_back(fit_override(parameters[i], ev.values.back()));
    }
    const auto start = std::chrono::steady_clock::now();
    Result<Scene> scene = load_scene(scene_path, o);
    if (!scene.ok()) {
      ev.message = scene.error().message;
    } else {
      Result<RunResult> run = run_scene(*scene, run_options);
      if (!run.ok()) {
        ev.message = run.error().message;
      } else if (run->stopped_early) {
        ev.message = "run stopped early: " + run->stop_reason;
      } else {
        ev.ok = true;
        ev.error = force_curve_error(*run, data, options.data_punctures);
        ev.puncture = run->puncture;
      }
    }
    ev.wall_seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
    result.history.push_back(ev);
    if (options.progress) options.progress(ev, static_cast<int>(result.history.size()) - 1);
    return ev.ok ? ev.error.relative : infinity;
  };
  auto budget_left = [&] { return static_cast<int>(result.history.size()) < options.max_evaluations; };

  const size_t n = parameters.size();
  if (n == 1) {
    // Scan, then golden section inside the best point's neighbours.
    const int g = std::max(3, options.grid_points);
    double best_s = 0, best = infinity;
    for (int j = 0; j < g && budget_left(); ++j) {
      const double s = static_cast<double>(j) / (g - 1);
      const double v = evaluate({s});
      if (v < best) best = v, best_s = s;
    }
    double a = std::max(0.0, best_s - 1.0 / (g - 1)), b = std::min(1.0, best_s + 1.0 / (g - 1));
    const double r = (std::sqrt(5.0) - 1.0) / 2.0;
    double x1 = b - r * (b - a), x2 = a + r * (b - a);
    double f1 = budget_left() ? evaluate({x1}) : infinity;
    double f2 = budget_left() ? evaluate({x2}) : infinity;
    while (b - a > options.tolerance && budget_left()) {
      if (f1 <= f2) {
        b = x2, x2 = x1, f2 = f1;
        x1 = b - r * (b - a);
        f1 = evaluate({x1});
      } else {
        a = x1, x1 = x2, f1 = f2;
        x2 = a + r * (b - a);
        f2 = evaluate({x2});
      }
    }
    result.converged = b - a <= options.tolerance;
  } else {
    // Nelder-Mead in the unit box (points clamped into it).
    auto clamp_point = [](std::vector<double> x) {
      for (double& c : x) c = std::clamp(c, 0.0, 1.0);
      return x;
    };
    std::vector<std::vector<double>> simplex(n + 1, std::vector<double>(n, 0.5));
    for (size_t i = 0; i < n; ++i) simplex[i + 1][i] = 0.75;
    std::vector<double> values(n + 1, infinity);
    for (size_t i = 0; i <= n && budget_left(); ++i) values[i] = evaluate(simplex[i]);
    auto size_of = [&] {
      double largest = 0;
      for (size_t i = 1; i <= n; ++i)
        for (size_t k = 0; k < n; ++k) largest = std::max(largest, std::fabs(simplex[i][k] - simplex[0][k]));
      return largest;
    };
    while (budget_left()) {
      std::vector<size_t> order(n + 1);
      std::iota(order.begin(), order.end(), size_t{0});
      std::sort(order.begin(), order.end(), [&](size_t x, size_t y) { return values[x] < values[y]; });
      std::vector<std::vector<double>> s2;
      std::vector<double> v2;
      for (size_t i : order) s2.push_back(simplex[i]), v2.push_back(values[i]);
      simplex = s2;
      values = v2;
      if (size_of() <= options.tolerance) {
        result.converged = true;
        break;
      }
      std::vector<double> centroid(n, 0.0);
      for (size_t i = 0; i < n; ++i)
        for (size_t k = 0; k < n; ++k) centroid[k] += simplex[i][k] / static_cast<double>(n);
      auto along = [&](double t) {
        std::vector<double> x(n);
        for (size_t k = 0; k < n; ++k) x[k] = centroid[k] + t * (simplex[n][k] - centroid[k]);
        return clamp_point(x);
      };
      const std::vector<double> xr = along(-1.0);
      const double fr = evaluate(xr);
      if (fr < values[0] && budget_left()) {
        const std::vector<double> xe = along(-2.0);
        const double fe = evaluate(xe);
        if (fe < fr) simplex[n] = xe, values[n] = fe;
        else simplex[n] = xr, values[n] = fr;
      } else if (fr < values[n - 1]) {
        simplex[n] = xr, values[n] = fr;
      } else if (budget_left()) {
        const std::vector<double> xc = fr < values[n] ? along(-0.5) : along(0.5);
        const double fc = evaluate(xc);
        if (fc < std::min(fr, values[n])) {
          simplex[n] = xc, values[n] = fc;
        } else {
          // Shrink towards the best point.
          for (size_t i = 1; i <= n && budget_left(); ++i) {
            for (size_t k = 0; k < n; ++k) simplex[i][k] = simplex[0][k] + 0.5 * (simplex[i][k] - simplex[0][k]);
            values[i] = evaluate(simplex[i]);
          }
        }
      }
    }
  }

  // The best evaluation over the whole history.
  const CalibrationEvaluation* best = nullptr;
  for (const CalibrationEvaluation& ev : result.history)
    if (ev.ok && (!best || ev.error.relative < best->error.relative)) best = &ev;
  if (!best) {
    const std::string why = result.history.empty() ? "no evaluation" : result.history.front().message;
    return make_error("calibrate: no run succeeded (first: %s)", why.c_str());
  }
  result.best = *best;
  return result;
}

}  // namespace zona
