// `zona run [SCENE]`: runs a scene's injection experiment and writes force.csv (streamed as the
// run goes), summary.json, VTU frames and the force-deformation plot (PNG and SVG); SIGINT /
// SIGTERM end the run at the next step with its outputs written (apps/stop_signals.h). Frames go
// to VTU files or an XDMF + HDF5 series (output.format, --output-format).
#include <unistd.h>

#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <limits>
#include <memory>
#include <utility>

#include <nlohmann/json.hpp>

#include "apps/commands.h"
#include "apps/plot_script.h"
#include "apps/stop_signals.h"
#include "engine/analysis/plot.h"
#include "engine/core/parallel.h"
#include "engine/sim/recorder.h"
#include "engine/scene/scene.h"
#include "engine/sim/simulation.h"
#include "kernels/backend_factory.h"
#include "kernels/backend_info.h"
#include "kernels/particle_backend.h"

namespace zona::cli {
namespace {

struct RunArgs {
  std::string scene = "mouse_oocyte";
  bool headless = false;
  std::string out;
  std::vector<std::string> sets;
  std::string solver;
  std::string backend = "cpu";
  int threads = 0;
  double stop_after_puncture = -1;
  bool no_frames = false;
  bool no_plot = false;     // --no-plot: no force_deformation.png / .svg (sweeps, calibration)
  std::string output_format;  // --output-format: vtu, xdmf or vtu+xdmf; "": the scene's
  std::string png_frames;   // --frames DIR: numbered PNG frames from the renderer
  std::string frame_color = "displacement";
  int frame_count = 0;      // 0: the scene's output.frames (or 50 when it has none)
  bool quiet = false;
  bool full_duration = false;  // simulate integrator.duration even long past the needle's end
  std::vector<std::string> compare;     // "FILE.csv[:label]": curves drawn beside this run's
  std::vector<std::string> references;  // "DEF_UM,FORCE_UN[:label]": reference points
};

// One progress line on stderr: rewritten in place on a terminal, else a line every few seconds.
class Progress {
 public:
  explicit Progress(bool quiet) : quiet_(quiet), tty_(isatty(STDERR_FILENO) == 1) {}
  void update(const RunProgress& p) {
    if (quiet_) return;
    if (!tty_ && p.wall_seconds < next_line_ && p.time < p.end_time) return;
    next_line_ = p.wall_seconds + 5.0;
    const NeedleReport& r = *p.report;
    std::fprintf(stderr,
                 "%szona run: t %.4f / %.4f s (%3.0f %%)  travel %6.2f um  deformation %6.2f um  "
                 "force %7.3f uN%s  wall %.1f s%s",
                 tty_ ? "\r" : "", p.time, p.end_time, 100.0 * p.time / p.end_time, r.travel * 1e6,
                 r.deformation * 1e6, r.force * 1e6, r.punctured ? "  punctured" : "",
                 p.wall_seconds, tty_ ? "   " : "\n");
    std::fflush(stderr);
  }
  void finish() {
    if (!quiet_ && tty_) std::fprintf(stderr, "\n");
  }

 private:
  bool quiet_;
  bool tty_;
  double next_line_ = 0;
};

// Splits "text[:label]" at the last ':' that is not part of a Windows drive or a path.
std::pair<std::string, std::string> split_label(const std::string& text) {
  const size_t colon = text.rfind(':');
  if (colon == std::string::npos || colon == 0) return {text, ""};
  return {text.substr(0, colon), text.substr(colon + 1)};
}

// The loading part (punctured == 0) of another run's force.csv: deformation [um], force [uN].
Result<PlotSeries> read_curve(const std::string& spec, uint32_t rgb) {
  const auto [path, label] = split_label(spec);
  // Before opening: a FIFO blocks the open, a device (/dev/zero) never ends.
  if (Status st = check_regular_file(path); !st)
    return make_error("--compare: %s", st.error().message.c_str());
  std::ifstream in(path);
  if (!in) return make_error("--compare: cannot open %s", path.c_str());
  std::string line;
  // The header: the first line that is not a '#' comment (zona's schema line).
  while (std::getline(in, line) && !line.empty() && line[0] == '#') {
  }
  std::vector<std::string> columns;
  for (size_t start = 0; start <= line.size();) {
    const size_t comma = std::min(line.find(',', start), line.size());
    columns.push_back(line.substr(start, comma - start));
    start = comma + 1;
  }
  auto index_of = [&](const char* name) {
    for (size_t i = 0; i < columns.size(); ++i)
      if (columns[i] == name) return static_cast<int>(i);
    return -1;
  };
  const int id = index_of("deformation_m"), iforce = index_of("force_N"), ip = index_of("punctured");
  if (id < 0 || iforce < 0)
    return make_error("--compare: %s has no deformation_m and force_N columns", path.c_str());
  PlotSeries s{label.empty() ? path : label, {}, {}, rgb, 1.5, 0};
  while (std::getline(in, line)) {
    std::vector<double> v;
    for (size_t start = 0; start <= line.size();) {
      const size_t comma = std::min(line.find(',', start), line.size());
      v.push_back(std::strtod(line.substr(start, comma - start).c_str(), nullptr));
      start = comma + 1;
    }
    if (static_cast<int>(v.size()) <= std::max({id, iforce, ip})) continue;
    if (ip >= 0 && v[static_cast<size_t>(ip)] != 0) break;
    s.x.push_back(v[static_cast<size_t>(id)] * 1e6);
    s.y.push_back(v[static_cast<size_t>(iforce)] * 1e6);
  }
  return s;
}

// "DEF_UM,FORCE_UN[:label]" as a marker.
Result<PlotSeries> read_reference(const std::string& spec, uint32_t rgb) {
  const auto [values, label] = split_label(spec);
  double d = 0, f = 0;
  if (std::sscanf(values.c_str(), "%lf,%lf", &d, &f) != 2)
    return make_error("--reference: expected DEFORMATION_UM,FORCE_UN[:label], got '%s'", spec.c_str());
  return PlotSeries{label.empty() ? values : label, {d}, {f}, rgb, 0, 7};
}

// The built-in PNG writer's plot (no Python or matplotlib): the loading branch up to the
// puncture, the puncture marked, then any compared curves and reference points. The branch
// after puncture is left out: drawn against deformation it would run back over the loading
// curve (python/zona_plot.py draws it in a panel of its own).
Status write_builtin_force_plot(const std::string& path, const Simulation& sim,
                                const RunResult& run, const RunArgs& args) {
  PlotSpec spec;
  spec.title = sim.scene().name + ": needle force vs deformation";
  spec.x_label = "deformation [um]";
  spec.y_label = "needle force [uN]";
  const std::string model = model_name(sim.scene().model);
  PlotSeries before{"this run (" + model + ")", {}, {}, 0x1f77b4, 2.0, 0};
  for (const ForceSample& s : run.samples) {
    if (s.punctured) break;
    before.x.push_back(s.deformation * 1e6);
    before.y.push_back(s.force * 1e6);
  }
  spec.series.push_back(before);
  if (run.puncture.punctured) {
    char label[96];
    std::snprintf(label, sizeof label, "puncture %.1f um, %.2f uN", run.puncture.deformation * 1e6,
                  run.puncture.force * 1e6);
    spec.series.push_back(PlotSeries{label, {run.puncture.deformation * 1e6},
                                     {run.puncture.force * 1e6}, 0xd62728, 0, 6});
  }
  static constexpr uint32_t kColours[] = {0x2ca02c, 0x9467bd, 0xff7f0e, 0x8c564b, 0x17becf};
  size_t colour = 0;
  for (const std::string& c : args.compare) {
    Result<PlotSeries> curve = read_curve(c, kColours[colour++ % 5]);
    if (!curve.ok()) return curve.error();
    spec.series.push_back(*curve);
  }
  for (const std::string& r : args.references) {
    Result<PlotSeries> point = read_reference(r, 0x000000);
    if (!point.ok()) return point.error();
    spec.series.push_back(*point);
  }
  // The deformation axis starts at the data (not at the tick below it).
  double x_min = std::numeric_limits<double>::infinity();
  for (const PlotSeries& series : spec.series)
    for (const double x : series.x)
      if (std::isfinite(x)) x_min = std::min(x_min, x);
  if (std::isfinite(x_min)) spec.x_min = x_min;
  spec.y_min = 0;
  return write_plot_png(path, spec);
}

// The force-deformation plot: force_deformation.png and .svg by python/zona_plot.py, from the
// force.csv and summary.json just written; without Python or matplotlib (or when the script
// fails), the built-in writer's PNG and a note saying why. The run has succeeded either way:
// a plot that cannot be drawn is a warning. Returns the files written.
std::vector<std::string> write_force_plots(const std::string& out, const Simulation& sim,
                                           const RunResult& run, const RunArgs& args) {
  namespace fs = std::filesystem;
  const std::string stem = (fs::path(out) / "force_deformation").string();
  std::vector<std::string> words = {
      "force", "--run", out + ":this run (" + model_name(sim.scene().model) + ")",
      "--title", sim.scene().name, "--out", stem};
  for (const std::string& c : args.compare) words.insert(words.end(), {"--run", c});
  for (const std::string& r : args.references) words.insert(words.end(), {"--reference", r});
  const Status drawn = run_plot_script(words);
  if (drawn) return plot_files(stem);
  if (!plot_png_available()) {
    std::fprintf(stderr, "zona run: warning: plot: %s; no plot written\n",
                 drawn.error().message.c_str());
    return {};
  }
  std::fprintf(stderr,
               "zona run: note: plot: %s; force_deformation.png drawn by the built-in writer "
               "(no SVG)\n",
               drawn.error().message.c_str());
  if (Status s = write_builtin_force_plot(stem + ".png", sim, run, args); !s) {
    std::fprintf(stderr, "zona run: warning: plot: %s\n", s.error().message.c_str());
    return {};
  }
  return {stem + ".png"};
}

void run_command(const RunArgs& args) {
  namespace fs = std::filesystem;
  RunProvenance provenance = local_provenance();  // the date is the run's start
  provenance.commit = source_commit();
  provenance.command = invocation();
  Result<std::string> path = find_scene_file(args.scene);
  if (!path.ok()) return fail(path.error().message);
  Result<Scene> scene = load_scene(*path, with_solver(args.sets, args.solver));
  if (!scene.ok()) return fail(scene.error().message);
  Result<BackendKind> kind = parse_backend_kind(args.backend);
  if (!kind.ok()) return fail(kind.error().message);
  if (Status st = static_backend(*scene, &*kind); !st) return fail(st.error().message);

  const std::string out = args.out.empty() ? "zona_run_" + scene->name : args.out;
  std::error_code ec;
  fs::create_directories(out, ec);
  if (ec) return fail(out + ": cannot create the output folder: " + ec.message());

  RunOptions options;
  options.simulation.threads = args.threads;
  if (*kind != BackendKind::kCpu) {
    BackendOptions backend_options;
    backend_options.cpu_threads = args.threads;
    const BackendKind k = *kind;
    options.simulation.backend_factory = [k, backend_options](std::string* notice) {
      return make_backend(k, backend_options, notice);
    };
    // The particle model (scene model "particles") has its own backends.
    options.simulation.particle_backend_factory = [k, backend_options](const ParticleModel& pm,
                                                                       std::string* notice) {
      return make_particle_backend(k, pm, backend_options, notice);
    };
  }
  options.stop_after_puncture = args.stop_after_puncture;

  if (args.frame_count < 0) return fail("--frame-count must be >= 0");
  if (!args.output_format.empty()) {
    bool known = false;
    for (FrameFormat f : {FrameFormat::kVtu, FrameFormat::kXdmf, FrameFormat::kVtuAndXdmf})
      if (args.output_format == frame_format_name(f)) {
        scene->output.format = f;
        known = true;
      }
    if (!known)
      return fail("--output-format: \"" + args.output_format +
                  "\" is not one of: vtu, xdmf, vtu+xdmf");
    if (writes_xdmf(scene->output.format) && !xdmf_supported())
      return fail("--output-format " + args.output_format + ": " + kXdmfUnsupportedMessage);
  }
  if (args.frame_count > 0) {
    scene->output.frames = args.frame_count;
    scene->output.frame_interval.reset();
  } else if (!args.png_frames.empty() && scene->output.frames <= 0 && !scene->output.frame_interval) {
    scene->output.frames = 50;
  }
  // A haptic scene's hour-long duration: the run ends with the needle unless asked
  // (end_run_with_needle, engine/scene/scene.h).
  if (!args.full_duration) {
    const double duration = scene->integrator.duration;
    if (const double needle_end = end_run_with_needle(*scene); needle_end > 0)
      std::fprintf(stderr,
                   "zona run: notice: integrator.duration is %.4g s but the needle stops at %.4g s "
                   "(needle.max_travel / needle.speed): the run ends with the needle "
                   "(--full-duration simulates all %.4g s)\n",
                   duration, needle_end, duration);
  }
  const auto setup_start = std::chrono::steady_clock::now();
  Result<std::unique_ptr<Simulation>> created = Simulation::create(*scene, options.simulation);
  if (!created.ok()) return fail(created.error().message);
  Simulation& sim = **created;
  const double setup_seconds =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - setup_start).count();
  if (!args.quiet) {
    std::fprintf(stderr, "zona run: %s (%s)\n", scene->name.c_str(), path->c_str());
    // The particle model's body Model carries a placeholder FEM material: describe the particles.
    const bool static_run = scene->solver.method == SolverMethod::kStatic;
    const std::string model_line = sim.particle_model() ? describe_particle_model(*sim.particle_model())
                                                        : describe_model(sim.model(), !static_run);
    std::fprintf(stderr, "zona run: %s\n", model_line.c_str());
    if (static_run)
      std::fprintf(stderr,
                   "zona run: static solver on the CPU, %d thread(s) (docs/static.md); setup %.2f s\n",
                   setup_thread_count(args.threads), setup_seconds);
    else
      std::fprintf(stderr, "zona run: backend %s; %lld steps to %.4g s; setup %.2f s\n",
                   sim.backend_description().c_str(),
                   static_cast<long long>(std::ceil(sim.end_time() / sim.model().dt)),
                   sim.end_time(), setup_seconds);
    for (const std::string& note : sim.notes()) std::fprintf(stderr, "zona run: note: %s\n", note.c_str());
  }

  // Frames as the run goes (VTU unless --no-frames, PNG with --frames DIR); a failed frame is
  // reported once and the run goes on.
  std::unique_ptr<FrameRecorder> frames;
  std::string frame_error;
  if (!args.no_frames && scene->output.frames > 0)
    frames = std::make_unique<FrameRecorder>(out, scene->output.format);
  PngFrameWriter png_frames;
  if (!args.png_frames.empty()) {
    Result<PngFrameWriter> writer =
        make_png_frame_writer(sim, args.png_frames, args.frame_color);
    if (!writer.ok()) return fail("--frames " + args.png_frames + ": " + writer.error().message);
    png_frames = std::move(*writer);
  }
  if (frames || png_frames)
    options.frame = [&](const Simulation& s, int) {
      if (!frame_error.empty()) return;
      if (frames)
        if (Status st = frames->write(s); !st) frame_error = st.error().message;
      if (png_frames && frame_error.empty())
        if (Status st = png_frames(s); !st) frame_error = st.error().message;
    };
  Progress progress(args.quiet);
  options.progress = [&](const RunProgress& p) { progress.update(p); };

  // Streamed outputs: scene.json before the run, force.csv row by row during it, so that a run
  // stopped half-way leaves its scene and its curve up to there. A failed row is reported once
  // after the run; the run goes on (its samples are still in memory for the summary and plot).
  // A previous run's outputs (its summary and plot, frames beyond this run's count, a
  // frames.pvd that --no-frames would leave) would sit beside this run's: they go first; any
  // other file in the folder stays.
  if (Status s = remove_run_outputs(out); !s) return fail(s.error().message);
  if (Status s = write_file_atomic((fs::path(out) / "scene.json").string(),
                                   scene_to_json(*scene).dump(2) + "\n");
      !s)
    return fail(s.error().message);
  Result<ForceCsvWriter> csv = ForceCsvWriter::open((fs::path(out) / "force.csv").string());
  if (!csv) return fail(csv.error().message);
  std::string csv_error;
  options.on_sample = [&](const ForceSample& sample) {
    if (csv_error.empty())
      if (Status s = csv->append(sample); !s) csv_error = s.error().message;
  };
  options.stop = &stop_requested();
  // The quasi-static check's warning, when it happens (on its own line past the progress line).
  options.warning = [&](const std::string& line) {
    if (!args.quiet && isatty(STDERR_FILENO) == 1) std::fprintf(stderr, "\n");
    std::fprintf(stderr, "zona run: warning: %s\n", line.c_str());
  };

  RunResult run;
  {
    const StopOnSignals stop_on_signals;
    run = run_simulation(sim, options);
  }
  progress.finish();
  if (frames)
    if (Status st = frames->close(); !st && frame_error.empty()) frame_error = st.error().message;
  if (!frame_error.empty()) std::fprintf(stderr, "zona run: warning: frames: %s\n", frame_error.c_str());

  // Outputs. A failed streamed row (disk full, ...): the whole curve is still in memory, so
  // force.csv gets one more try whole.
  if (Status s = csv->close(); !s && csv_error.empty()) csv_error = s.error().message;
  if (!csv_error.empty()) {
    if (Status s = write_force_csv(csv->path(), run.samples); !s) return fail(csv_error);
    std::fprintf(stderr, "zona run: warning: %s; force.csv rewritten whole after the run\n",
                 csv_error.c_str());
  }
  const TrainingMetrics metrics = compute_training_metrics(run, sim.cell_diameter());
  if (sim.backend() && std::string(sim.backend()->name()) == "cuda") {
    // The backend runs on device 0 (BackendOptions::device, which run does not change).
    for (const DeviceInfo& d : cuda_devices(nullptr))
      if (d.ordinal == 0) provenance.gpu = d.name;
  }
  nlohmann::json summary = run_summary_json(sim, run, metrics, provenance);
  summary["numerics"]["setup_time_s"] = setup_seconds;
  // The file the scene name resolved to (./scenes, $ZONA_SCENES_DIR, installed, source tree).
  summary["scene_file"] = *path;
  if (Status s = write_file_atomic((fs::path(out) / "summary.json").string(),
                                   summary.dump(2) + "\n");
      !s)
    return fail(s.error().message);
  const std::vector<std::string> plots =
      args.no_plot ? std::vector<std::string>() : write_force_plots(out, sim, run, args);

  // What happened, on stdout.
  std::printf("scene: %s (%s)\n", scene->name.c_str(), path->c_str());
  if (run.puncture.punctured)
    std::printf("puncture: t %.4f s, travel %.2f um, deformation %.2f um (%.1f %% of %.1f um), "
                "force %.3f uN\n",
                run.puncture.time, run.puncture.needle_travel * 1e6, run.puncture.deformation * 1e6,
                metrics.deformation_percent, sim.cell_diameter() * 1e6, run.puncture.force * 1e6);
  else
    std::printf("puncture: none\n");
  if (scene->solver.method == SolverMethod::kStatic)
    std::printf("peak force %.3f uN; %lld load steps (static); wall %.1f s\n",
                run.peak_force * 1e6, static_cast<long long>(run.steps), run.wall_seconds);
  else
    std::printf("peak force %.3f uN; %lld steps of %.3g s (mass scaling %.4g); wall %.1f s\n",
                run.peak_force * 1e6, static_cast<long long>(run.steps), sim.model().dt,
                sim.model().mass_scaling, run.wall_seconds);
  if (run.oracle_solves > 0 || run.oracle_failures > 0)
    std::printf(
        "direct oracle: %lld load steps solved both ways, largest difference %.3g of the "
        "largest displacement; %lld where the direct Newton did not converge\n",
        static_cast<long long>(run.oracle_solves), run.oracle_max_difference,
        static_cast<long long>(run.oracle_failures));
  if (run.status != kStepOk) {
    std::string flags;
    for (const std::string& name : step_flag_names(run.status)) flags += (flags.empty() ? "" : ", ") + name;
    std::printf("step flags seen: %s\n", flags.c_str());
  }
  std::string plot_names;
  for (const std::string& p : plots) plot_names += ", " + fs::path(p).filename().string();
  std::printf("wrote %s/{force.csv, summary.json, scene.json%s%s}\n", out.c_str(),
              frames ? ", frames.pvd" : "", plot_names.c_str());
  if (run.stopped_early) return fail("run stopped early: " + run.stop_reason);
  if (run.quasi_limits.enforce && !run.quasi_static()) {
    char line[400];
    std::snprintf(line, sizeof line,
                  "the run was not quasi-static (%lld steps failed the check from %.3g um of "
                  "deformation; worst imbalance %.3g, limit %.3g): its curve is not the cell's "
                  "equilibrium and no puncture was taken from those states (summary.json: "
                  "quasi_static)",
                  static_cast<long long>(run.quasi.failed_steps),
                  run.quasi.first_failed_deformation * 1e6, run.quasi.worst_imbalance,
                  run.quasi_limits.max_imbalance);
    return fail(line);
  }
  // A signal: the run ended at the step it arrived (or, arriving after the last step's check,
  // at its end); the exit status is the shell's 128 + signal either way.
  if (const int sig = stop_signal(); sig != 0) {
    const char* name = stop_signal_name(sig);
    if (run.interrupted)
      std::fprintf(stderr,
                   "zona run: interrupted by %s at t %.6g s (%lld steps); force.csv and "
                   "summary.json hold the run up to there\n",
                   name, run.simulated_time, static_cast<long long>(run.steps));
    else
      std::fprintf(stderr, "zona run: %s arrived after the last step; the outputs are complete\n",
                   name);
    exit_code() = 128 + sig;
  }
}

}  // namespace

void add_run_command(CLI::App& app) {
  auto args = std::make_shared<RunArgs>();
  auto* cmd = app.add_subcommand(
      "run", "Run a scene's injection experiment (default: scenes/mouse_oocyte.json)");
  cmd->add_option("scene", args->scene, "Scene file or name")->capture_default_str();
  cmd->add_flag("--headless", args->headless, "No window (the renderer comes later; always on now)");
  cmd->add_option("--out", args->out, "Output folder (default: zona_run_<scene name>)");
  cmd->add_option("--set", args->sets, "Override a scene key: key.path=value (repeatable)");
  add_solver_option(cmd, &args->solver);
  cmd->add_option("--backend", args->backend, "Compute backend: auto, cpu or cuda")
      ->capture_default_str();
  cmd->add_option("--threads", args->threads,
                  "CPU threads of the explicit CPU backend and of the static solver (0: every "
                  "core this process may run on)")
      ->capture_default_str();
  cmd->add_option("--stop-after-puncture", args->stop_after_puncture,
                  "Stop this many simulated seconds after puncture (default: run to the end)");
  cmd->add_flag("--no-frames", args->no_frames, "Write no frames (VTU or XDMF)");
  cmd->add_flag("--no-plot", args->no_plot,
                "Draw no force-deformation plot (what zona sweep and zona calibrate run)");
  cmd->add_option("--output-format", args->output_format,
                  "Frames as vtu (frames.pvd + .vtu files), xdmf (frames.xdmf + frames.h5, "
                  "needs HDF5) or vtu+xdmf; default: the scene's output.format (vtu)");
  cmd->add_option("--frames", args->png_frames,
                  "Also render numbered PNG frames into this folder (Vulkan renderer, headless)");
  cmd->add_option("--frame-color", args->frame_color,
                  "Colour of the PNG frames: displacement, stress or none")
      ->capture_default_str();
  cmd->add_option("--frame-count", args->frame_count,
                  "Frames over the run (VTU and PNG); 0: the scene's output.frames, or 50 for "
                  "--frames when the scene has none")
      ->capture_default_str();
  cmd->add_flag("--quiet", args->quiet, "No progress line");
  cmd->add_flag("--full-duration", args->full_duration,
                "Simulate the scene's whole integrator.duration, also when it lasts long past the "
                "needle's end (by default such a run ends with the needle, with a notice)");
  cmd->add_option("--compare", args->compare,
                  "Draw another run's force.csv (or its folder) in the plot: FILE[:label]");
  cmd->add_option("--reference", args->references,
                  "Mark a reference point in the plot: DEFORMATION_UM,FORCE_UN[:label]");
  cmd->callback([args] { run_command(*args); });
}

}  // namespace zona::cli
