// `zona study convergence SCENE`: the injection experiment at a list of mesh sizes, its curves
// compared at fixed deformations (engine/analysis/convergence_study.h); writes convergence.csv,
// convergence_summary.csv and convergence.png, after every size. SIGINT / SIGTERM end the
// running size at its next step (a row marked interrupted) and the study with it.
#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <ctime>
#include <filesystem>
#include <fstream>
#include <memory>
#include <string>
#include <vector>

#include "apps/commands.h"
#include "apps/stop_signals.h"
#include "engine/analysis/convergence_study.h"
#include "apps/plot_script.h"
#include "engine/analysis/plot.h"
#include "engine/core/parallel.h"
#include "bench/scaling/scaling_bench.h"
#include "engine/scene/scene.h"
#include "engine/sim/simulation.h"
#include "kernels/backend_factory.h"
#include "kernels/backend_info.h"
#include "kernels/particle_backend.h"

namespace zona::cli {
namespace {

struct ConvergenceArgs {
  std::string scene;
  std::string vertices;         // the sizes given (empty list: an error)
  bool vertices_given = false;  // false: the backend's default sizes (kCpuSizes, kGpuSizes)
  std::string backend = "cpu";
  int threads = 0;
  std::vector<std::string> sets;
  std::string solver;
  std::string deformations = "10,20,30,40";
  std::string out;
  bool quiet = false;
};

// Default mesh sizes: what the backend finishes in minutes (CPU, 2 cores: about 2 min; a GPU:
// about 20 min, most of it the 1M-vertex mesh). Estimates below.
constexpr const char* kCpuSizes = "1e3,2e3,4e3";
constexpr const char* kGpuSizes = "1e3,4e3,16e3,64e3,256e3,1e6";

// Rough wall time per step of the injection job, from the job benchmarks in bench/results:
// the CPU about 0.1 us per vertex on 2 threads (1.03 ms at 10k vertices on an EPYC), the GPU a
// floor of 13 us plus 0.57 ns per vertex (0.57 ms at 1M vertices on an H100).
double estimated_ms_per_step(bool gpu, double vertices, int threads) {
  if (gpu) return 0.013 + 5.7e-7 * vertices;
  return 1.0e-4 * vertices * 2.0 / std::max(threads, 1);
}

// Steps of one size's run: its end time over its step; 0 when the step is set by the mesh
// (no dt or target_dt in the scene) or nothing but a trajectory ends the run.
double estimated_steps(const Scene& scene) {
  const IntegratorDef& in = scene.integrator;
  const double dt = in.target_dt ? *in.target_dt : (in.dt ? *in.dt : 0.0);
  double end = in.duration;
  if (!(end > 0) && scene.needle.enabled && scene.needle.speed > 0)
    end = scene.needle.max_travel / scene.needle.speed;
  return dt > 0 && end > 0 ? std::ceil(end / dt) : 0.0;
}

std::string format_wall(double seconds) {
  char text[32];
  if (seconds < 90) std::snprintf(text, sizeof text, "%.0f s", seconds);
  else if (seconds < 5400) std::snprintf(text, sizeof text, "%.0f min", seconds / 60);
  else std::snprintf(text, sizeof text, "%.1f h", seconds / 3600);
  return text;
}

// The options in full (defaults included), for the CSVs' comment lines.
std::string command_line(const ConvergenceArgs& a, const std::string& out) {
  std::string c = "zona study convergence " + a.scene + " --vertices " + a.vertices +
                  " --deformations " + a.deformations + " --backend " + a.backend + " --threads " +
                  std::to_string(a.threads);
  for (const std::string& s : a.sets) c += " --set " + s;
  return c + " --out " + out;
}

std::string utc_now() {
  char text[40];
  const std::time_t now = std::time(nullptr);
  std::strftime(text, sizeof text, "%Y-%m-%d %H:%M:%S UTC", std::gmtime(&now));
  return text;
}

Status write_text(const std::string& path, const std::string& text) {
  std::ofstream out(path);
  if (!out) return make_error("%s: cannot open for writing", path.c_str());
  out << text;
  if (!out) return make_error("%s: write failed", path.c_str());
  return Status::ok_status();
}

// Progress of the running size on stderr: redrawn on a terminal, a line every 30 s otherwise.
class Progress {
 public:
  explicit Progress(bool quiet) : quiet_(quiet), tty_(isatty(STDERR_FILENO) == 1) {}
  void start() { next_line_ = 30.0; }
  void update(const RunProgress& p) {
    if (quiet_) return;
    if (!tty_ && p.wall_seconds < next_line_) return;
    next_line_ = p.wall_seconds + 30.0;
    const NeedleReport& r = *p.report;
    std::fprintf(stderr,
                 "%szona study:   t %.4f / %.4f s  deformation %6.2f um  force %7.3f uN  "
                 "wall %.0f s%s",
                 tty_ ? "\r" : "", p.time, p.end_time, r.deformation * 1e6, r.force * 1e6,
                 p.wall_seconds, tty_ ? "   " : "\n");
    std::fflush(stderr);
  }
  void finish() {
    if (!quiet_ && tty_) std::fprintf(stderr, "\r%80s\r", "");
  }

 private:
  bool quiet_;
  bool tty_;
  double next_line_ = 30.0;
};

// The two CSV files, from the runs so far (rewritten after every size, so that a long study
// leaves its finished sizes on disk).
Status write_outputs(const std::filesystem::path& out, ConvergenceStudy study,
                     const std::vector<std::string>& comments) {
  fill_relative_differences(study);
  std::vector<std::string> samples_comments = comments;
  samples_comments.push_back(
      "one row per (size, sample): the run's samples (output.sample_interval) to puncture, and "
      "the few after it that the last block of steps recorded (punctured 1); deformation_um at "
      "the needle's entry point, force_un the filtered axial needle force");
  std::vector<std::string> summary_comments = comments;
  summary_comments.push_back(
      "one row per size: force_at_D_un the force where the loading branch (before puncture) "
      "first reaches D um, linearly interpolated, empty where it does not; rel_diff_at_D "
      "(force - finest's) / finest's, the finest being the size with the most vertices; "
      "imbalance_at_D (needle force + holding force along the axis) / needle force there, 0 "
      "in static equilibrium, the share carried by inertia and damping; "
      "largest_drop_rel the largest sample-to-sample fall of the force on the loading branch "
      "over the puncture force (the peak force without puncture); inverted_from_um the "
      "deformation of the first sample before puncture with an inverted element, empty where "
      "none; free text has ',' as ';'");
  if (Status s =
          write_text((out / "convergence.csv").string(), convergence_csv(study, samples_comments));
      !s)
    return s;
  if (Status s = write_text((out / "convergence_summary.csv").string(),
                            convergence_summary_csv(study, summary_comments));
      !s)
    return s;
  return Status::ok_status();
}

// The curves' plot, convergence.png and .svg, by python/zona_plot.py from the CSVs just
// written; without Python or matplotlib, the built-in writer's PNG (no SVG) and a note, given
// once per study (`noted`). A convenience: no curve yet, or a plot that fails, leaves the CSVs.
// Returns the files written.
std::vector<std::string> write_plot(const std::filesystem::path& out, const ConvergenceStudy& study,
                                    bool* noted) {
  const PlotSpec spec = convergence_plot(study);
  if (spec.series.empty()) return {};
  const std::string stem = (out / "convergence").string();
  const Status drawn = run_plot_script(
      {"convergence", "--study", out.string(), "--title", study.scene_name, "--out", stem});
  if (drawn) return plot_files(stem);
  if (!*noted)
    std::fprintf(stderr, "zona study: note: plot: %s; %s\n", drawn.error().message.c_str(),
                 plot_png_available() ? "convergence.png drawn by the built-in writer (no SVG)"
                                      : "no plot written");
  *noted = true;
  if (!plot_png_available()) return {};
  if (Status s = write_plot_png(stem + ".png", spec); !s) {
    std::fprintf(stderr, "zona study: warning: plot: %s\n", s.error().message.c_str());
    return {};
  }
  return {stem + ".png"};
}

void convergence_command(const ConvergenceArgs& given) {
  namespace fs = std::filesystem;
  ConvergenceArgs args = given;
  args.sets = with_solver(args.sets, args.solver);
  // The static solver runs on the CPU (static_backend).
  if (args.solver == "static" && args.backend == "auto") args.backend = "cpu";
  // Everything that can be wrong with the input is found before the first size runs.
  Result<BackendKind> kind = parse_backend_kind(args.backend);
  if (!kind) return fail(kind.error().message);
  // The GPU runs when asked for, or for auto when a device is there.
  std::string device_notice;
  const std::vector<DeviceInfo> devices = cuda_devices(&device_notice);
  const bool gpu = *kind == BackendKind::kCuda || (*kind == BackendKind::kAuto && !devices.empty());
  ConvergenceArgs resolved = args;
  if (!args.vertices_given) resolved.vertices = gpu ? kGpuSizes : kCpuSizes;
  Result<std::vector<int64_t>> vertices = parse_study_vertices(resolved.vertices);
  if (!vertices) return fail(vertices.error().message);
  Result<std::vector<double>> deformations = parse_study_deformations(args.deformations);
  if (!deformations) return fail(deformations.error().message);
  if (args.threads < 0) return fail("--threads must be >= 0");
  Result<std::string> path = find_scene_file(args.scene);
  if (!path) return fail(path.error().message);
  Result<std::vector<Scene>> scenes = convergence_scenes(*path, args.sets, *vertices);
  if (!scenes) return fail(scenes.error().message);

  // The backend, wired as `zona run` does; --backend cuda without a device is bad input.
  BackendOptions backend_options;
  backend_options.cpu_threads = args.threads;
  ConvergenceOptions options;
  options.simulation.threads = args.threads;
  if (*kind != BackendKind::kCpu) {
    if (*kind == BackendKind::kCuda)
      if (Result<std::unique_ptr<Backend>> probe = make_backend(*kind, backend_options); !probe)
        return fail(probe.error().message);
    const BackendKind k = *kind;
    options.simulation.backend_factory = [k, backend_options](std::string* notice) {
      return make_backend(k, backend_options, notice);
    };
    options.simulation.particle_backend_factory = [k, backend_options](const ParticleModel& pm,
                                                                       std::string* notice) {
      return make_particle_backend(k, pm, backend_options, notice);
    };
  }

  // The estimate first: a CPU study of a million vertices takes days, not minutes.
  {
    const int threads = setup_thread_count(args.threads);
    std::string line;
    double total = 0;
    bool known = true;
    for (const Scene& scene : *scenes) {
      const double n = static_cast<double>(scene.mesh.generate.target_vertices);
      const double steps = estimated_steps(scene);
      known = known && steps > 0;
      const double wall = steps * estimated_ms_per_step(gpu, n, threads) * 1e-3;
      total += wall;
      char part[96];
      std::snprintf(part, sizeof part, "%s%.0f vertices ~%s", line.empty() ? "" : ", ", n,
                    steps > 0 ? format_wall(wall).c_str() : "?");
      line += part;
    }
    std::printf("estimate (rough, from the job benchmarks): %s on %s: %s; total ~%s%s\n",
                resolved.vertices.c_str(), gpu ? "the GPU" : ("the CPU, " + std::to_string(threads) + " threads").c_str(),
                line.c_str(), format_wall(total).c_str(),
                known ? "" : " (sizes with '?': the step is set by the mesh)");
    std::fflush(stdout);
  }

  const std::string out = args.out.empty() ? "zona_study_" + scenes->front().name : args.out;
  std::error_code ec;
  fs::create_directories(out, ec);
  if (ec) return fail(out + ": cannot create the output folder: " + ec.message());

  // Comment lines of both CSVs: what ran, when, from which source, where.
  const MachineInfo machine = local_machine_info();
  const std::string commit = source_commit();
  const std::vector<std::string> comments = {
      "zona study convergence: scene " + scenes->front().name + " (" + *path + "), zona " +
          machine.zona_version,
      "command: " + command_line(resolved, out),
      "date: " + utc_now(),
      "commit: " + (commit.empty() ? std::string("unknown") : commit),
      "machine: " + machine.cpu_model + ", " + std::to_string(machine.hardware_threads) +
          " hardware threads; gpu: " +
          (devices.empty() ? std::string("none") : devices.front().name),
  };

  Progress progress(args.quiet);
  options.progress = [&](const RunProgress& p) { progress.update(p); };
  const size_t count = scenes->size();
  size_t index = 0;
  options.started = [&](const Scene& scene) {
    ++index;
    progress.start();
    if (!args.quiet)
      std::fprintf(stderr, "zona study: size %zu/%zu: mesh.generate.vertices=%lld\n", index, count,
                   static_cast<long long>(scene.mesh.generate.target_vertices));
  };
  bool write_warned = false;
  bool plot_noted = false;
  ConvergenceStudy so_far;
  so_far.scene_name = scenes->front().name;
  so_far.deformations = *deformations;
  const bool static_solver = scenes->front().solver.method == SolverMethod::kStatic;
  options.finished = [&](const ConvergenceRun& r) {
    progress.finish();
    for (const std::string& note : r.notes)
      std::fprintf(stderr, "zona study: note: %s\n", note.c_str());
    if (r.vertices > 0 && static_solver)
      std::printf("%lld vertices, %lld tets: %lld load steps (static), setup %.1f s, wall %.1f s; ",
                  static_cast<long long>(r.vertices), static_cast<long long>(r.tets),
                  static_cast<long long>(r.steps), r.setup_seconds, r.wall_seconds);
    else if (r.vertices > 0)
      std::printf("%lld vertices, %lld tets: %lld steps of %.3g s, setup %.1f s, wall %.1f s; ",
                  static_cast<long long>(r.vertices), static_cast<long long>(r.tets),
                  static_cast<long long>(r.steps), r.dt, r.setup_seconds, r.wall_seconds);
    else
      std::printf("target %lld vertices: ", static_cast<long long>(r.target_vertices));
    if (r.punctured)
      std::printf("puncture at %.2f um, %.3f uN", r.puncture_deformation * 1e6,
                  r.puncture_force * 1e6);
    else if (r.vertices > 0)
      std::printf("no puncture, peak %.3f uN", r.peak_force * 1e6);
    if (r.stopped_early) std::printf("; stopped early: %s", r.stop_reason.c_str());
    std::printf("\n");
    std::fflush(stdout);
    so_far.runs.push_back(r);
    if (Status s = write_outputs(out, so_far, comments); !s && !write_warned) {
      std::fprintf(stderr, "zona study: warning: %s\n", s.error().message.c_str());
      write_warned = true;
    } else if (s) {
      write_plot(out, so_far, &plot_noted);
    }
  };

  // SIGINT / SIGTERM (a cluster's time limit) end the running size at its next step: its row
  // is marked interrupted, no further size starts, and the CSVs hold the sizes run.
  options.stop = &stop_requested();
  ConvergenceStudy study;
  {
    const StopOnSignals stop_on_signals;
    study = run_convergence_study(*scenes, *deformations, options);
  }
  if (Status s = write_outputs(out, study, comments); !s) return fail(s.error().message);
  std::string plot_names;
  for (const std::string& p : write_plot(out, study, &plot_noted))
    plot_names += ", " + fs::path(p).filename().string();
  std::printf("wrote %s/{convergence.csv, convergence_summary.csv%s}\n", out.c_str(),
              plot_names.c_str());
  if (const int sig = stop_signal(); sig != 0) {
    const bool cut = !study.runs.empty() && study.runs.back().interrupted;
    std::fprintf(stderr,
                 "zona study: interrupted by %s: %zu of %zu sizes run%s; the CSVs hold them\n",
                 stop_signal_name(sig), study.runs.size(), count,
                 cut ? ", the last one up to where the signal stopped it" : "");
    exit_code() = 128 + sig;
  }
}

}  // namespace

void add_study_commands(CLI::App& app) {
  auto* group = app.add_subcommand("study", "Numerical studies of a scene: convergence");
  // Its subcommand is required: main() lists them when it is missing.
  group->require_subcommand(0, 1);

  auto args = std::make_shared<ConvergenceArgs>();
  auto* cmd = group->add_subcommand(
      "convergence",
      "Run a scene's injection at several mesh sizes and compare the force-deformation curves");
  cmd->add_option("scene", args->scene, "Scene file or name (its mesh must be generated)")
      ->required();
  CLI::Option* vertices = cmd->add_option("--vertices", args->vertices,
                  std::string("Mesh sizes: comma list of vertex counts (default: ") + kCpuSizes +
                      " on the CPU, " + kGpuSizes + " on the GPU)");
  cmd->add_option("--backend", args->backend, "Compute backend: auto, cpu or cuda")
      ->capture_default_str();
  add_solver_option(cmd, &args->solver);
  cmd->add_option("--threads", args->threads, "CPU threads (0: all)")->capture_default_str();
  cmd->add_option("--set", args->sets, "Override a scene key: key.path=value (repeatable)");
  cmd->add_option("--deformations", args->deformations,
                  "Deformations [um] at which the forces are compared: comma list")
      ->capture_default_str();
  cmd->add_option("--out", args->out, "Output folder (default: zona_study_<scene name>)");
  cmd->add_flag("--quiet", args->quiet, "No progress lines on stderr");
  cmd->callback([args, vertices] {
    args->vertices_given = vertices->count() > 0;
    convergence_command(*args);
  });
}

}  // namespace zona::cli
