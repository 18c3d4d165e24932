// Mesh-convergence study: sizes, curves read at fixed deformations, CSVs and plot
// (engine/analysis/convergence_study.h).
#include "engine/analysis/convergence_study.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <limits>
#include <memory>

#include "engine/mesh/mesh_generate.h"
#include "engine/sim/recorder.h"

namespace zona {
namespace {

// Splits "a,b,c" into trimmed tokens; an empty list or entry is an error naming the option.
Result<std::vector<std::string>> split_list(std::string_view text, const char* option) {
  std::vector<std::string> out;
  for (size_t i = 0; i <= text.size();) {
    size_t j = text.find(',', i);
    if (j == std::string_view::npos) j = text.size();
    std::string token(text.substr(i, j - i));
    token.erase(0, token.find_first_not_of(" \t"));
    token.erase(token.find_last_not_of(" \t") + 1);
    if (token.empty()) {
      if (text.find_first_not_of(" \t") == std::string_view::npos)
        return make_error("%s: the list is empty", option);
      return make_error("%s: empty entry in '%s'", option, std::string(text).c_str());
    }
    out.push_back(token);
    i = j + 1;
  }
  return out;
}

// A finite number with nothing after it.
std::optional<double> parse_number(const std::string& s) {
  char* end = nullptr;
  const double x = std::strtod(s.c_str(), &end);
  if (end == s.c_str() || *end != '\0' || !std::isfinite(x)) return {};
  return x;
}

std::string format(double x, const char* spec = "%.6g") {
  char buf[64];
  std::snprintf(buf, sizeof buf, spec, x);
  return buf;
}

std::string format_optional(const std::optional<double>& x, double scale = 1.0) {
  return x ? format(*x * scale) : std::string();
}

// Free text in a CSV field: commas and line breaks would split the row.
std::string csv_text(std::string s) {
  for (char& c : s) {
    if (c == ',') c = ';';
    if (c == '\n' || c == '\r') c = ' ';
  }
  return s;
}

std::string comment_block(std::span<const std::string> comments) {
  std::string out;
  for (const std::string& c : comments) out.append("# ").append(c).append("\n");
  return out;
}

// Appends the fields as one CSV line.
void append_row(std::string& out, const std::vector<std::string>& fields) {
  for (size_t i = 0; i < fields.size(); ++i) {
    if (i > 0) out += ',';
    out += fields[i];
  }
  out += '\n';
}

// "10um", "2.5um": a requested deformation [m] in a column name.
std::string deformation_tag(double deformation) {
  return format(deformation * 1e6) + "um";
}

}  // namespace

// ---------------------------------------------------------------------------------------------
// Arguments.

Result<std::vector<int64_t>> parse_study_vertices(std::string_view text) {
  Result<std::vector<std::string>> tokens = split_list(text, "--vertices");
  if (!tokens) return tokens.error();
  std::vector<int64_t> out;
  for (const std::string& t : *tokens) {
    const std::optional<double> x = parse_number(t);
    if (!x || *x != std::floor(*x) || *x < 0)
      return make_error("--vertices: '%s' is not a vertex count (give counts like 300 or 1e6)",
                        t.c_str());
    if (*x < static_cast<double>(kMinCellMeshVertices) ||
        *x > static_cast<double>(kMaxCellMeshVertices))
      return make_error("--vertices: %s is outside the mesher's range [%lld, %lld]", t.c_str(),
                        static_cast<long long>(kMinCellMeshVertices),
                        static_cast<long long>(kMaxCellMeshVertices));
    out.push_back(static_cast<int64_t>(*x));
  }
  return out;
}

Result<std::vector<double>> parse_study_deformations(std::string_view text) {
  Result<std::vector<std::string>> tokens = split_list(text, "--deformations");
  if (!tokens) return tokens.error();
  std::vector<double> out;
  for (const std::string& t : *tokens) {
    const std::optional<double> x = parse_number(t);
    if (!x || !(*x > 0))
      return make_error(
          "--deformations: '%s' is not a positive deformation in um (give a list "
          "like 10,20,30,40)",
          t.c_str());
    out.push_back(*x * 1e-6);
  }
  return out;
}

// ---------------------------------------------------------------------------------------------
// One curve.

std::vector<CurvePoint> loading_branch(std::span<const ForceSample> samples,
                                       const PunctureRecord& puncture) {
  std::vector<CurvePoint> branch;
  branch.reserve(samples.size() + 1);
  bool broken = false;
  for (const ForceSample& s : samples) {
    if (s.punctured) break;
    if (!std::isfinite(s.deformation) || !std::isfinite(s.force)) {
      broken = true;
      break;
    }
    branch.push_back({s.deformation, s.force, s.holding_force});
  }
  // The puncture point closes the branch: the force the criterion fired at, before release.
  if (!broken && puncture.punctured && std::isfinite(puncture.deformation) &&
      std::isfinite(puncture.force))
    branch.push_back({puncture.deformation, puncture.force,
                      branch.empty() ? 0.0 : branch.back().holding});
  return branch;
}

std::optional<double> force_at_deformation(std::span<const CurvePoint> branch, double deformation) {
  // The first point at or past the level; the crossing lies between it and the one before.
  for (size_t i = 0; i < branch.size(); ++i) {
    if (!(branch[i].deformation >= deformation)) continue;
    if (branch[i].deformation == deformation) return branch[i].force;
    if (i == 0) return std::nullopt;  // the branch starts past the level
    const CurvePoint& a = branch[i - 1];
    const CurvePoint& b = branch[i];
    const double t = (deformation - a.deformation) / (b.deformation - a.deformation);
    return a.force + t * (b.force - a.force);
  }
  return std::nullopt;
}

std::optional<double> imbalance_at_deformation(std::span<const CurvePoint> branch,
                                               double deformation) {
  std::vector<CurvePoint> net(branch.begin(), branch.end());
  for (CurvePoint& p : net) p.force += p.holding;
  const std::optional<double> force = force_at_deformation(branch, deformation);
  const std::optional<double> sum = force_at_deformation(net, deformation);
  if (!force || !sum || !(*force > 0)) return std::nullopt;
  return *sum / *force;
}

double largest_force_drop(std::span<const CurvePoint> branch, double reference_force) {
  if (!(reference_force > 0)) return 0;
  double drop = 0;
  for (size_t i = 1; i < branch.size(); ++i)
    drop = std::max(drop, branch[i - 1].force - branch[i].force);
  return drop / reference_force;
}

// ---------------------------------------------------------------------------------------------
// The study.

ConvergenceRun summarize_convergence_run(int64_t target_vertices, const RunResult& run,
                                         std::span<const double> deformations) {
  ConvergenceRun out;
  out.target_vertices = target_vertices;
  out.steps = run.steps;
  out.wall_seconds = run.wall_seconds;
  out.punctured = run.puncture.punctured;
  if (out.punctured) {
    out.puncture_deformation = run.puncture.deformation;
    out.puncture_force = run.puncture.force;
  }
  out.peak_force = run.peak_force;
  const std::vector<CurvePoint> branch = loading_branch(run.samples, run.puncture);
  for (const double d : deformations) out.force_at.push_back(force_at_deformation(branch, d));
  out.relative_to_finest.assign(deformations.size(), std::nullopt);
  for (const double d : deformations) out.imbalance_at.push_back(imbalance_at_deformation(branch, d));
  out.largest_drop =
      largest_force_drop(branch, out.punctured ? out.puncture_force : out.peak_force);
  for (const ForceSample& s : run.samples) {
    if (s.punctured) break;
    if (s.status & kStepInvertedElement) {
      out.inverted_from = s.deformation;
      break;
    }
  }
  std::vector<std::string> flags = step_flag_names(run.status);
  if (run.sample_buffer_full) flags.push_back("sample buffer full");
  for (const std::string& name : flags) {
    if (!out.step_flags.empty()) out.step_flags += '|';
    out.step_flags += name;
  }
  out.stopped_early = run.stopped_early || run.interrupted;
  out.stop_reason = run.stop_reason;
  out.interrupted = run.interrupted;
  if (run.interrupted && out.stop_reason.empty()) {
    const double deformation = run.samples.empty() ? 0.0 : run.samples.back().deformation;
    char line[160];
    std::snprintf(line, sizeof line,
                  "interrupted at t %.6g s (%.4g um of deformation): the curve is a result up to "
                  "there",
                  run.simulated_time, deformation * 1e6);
    out.stop_reason = line;
  }
  out.samples = run.samples;
  return out;
}

void fill_relative_differences(ConvergenceStudy& study) {
  const ConvergenceRun* finest = nullptr;
  for (const ConvergenceRun& r : study.runs)
    if (r.vertices > 0 && (!finest || r.vertices > finest->vertices)) finest = &r;
  for (ConvergenceRun& r : study.runs) {
    r.relative_to_finest.assign(study.deformations.size(), std::nullopt);
    if (!finest) continue;
    for (size_t k = 0; k < study.deformations.size(); ++k) {
      const std::optional<double>& mine = r.force_at[k];
      const std::optional<double>& ref = finest->force_at[k];
      if (mine && ref && *ref != 0) r.relative_to_finest[k] = (*mine - *ref) / *ref;
    }
  }
}

Result<std::vector<Scene>> convergence_scenes(const std::string& scene_path,
                                              const std::vector<std::string>& overrides,
                                              std::span<const int64_t> vertices) {
  std::vector<Scene> scenes;
  for (const int64_t n : vertices) {
    std::vector<std::string> sets = overrides;
    sets.push_back("mesh.generate.vertices=" + std::to_string(n));
    sets.push_back("output.frames=0");
    Result<Scene> scene = load_scene(scene_path, sets);
    if (!scene) return scene.error();
    if (scene->mesh.source != MeshSource::kGenerate)
      return make_error(
          "%s: the study varies mesh.generate.vertices, but the scene's mesh is "
          "the file %s",
          scene_path.c_str(), scene->mesh.file.c_str());
    scenes.push_back(std::move(*scene));
  }
  return scenes;
}

ConvergenceStudy run_convergence_study(std::span<const Scene> scenes,
                                       std::span<const double> deformations,
                                       const ConvergenceOptions& options) {
  ConvergenceStudy study;
  study.deformations.assign(deformations.begin(), deformations.end());
  if (!scenes.empty()) study.scene_name = scenes.front().name;
  for (const Scene& scene : scenes) {
    if (options.started) options.started(scene);
    const int64_t target = scene.mesh.generate.target_vertices;
    const auto setup_start = std::chrono::steady_clock::now();
    Result<std::unique_ptr<Simulation>> created = Simulation::create(scene, options.simulation);
    ConvergenceRun run;
    if (!created) {
      // A size that cannot be built (mesher, memory, backend) is a row, not the end of the study.
      run.target_vertices = target;
      run.force_at.assign(deformations.size(), std::nullopt);
      run.relative_to_finest.assign(deformations.size(), std::nullopt);
      run.stopped_early = true;
      run.stop_reason = "setup failed: " + created.error().message;
    } else {
      Simulation& sim = **created;
      const double setup_seconds =
          std::chrono::duration<double>(std::chrono::steady_clock::now() - setup_start).count();
      RunOptions ro;
      ro.simulation = options.simulation;
      ro.stop_after_puncture = 0;
      ro.progress = options.progress;
      ro.stop = options.stop;
      const RunResult result = run_simulation(sim, ro);
      run = summarize_convergence_run(target, result, deformations);
      run.vertices = static_cast<int64_t>(sim.mesh().vertex_count());
      run.tets = static_cast<int64_t>(sim.mesh().tet_count());
      // A static run has load steps, not a time step.
      run.dt = sim.scene().solver.method == SolverMethod::kStatic ? 0.0 : sim.model().dt;
      run.setup_seconds = setup_seconds;
      run.backend = sim.backend_description();
      run.notes = sim.notes();
    }
    study.runs.push_back(std::move(run));
    if (options.finished) options.finished(study.runs.back());
    if (options.stop && options.stop->load(std::memory_order_relaxed)) break;
  }
  fill_relative_differences(study);
  return study;
}

// ---------------------------------------------------------------------------------------------
// Output.

std::string convergence_csv(const ConvergenceStudy& study, std::span<const std::string> comments) {
  std::string out = comment_block(comments);
  out += "target_vertices,vertices,tets,time_s,travel_um,deformation_um,force_un,punctured\n";
  for (const ConvergenceRun& r : study.runs)
    for (const ForceSample& s : r.samples)
      append_row(out,
                 {std::to_string(r.target_vertices), std::to_string(r.vertices),
                  std::to_string(r.tets), format(s.time), format(s.travel * 1e6),
                  format(s.deformation * 1e6), format(s.force * 1e6), s.punctured ? "1" : "0"});
  return out;
}

std::string convergence_summary_csv(const ConvergenceStudy& study,
                                    std::span<const std::string> comments) {
  std::string out = comment_block(comments);
  out +=
      "target_vertices,vertices,tets,dt_s,steps,setup_s,wall_s,backend,punctured,"
      "puncture_deformation_um,puncture_force_un,peak_force_un";
  for (const double d : study.deformations)
    out.append(",force_at_").append(deformation_tag(d)).append("_un");
  for (const double d : study.deformations) out.append(",rel_diff_at_").append(deformation_tag(d));
  for (const double d : study.deformations) out.append(",imbalance_at_").append(deformation_tag(d));
  out += ",largest_drop_rel,inverted_from_um,step_flags,stopped_early,stop_reason\n";
  for (const ConvergenceRun& r : study.runs) {
    const bool ran = r.vertices > 0;
    std::vector<std::string> f = {std::to_string(r.target_vertices),
                                  std::to_string(r.vertices),
                                  std::to_string(r.tets),
                                  ran && r.dt > 0 ? format(r.dt) : "",
                                  std::to_string(r.steps),
                                  ran ? format(r.setup_seconds, "%.3f") : "",
                                  ran ? format(r.wall_seconds, "%.3f") : "",
                                  csv_text(r.backend),
                                  r.punctured ? "1" : "0",
                                  r.punctured ? format(r.puncture_deformation * 1e6) : "",
                                  r.punctured ? format(r.puncture_force * 1e6) : "",
                                  ran ? format(r.peak_force * 1e6) : ""};
    for (const std::optional<double>& x : r.force_at) f.push_back(format_optional(x, 1e6));
    for (const std::optional<double>& x : r.relative_to_finest) f.push_back(format_optional(x));
    for (size_t k = 0; k < study.deformations.size(); ++k)
      f.push_back(k < r.imbalance_at.size() ? format_optional(r.imbalance_at[k]) : "");
    f.push_back(ran ? format(r.largest_drop) : "");
    f.push_back(format_optional(r.inverted_from, 1e6));
    f.push_back(csv_text(r.step_flags));
    f.push_back(r.stopped_early ? "1" : "0");
    f.push_back(csv_text(r.stop_reason));
    append_row(out, f);
  }
  return out;
}

PlotSpec convergence_plot(const ConvergenceStudy& study) {
  static constexpr uint32_t kColours[] = {0x1f77b4, 0xff7f0e, 0x2ca02c, 0xd62728, 0x9467bd,
                                          0x8c564b, 0xe377c2, 0x7f7f7f, 0xbcbd22, 0x17becf};
  PlotSpec spec;
  spec.title = study.scene_name + ": mesh convergence (discs: puncture)";
  spec.x_label = "deformation [um]";
  spec.y_label = "needle force [uN]";
  size_t colour = 0;
  double x_min = std::numeric_limits<double>::infinity();
  for (const ConvergenceRun& r : study.runs) {
    if (r.vertices <= 0) continue;  // setup failed: nothing to draw
    const uint32_t rgb = kColours[colour++ % std::size(kColours)];
    PlotSeries curve{std::to_string(r.vertices) + " vertices", {}, {}, rgb, 1.5, 0};
    PunctureRecord puncture;
    puncture.punctured = r.punctured;
    puncture.deformation = r.puncture_deformation;
    puncture.force = r.puncture_force;
    for (const CurvePoint& p : loading_branch(r.samples, puncture)) {
      curve.x.push_back(p.deformation * 1e6);
      curve.y.push_back(p.force * 1e6);
    }
    if (curve.x.empty()) continue;
    x_min = std::min(x_min, *std::min_element(curve.x.begin(), curve.x.end()));
    spec.series.push_back(std::move(curve));
    if (r.punctured)
      spec.series.push_back(
          PlotSeries{"", {r.puncture_deformation * 1e6}, {r.puncture_force * 1e6}, rgb, 0, 5});
  }
  // The deformation axis starts at the data (not at the tick below it).
  if (std::isfinite(x_min)) spec.x_min = x_min;
  spec.y_min = 0;
  return spec;
}

}  // namespace zona
