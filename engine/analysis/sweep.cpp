// Parameter sweeps: points, the sweep folder, point jobs and markers, the table, the SLURM
// script (engine/analysis/sweep.h).
#include "engine/analysis/sweep.h"

#include <signal.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <set>
#include <sstream>
#include <stdexcept>

#include <nlohmann/json.hpp>

#include "engine/analysis/convergence_study.h"
#include "engine/sim/recorder.h"

namespace zona {
namespace {

namespace fs = std::filesystem;
using nlohmann::json;

std::string trim(const std::string& s) {
  const size_t b = s.find_first_not_of(" \t\r");
  if (b == std::string::npos) return "";
  return s.substr(b, s.find_last_not_of(" \t\r") - b + 1);
}

// One CSV line into fields; "..." quotes a field (a doubled quote inside is one quote).
// Returns false on an unterminated quote.
bool split_quoted(const std::string& line, std::vector<std::string>* out) {
  out->clear();
  std::string field;
  bool quoted = false, was_quoted = false;
  for (size_t i = 0; i < line.size(); ++i) {
    const char c = line[i];
    if (quoted) {
      if (c == '"' && i + 1 < line.size() && line[i + 1] == '"') field += '"', ++i;
      else if (c == '"') quoted = false;
      else field += c;
    } else if (c == '"') {
      quoted = was_quoted = true;
    } else if (c == ',') {
      out->push_back(was_quoted ? field : trim(field));
      field.clear();
      was_quoted = false;
    } else {
      field += c;
    }
  }
  if (quoted) return false;
  out->push_back(was_quoted ? field : trim(field));
  return true;
}

std::string quote_field(const std::string& s) {
  if (s.find_first_of(",\"\n") == std::string::npos) return s;
  std::string q = "\"";
  for (char c : s) q += c == '"' ? std::string("\"\"") : std::string(1, c);
  return q + "\"";
}

// Free text in a CSV field: commas and line breaks would split the row.
std::string csv_text(std::string s) {
  for (char& c : s) {
    if (c == ',') c = ';';
    if (c == '\n' || c == '\r') c = ' ';
  }
  return s;
}

// Appends ",VALUE" (two appends: GCC 12's -Wrestrict misfires on "," + std::string).
void add_field(std::string& text, const std::string& value) {
  text += ',';
  text += value;
}

std::string number(double x) {
  char text[40];
  std::snprintf(text, sizeof text, "%.9g", x);
  return text;
}

std::string optional_number(const std::optional<double>& x) { return x ? number(*x) : ""; }

// "10um": a deformation [m] in a column name.
std::string deformation_tag(double d) {
  char text[40];
  std::snprintf(text, sizeof text, "%.6gum", d * 1e6);
  return text;
}

std::string read_all(const fs::path& p) {
  std::ifstream in(p, std::ios::binary);
  std::ostringstream s;
  s << in.rdbuf();
  return s.str();
}

// The loading branch of a zona force.csv: rows before the first punctured one, in time order.
Result<std::vector<CurvePoint>> read_loading_rows(const fs::path& path) {
  if (Status st = check_regular_file(path.string()); !st) return st.error();
  std::ifstream in(path);
  std::string line;
  int id = -1, iforce = -1, ip = -1, line_number = 0;
  std::vector<CurvePoint> branch;
  std::vector<std::string> cells;
  while (std::getline(in, line)) {
    ++line_number;
    if (line.empty() || line[0] == '#') continue;
    split_quoted(line, &cells);
    if (id < 0) {
      for (size_t i = 0; i < cells.size(); ++i) {
        if (cells[i] == "deformation_m") id = static_cast<int>(i);
        if (cells[i] == "force_N") iforce = static_cast<int>(i);
        if (cells[i] == "punctured") ip = static_cast<int>(i);
      }
      if (id < 0 || iforce < 0)
        return make_error("%s:%d: no deformation_m and force_N columns", path.c_str(), line_number);
      continue;
    }
    // A row cut short by a kill is the end of the curve, not an error.
    if (static_cast<int>(cells.size()) <= std::max({id, iforce, ip})) break;
    if (ip >= 0 && std::strtod(cells[static_cast<size_t>(ip)].c_str(), nullptr) != 0) break;
    branch.push_back({std::strtod(cells[static_cast<size_t>(id)].c_str(), nullptr),
                      std::strtod(cells[static_cast<size_t>(iforce)].c_str(), nullptr), 0.0});
  }
  return branch;
}

}  // namespace

// ---------------------------------------------------------------------------------------------
// Points.

Result<SweepPoints> sweep_points_from_sets(std::span<const std::string> sets,
                                           std::vector<std::string>* fixed) {
  SweepPoints out;
  std::vector<std::vector<std::string>> lists;
  for (const std::string& s : sets) {
    const size_t eq = s.find('=');
    if (eq == std::string::npos || eq == 0)
      return make_error("--set '%s': expected KEY=VALUE or KEY=A,B,C", s.c_str());
    const std::string key = s.substr(0, eq);
    std::vector<std::string> values;
    std::string value;
    std::istringstream in(s.substr(eq + 1));
    while (std::getline(in, value, ',')) values.push_back(trim(value));
    if (s.back() == ',') values.push_back("");
    for (const std::string& v : values)
      if (v.empty()) return make_error("--set %s: empty value in '%s'", key.c_str(), s.c_str());
    if (values.empty()) return make_error("--set %s: no value", key.c_str());
    for (const std::string& k : out.keys)
      if (k == key) return make_error("--set %s: given twice", key.c_str());
    if (values.size() == 1) {
      fixed->push_back(key + "=" + values.front());
      continue;
    }
    out.keys.push_back(key);
    lists.push_back(values);
  }
  if (out.keys.empty()) return out;
  // The product, the last key varying fastest.
  std::vector<size_t> at(lists.size(), 0);
  while (true) {
    std::vector<std::string> row;
    for (size_t k = 0; k < lists.size(); ++k) row.push_back(lists[k][at[k]]);
    out.values.push_back(row);
    size_t k = lists.size();
    while (k > 0 && ++at[k - 1] == lists[k - 1].size()) at[--k] = 0;
    if (k == 0) break;
  }
  return out;
}

Result<SweepPoints> read_sweep_manifest(const std::string& path) {
  if (Status st = check_regular_file(path); !st) return st.error();
  std::ifstream in(path);
  if (!in) return make_error("%s: cannot open", path.c_str());
  SweepPoints out;
  std::vector<int> columns;  // the file's column of each key
  size_t width = 0;
  std::string line;
  std::vector<std::string> cells;
  int line_number = 0;
  bool header = false;
  while (std::getline(in, line)) {
    ++line_number;
    if (trim(line).empty() || line[0] == '#') continue;
    if (!split_quoted(line, &cells))
      return make_error("%s:%d: unterminated quote", path.c_str(), line_number);
    if (!header) {
      header = true;
      width = cells.size();
      std::set<std::string> seen;
      for (size_t i = 0; i < cells.size(); ++i) {
        if (cells[i].empty()) return make_error("%s:%d: empty column name", path.c_str(), line_number);
        if (!seen.insert(cells[i]).second)
          return make_error("%s:%d: column %s given twice", path.c_str(), line_number, cells[i].c_str());
        if (cells[i] == "point") continue;
        out.keys.push_back(cells[i]);
        columns.push_back(static_cast<int>(i));
      }
      if (out.keys.empty()) return make_error("%s:%d: the header names no scene key", path.c_str(), line_number);
      continue;
    }
    if (cells.size() != width)
      return make_error("%s:%d: %zu fields, the header has %zu", path.c_str(), line_number, cells.size(), width);
    std::vector<std::string> row;
    for (size_t k = 0; k < columns.size(); ++k) {
      const std::string& v = cells[static_cast<size_t>(columns[k])];
      if (v.empty())
        return make_error("%s:%d: empty value of %s", path.c_str(), line_number, out.keys[k].c_str());
      row.push_back(v);
    }
    out.values.push_back(row);
  }
  if (!header) return make_error("%s: empty (no header)", path.c_str());
  if (out.values.empty()) return make_error("%s: no point (only a header)", path.c_str());
  return out;
}

Result<SweepPoints> combine_sweep_points(const SweepPoints& a, const SweepPoints& b) {
  if (a.keys.empty()) return b;
  if (b.keys.empty()) return a;
  SweepPoints out;
  out.keys = a.keys;
  for (const std::string& k : b.keys) {
    for (const std::string& ka : a.keys)
      if (k == ka) return make_error("%s: in both the manifest and a --set list", k.c_str());
    out.keys.push_back(k);
  }
  for (const auto& ra : a.values)
    for (const auto& rb : b.values) {
      std::vector<std::string> row = ra;
      row.insert(row.end(), rb.begin(), rb.end());
      out.values.push_back(row);
    }
  return out;
}

std::string sweep_manifest_csv(const SweepPoints& points) {
  std::string text = "point";
  for (const std::string& k : points.keys) add_field(text, quote_field(k));
  text += "\n";
  for (size_t i = 0; i < points.values.size(); ++i) {
    text += std::to_string(i);
    for (const std::string& v : points.values[i]) add_field(text, quote_field(v));
    text += "\n";
  }
  return text;
}

// ---------------------------------------------------------------------------------------------
// The sweep folder.

json sweep_config_json(const SweepConfig& c) {
  return json{{"schema", "zona sweep 1"},  {"scene", c.scene},     {"fixed", c.fixed},
              {"backend", c.backend},      {"threads", c.threads}, {"solver", c.solver},
              {"deformations_m", c.deformations}, {"point_count", c.point_count}};
}

Result<SweepConfig> read_sweep_config(const std::string& dir) {
  const std::string path = (fs::path(dir) / "sweep.json").string();
  if (Status st = check_regular_file(path); !st)
    return make_error("%s (is %s a sweep folder?)", st.error().message.c_str(), dir.c_str());
  json j = json::parse(read_all(path), nullptr, false);
  if (j.is_discarded() || !j.is_object()) return make_error("%s: not valid JSON", path.c_str());
  SweepConfig c;
  try {
    c.scene = j.at("scene").get<std::string>();
    c.fixed = j.at("fixed").get<std::vector<std::string>>();
    c.backend = j.at("backend").get<std::string>();
    c.threads = j.at("threads").get<int>();
    c.solver = j.value("solver", std::string());
    c.deformations = j.at("deformations_m").get<std::vector<double>>();
    c.point_count = j.at("point_count").get<size_t>();
  } catch (const json::exception& e) {
    return make_error("%s: %s", path.c_str(), e.what());
  }
  return c;
}

std::string sweep_point_folder(size_t index) {
  char name[40];
  std::snprintf(name, sizeof name, "points/%05zu", index);
  return name;
}

WorkerJob sweep_point_job(const std::string& zona, const std::string& dir, const SweepConfig& c,
                          const SweepPoints& points, size_t index) {
  const std::string folder = (fs::path(dir) / sweep_point_folder(index)).string();
  WorkerJob job;
  // No frames, no plot: a sweep wants the curve and the summary, at the least cost per point.
  job.argv = {zona, "run", c.scene, "--out", folder, "--quiet", "--no-frames", "--no-plot",
              "--backend", c.backend, "--threads", std::to_string(c.threads)};
  auto add_set = [&](const std::string& s) { job.argv.insert(job.argv.end(), {"--set", s}); };
  for (const std::string& s : c.fixed) add_set(s);
  if (!c.solver.empty()) add_set("solver.method=" + c.solver);
  for (size_t k = 0; k < points.keys.size(); ++k) add_set(points.keys[k] + "=" + points.values[index][k]);
  job.log_path = (fs::path(folder) / "run.log").string();
  return job;
}

// ---------------------------------------------------------------------------------------------
// Completion.

bool sweep_outcome_is_final(const WorkerOutcome& o) {
  if (!o.started) return false;
  if (o.signal == SIGKILL || o.signal == SIGTERM || o.signal == SIGINT || o.signal == SIGHUP)
    return false;
  if (o.exit_code == 128 + SIGINT || o.exit_code == 128 + SIGTERM) return false;
  return true;
}

PointRecord sweep_point_record(size_t index, const WorkerOutcome& o, const std::string& log) {
  PointRecord r;
  r.index = index;
  r.exit_code = o.signal ? -1 : o.exit_code;
  r.signal = o.signal;
  r.wall_seconds = o.wall_seconds;
  r.status = o.signal ? "crashed" : (o.exit_code == 0 ? "ok" : "failed");
  if (r.status == "ok") return r;
  // The run's error line ("zona: error: ..."), else its last line, else how it ended.
  std::istringstream in(log);
  std::string line, last;
  while (std::getline(in, line)) {
    if (trim(line).empty()) continue;
    last = trim(line);
    if (line.rfind("zona: error: ", 0) == 0) r.message = line.substr(13);
  }
  if (r.message.empty()) r.message = last;
  if (o.signal) r.message = describe_outcome(o) + (r.message.empty() ? "" : ": " + r.message);
  return r;
}

Status write_point_record(const std::string& dir, const PointRecord& r) {
  const json j = {{"point", r.index},       {"status", r.status}, {"exit_code", r.exit_code},
                  {"signal", r.signal},     {"wall_s", r.wall_seconds},
                  {"message", r.message}};
  return write_file_atomic((fs::path(dir) / sweep_point_folder(r.index) / "point.json").string(),
                           j.dump(2) + "\n");
}

Result<std::optional<PointRecord>> read_point_record(const std::string& dir, size_t index) {
  const fs::path path = fs::path(dir) / sweep_point_folder(index) / "point.json";
  std::error_code ec;
  if (!fs::exists(path, ec)) return std::optional<PointRecord>();
  json j = json::parse(read_all(path), nullptr, false);
  PointRecord r;
  try {
    if (j.is_discarded()) throw std::runtime_error("not valid JSON");
    r.index = j.at("point").get<size_t>();
    r.status = j.at("status").get<std::string>();
    r.exit_code = j.at("exit_code").get<int>();
    r.signal = j.at("signal").get<int>();
    r.wall_seconds = j.at("wall_s").get<double>();
    r.message = j.at("message").get<std::string>();
  } catch (const std::exception& e) {
    return make_error("%s: %s", path.c_str(), e.what());
  }
  if (r.index != index) return make_error("%s: says point %zu", path.c_str(), r.index);
  return std::optional<PointRecord>(r);
}

// ---------------------------------------------------------------------------------------------
// The table.

SweepRow read_sweep_row(const std::string& dir, const SweepConfig& config, size_t index) {
  SweepRow row;
  row.index = index;
  row.force_at.assign(config.deformations.size(), std::nullopt);
  Result<std::optional<PointRecord>> marker = read_point_record(dir, index);
  if (!marker) {
    row.status = "pending";
    row.message = marker.error().message;
    return row;
  }
  if (!marker->has_value()) return row;  // pending
  const PointRecord& r = **marker;
  row.status = r.status;
  row.exit_code = r.exit_code;
  row.wall_seconds = r.wall_seconds;
  row.message = r.message;
  const fs::path folder = fs::path(dir) / sweep_point_folder(index);
  json summary = json::parse(read_all(folder / "summary.json"), nullptr, false);
  if (summary.is_discarded() || !summary.is_object()) {
    if (row.message.empty()) row.message = "no summary.json";
    return row;
  }
  const json& p = summary.value("puncture", json::object());
  row.punctured = p.value("punctured", false);
  if (row.punctured) {
    row.puncture_deformation = p.value("deformation_m", 0.0);
    row.puncture_force = p.value("force_N", 0.0);
  }
  if (summary.contains("peak_force_N") && summary["peak_force_N"].is_number())
    row.peak_force = summary["peak_force_N"].get<double>();
  if (summary.contains("quasi_static") && summary["quasi_static"].is_boolean())
    row.quasi_static = summary["quasi_static"].get<bool>();
  Result<std::vector<CurvePoint>> branch = read_loading_rows(folder / "force.csv");
  if (!branch) {
    if (row.message.empty()) row.message = branch.error().message;
    return row;
  }
  // The puncture closes the branch, as in the convergence study (loading_branch).
  if (row.punctured) branch->push_back({*row.puncture_deformation, *row.puncture_force, 0.0});
  for (size_t k = 0; k < config.deformations.size(); ++k)
    row.force_at[k] = force_at_deformation(*branch, config.deformations[k]);
  return row;
}

std::string sweep_table_csv(const SweepConfig& config, const SweepPoints& points,
                            std::span<const SweepRow> rows) {
  std::string text = "point";
  for (const std::string& k : points.keys) add_field(text, quote_field(k));
  text += ",status,exit_code,punctured,puncture_deformation_m,puncture_force_N,peak_force_N";
  for (double d : config.deformations) add_field(text, "force_at_" + deformation_tag(d) + "_N");
  text += ",quasi_static,wall_s,folder,message\n";
  for (const SweepRow& r : rows) {
    text += std::to_string(r.index);
    for (const std::string& v : points.values[r.index]) add_field(text, quote_field(v));
    add_field(text, r.status);
    add_field(text, r.status == "pending" ? "" : std::to_string(r.exit_code));
    add_field(text, r.punctured ? "1" : (r.status == "pending" ? "" : "0"));
    add_field(text, optional_number(r.puncture_deformation));
    add_field(text, optional_number(r.puncture_force));
    add_field(text, optional_number(r.peak_force));
    for (const std::optional<double>& f : r.force_at) add_field(text, optional_number(f));
    add_field(text, r.quasi_static ? (*r.quasi_static ? "1" : "0") : "");
    add_field(text, r.wall_seconds ? number(std::round(*r.wall_seconds * 1000) / 1000) : "");
    add_field(text, sweep_point_folder(r.index));
    add_field(text, csv_text(r.message));
    text += '\n';
  }
  return text;
}

// ---------------------------------------------------------------------------------------------
// SLURM.

std::string slurm_script(const std::string& zona, const std::string& dir, size_t count,
                         const SlurmOptions& o) {
  auto shell_quote = [](const std::string& s) {
    std::string q = "'";
    for (char c : s) q += c == '\'' ? std::string("'\\''") : std::string(1, c);
    return q + "'";
  };
  std::string array = "0-" + std::to_string(count == 0 ? 0 : count - 1);
  if (o.max_parallel > 0) array += "%" + std::to_string(o.max_parallel);
  std::string s = "#!/bin/bash\n";
  s += "# zona sweep: one array task per point of " + dir + "/manifest.csv (docs/sweeps.md).\n";
  s += "# Submit: sbatch " + dir + "/sweep.sbatch; then: zona sweep collect " + dir + "\n";
  s += "#SBATCH --job-name=" + o.job_name + "\n";
  s += "#SBATCH --array=" + array + "\n";
  s += "#SBATCH --cpus-per-task=" + std::to_string(o.cpus_per_task) + "\n";
  if (o.gpus_per_task > 0) s += "#SBATCH --gres=gpu:" + std::to_string(o.gpus_per_task) + "\n";
  s += "#SBATCH --time=" + o.time + "\n";
  s += "#SBATCH --output=" + dir + "/slurm/%A_%a.out\n";
  for (const std::string& e : o.extra) s += "#SBATCH " + e + "\n";
  s += "set -euo pipefail\n";
  s += "exec " + shell_quote(zona) + " sweep --task \"$SLURM_ARRAY_TASK_ID\" --out " + shell_quote(dir) + "\n";
  return s;
}

}  // namespace zona
