// `zona sweep SCENE --set KEY=A,B,C ... [--manifest F.csv] --jobs N --out DIR`: runs a scene at
// every parameter point, each point a `zona run` child of this program (engine/analysis/
// worker_pool.h), resumable, into one table (DIR/sweep.csv). `--slurm` writes a job array
// instead, whose tasks run `zona sweep --task I --out DIR`; `zona sweep collect DIR` builds the
// table from whatever ran the points (docs/sweeps.md).
#include <signal.h>

#include <algorithm>
#include <atomic>
#include <csignal>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <map>
#include <memory>
#include <sstream>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "apps/commands.h"
#include "engine/analysis/convergence_study.h"
#include "engine/analysis/sweep.h"
#include "engine/core/thread_pool.h"
#include "engine/scene/scene.h"
#include "engine/sim/backend.h"
#include "engine/sim/recorder.h"
#include "kernels/backend_info.h"

namespace zona::cli {
namespace {

namespace fs = std::filesystem;

struct SweepArgs {
  std::string scene;
  std::vector<std::string> sets;
  std::string manifest;
  int jobs = 1;
  std::string backend = "cpu";
  int threads = -1;  // -1: the cores over the jobs
  std::string solver;
  std::string deformations = "10,20,30,40";
  std::string out;
  bool retry_failed = false;
  bool quiet = false;
  bool slurm = false;
  SlurmOptions slurm_options;
  long task = -1;
  std::string collect_dir;
};

std::atomic<bool> g_stop{false};
volatile std::sig_atomic_t g_signal = 0;

extern "C" void on_sweep_signal(int sig) {
  g_signal = sig;
  g_stop.store(true, std::memory_order_relaxed);
}

// SIGINT / SIGTERM stop the sweep: no point starts after it, the running ones are told to stop
// (they write their outputs, and their points run again on resume). No SA_RESTART, so that the
// pool's waitpid returns to look at the flag.
void install_stop_handlers() {
  struct sigaction action {};
  action.sa_handler = on_sweep_signal;
  sigemptyset(&action.sa_mask);
  for (int sig : {SIGINT, SIGTERM}) {
    struct sigaction previous {};
    sigaction(sig, nullptr, &previous);
    if (previous.sa_handler != SIG_IGN) sigaction(sig, &action, nullptr);
  }
}

std::string read_text(const fs::path& p) {
  std::ifstream in(p, std::ios::binary);
  std::ostringstream s;
  s << in.rdbuf();
  return s.str();
}

// The table from the point folders: written to DIR/sweep.csv; counts by status into `counts`.
Status collect(const std::string& dir, const SweepConfig& config, const SweepPoints& points,
               std::map<std::string, size_t>* counts) {
  std::vector<SweepRow> rows;
  for (size_t i = 0; i < points.values.size(); ++i) {
    rows.push_back(read_sweep_row(dir, config, i));
    ++(*counts)[rows.back().status];
  }
  return write_file_atomic((fs::path(dir) / "sweep.csv").string(), sweep_table_csv(config, points, rows));
}

std::string counts_text(const std::map<std::string, size_t>& counts) {
  std::string text;
  for (const char* s : {"ok", "failed", "crashed", "pending"})
    if (auto it = counts.find(s); it != counts.end() && it->second)
      text += (text.empty() ? "" : ", ") + std::to_string(it->second) + " " + s;
  return text;
}

// The sweep folder's points and shared settings (written by the first `zona sweep`).
Status load_folder(const std::string& dir, SweepConfig* config, SweepPoints* points) {
  Result<SweepConfig> c = read_sweep_config(dir);
  if (!c) return c.error();
  Result<SweepPoints> p = read_sweep_manifest((fs::path(dir) / "manifest.csv").string());
  if (!p) return p.error();
  if (p->values.size() != c->point_count)
    return make_error("%s/manifest.csv: %zu points, sweep.json says %zu", dir.c_str(),
                      p->values.size(), c->point_count);
  *config = *c;
  *points = *p;
  return Status::ok_status();
}

// Runs `indices` with the pool; writes each final point's marker. Returns false when stopped.
bool run_points(const std::string& zona, const std::string& dir, const SweepConfig& config,
                const SweepPoints& points, const std::vector<size_t>& indices, int jobs,
                const std::vector<std::string>& devices, bool quiet) {
  std::vector<WorkerJob> work;
  for (size_t i : indices) {
    std::error_code ec;
    fs::create_directories(fs::path(dir) / sweep_point_folder(i), ec);
    work.push_back(sweep_point_job(zona, dir, config, points, i));
  }
  WorkerPoolOptions options;
  options.workers = jobs;
  options.stop = &g_stop;
  // One GPU per worker: slot k sees only its device (devices repeat when jobs exceed them).
  if (!devices.empty())
    options.slot_env = [devices](int slot) {
      return std::vector<std::string>{"CUDA_VISIBLE_DEVICES=" + devices[static_cast<size_t>(slot) % devices.size()]};
    };
  size_t done = 0;
  const size_t left = run_worker_pool(work, options, [&](size_t k, const WorkerOutcome& o) {
    const size_t i = indices[k];
    ++done;
    if (!sweep_outcome_is_final(o)) {
      if (!quiet)
        std::fprintf(stderr, "zona sweep: point %zu: %s; it runs again when the sweep resumes\n", i,
                     describe_outcome(o).c_str());
      return;
    }
    const std::string log = read_text(fs::path(dir) / sweep_point_folder(i) / "run.log");
    const PointRecord r = sweep_point_record(i, o, log);
    if (Status s = write_point_record(dir, r); !s)
      std::fprintf(stderr, "zona sweep: warning: point %zu: %s\n", i, s.error().message.c_str());
    if (!quiet)
      std::fprintf(stderr, "zona sweep: %zu/%zu: point %zu %s%s%s [%.1f s]\n", done, indices.size(), i,
                   r.status.c_str(), r.message.empty() ? "" : ": ", r.message.c_str(), r.wall_seconds);
  });
  return left == 0 && !g_stop.load();
}

// The devices a --backend cuda sweep gives its workers: CUDA_VISIBLE_DEVICES' entries when set,
// else every device's ordinal.
std::vector<std::string> worker_devices(const std::string& backend) {
  if (backend != "cuda") return {};
  std::vector<std::string> out;
  if (const char* visible = std::getenv("CUDA_VISIBLE_DEVICES"); visible && *visible) {
    std::istringstream in(visible);
    std::string d;
    while (std::getline(in, d, ',')) out.push_back(d);
    return out;
  }
  for (const DeviceInfo& d : cuda_devices(nullptr)) out.push_back(std::to_string(d.ordinal));
  return out;
}

void task_command(const SweepArgs& a) {
  if (a.out.empty()) return fail("--task needs --out DIR (the sweep folder)");
  SweepConfig config;
  SweepPoints points;
  if (Status s = load_folder(a.out, &config, &points); !s) return fail(s.error().message);
  if (a.task < 0 || static_cast<size_t>(a.task) >= points.values.size())
    return fail("--task " + std::to_string(a.task) + ": the sweep has points 0.." +
                std::to_string(points.values.size() - 1));
  const size_t i = static_cast<size_t>(a.task);
  Result<std::optional<PointRecord>> marker = read_point_record(a.out, i);
  if (!marker) return fail(marker.error().message);
  if (marker->has_value() && !((*marker)->status != "ok" && a.retry_failed)) {
    std::printf("point %zu: already done (%s)\n", i, (*marker)->status.c_str());
    return;
  }
  install_stop_handlers();
  const std::string zona = self_executable();
  // The devices are the scheduler's (SLURM sets CUDA_VISIBLE_DEVICES for --gres=gpu).
  run_points(zona, a.out, config, points, {i}, 1, {}, true);  // its one line is below
  Result<std::optional<PointRecord>> after = read_point_record(a.out, i);
  if (g_signal != 0) {
    exit_code() = 128 + g_signal;
    return;
  }
  if (!after || !after->has_value()) return fail("point " + std::to_string(i) + ": not finished");
  std::printf("point %zu: %s%s%s\n", i, (*after)->status.c_str(), (*after)->message.empty() ? "" : ": ",
              (*after)->message.c_str());
}

void collect_command(const std::string& dir) {
  SweepConfig config;
  SweepPoints points;
  if (Status s = load_folder(dir, &config, &points); !s) return fail(s.error().message);
  std::map<std::string, size_t> counts;
  if (Status s = collect(dir, config, points, &counts); !s) return fail(s.error().message);
  std::printf("%zu points: %s; wrote %s/sweep.csv\n", points.values.size(), counts_text(counts).c_str(),
              dir.c_str());
}

void sweep_command(const SweepArgs& a) {
  if (a.task >= 0) return task_command(a);
  if (a.jobs < 1) return fail("--jobs must be >= 1");
  if (a.backend != "cpu" && a.backend != "cuda" && a.backend != "auto")
    return fail("--backend '" + a.backend + "': expected auto, cpu or cuda");
  const std::string out = a.out.empty() ? "zona_sweep" : a.out;
  const bool existing = fs::exists(fs::path(out) / "sweep.json");

  // The sweep: from the arguments, or the folder's own when only --out is given (resume).
  SweepConfig config;
  SweepPoints points;
  if (a.scene.empty()) {
    if (!existing) return fail("give a SCENE (or --out DIR of an existing sweep to resume it)");
    if (!a.sets.empty() || !a.manifest.empty())
      return fail("--set and --manifest need a SCENE (the folder's sweep has its own)");
    if (Status s = load_folder(out, &config, &points); !s) return fail(s.error().message);
  } else {
    Result<std::string> path = find_scene_file(a.scene);
    if (!path) return fail(path.error().message);
    config.scene = *path;
    Result<SweepPoints> from_sets = sweep_points_from_sets(a.sets, &config.fixed);
    if (!from_sets) return fail(from_sets.error().message);
    SweepPoints from_manifest;
    if (!a.manifest.empty()) {
      Result<SweepPoints> m = read_sweep_manifest(a.manifest);
      if (!m) return fail(m.error().message);
      from_manifest = *m;
    }
    Result<SweepPoints> all = combine_sweep_points(from_manifest, *from_sets);
    if (!all) return fail(all.error().message);
    points = *all;
    if (points.values.empty())
      return fail("no parameter to sweep: give --set KEY=A,B,C (several values) or --manifest F.csv");
    Result<std::vector<double>> d = parse_study_deformations(a.deformations);
    if (!d) return fail(d.error().message);
    config.deformations = *d;
    config.backend = a.backend;
    config.solver = a.solver;
    // A SLURM task runs on the node the scheduler picks, with --slurm-cpus cores: it takes
    // those (--threads 0: the cores it may run on), not a share of this machine's.
    const int cores = available_cores();
    config.threads = a.threads >= 0 ? a.threads : a.slurm ? 0 : std::max(1, cores / a.jobs);
    config.point_count = points.values.size();
    // Every point's scene must load: a typo in a key fails here, not in 100 logs.
    for (size_t i = 0; i < points.values.size(); ++i) {
      std::vector<std::string> o = config.fixed;
      if (!config.solver.empty()) o.push_back("solver.method=" + config.solver);
      for (size_t k = 0; k < points.keys.size(); ++k) o.push_back(points.keys[k] + "=" + points.values[i][k]);
      if (Result<Scene> s = load_scene(config.scene, o); !s)
        return fail("point " + std::to_string(i) + ": " + s.error().message);
    }
    // An existing folder must hold this same sweep (resume), never another one's points.
    const std::string config_text = sweep_config_json(config).dump(2) + "\n";
    const std::string manifest_text = sweep_manifest_csv(points);
    if (existing) {
      if (read_text(fs::path(out) / "sweep.json") != config_text ||
          read_text(fs::path(out) / "manifest.csv") != manifest_text)
        return fail(out + " holds a different sweep (its sweep.json or manifest.csv differs): use "
                          "another --out, or `zona sweep --out " + out + "` to resume that one");
    } else {
      std::error_code ec;
      fs::create_directories(fs::path(out) / "points", ec);
      if (ec) return fail(out + ": cannot create the folder: " + ec.message());
      if (Status s = write_file_atomic((fs::path(out) / "manifest.csv").string(), manifest_text); !s)
        return fail(s.error().message);
      if (Status s = write_file_atomic((fs::path(out) / "sweep.json").string(), config_text); !s)
        return fail(s.error().message);
    }
  }
  const std::string dir = fs::absolute(out).lexically_normal().string();
  const std::string zona = self_executable();
  if (zona.empty()) return fail("cannot find this program's path (/proc/self/exe)");

  if (a.slurm) {
    SlurmOptions o = a.slurm_options;
    if (config.backend == "cuda" && o.gpus_per_task == 0) o.gpus_per_task = 1;
    std::error_code ec;
    fs::create_directories(fs::path(dir) / "slurm", ec);  // sbatch does not create --output's folder
    const std::string script = (fs::path(dir) / "sweep.sbatch").string();
    if (Status s = write_file_atomic(script, slurm_script(zona, dir, points.values.size(), o)); !s)
      return fail(s.error().message);
    std::printf("wrote %s (%zu array tasks) and %s/manifest.csv\n", script.c_str(), points.values.size(),
                dir.c_str());
    std::printf("submit: sbatch %s\nthen:   zona sweep collect %s\n", script.c_str(), dir.c_str());
    return;
  }

  // The points left: no marker (never run, or killed), or a failed one with --retry-failed.
  std::vector<size_t> todo;
  for (size_t i = 0; i < points.values.size(); ++i) {
    Result<std::optional<PointRecord>> marker = read_point_record(dir, i);
    if (!marker) return fail(marker.error().message);
    if (!marker->has_value() || ((*marker)->status != "ok" && a.retry_failed)) todo.push_back(i);
  }
  const std::vector<std::string> devices = worker_devices(config.backend);
  if (config.backend == "cuda" && devices.empty())
    return fail("--backend cuda: no CUDA device (zona info lists them)");
  if (!a.quiet) {
    std::fprintf(stderr, "zona sweep: %zu points, %zu done, %zu to run with %d worker%s%s\n",
                 points.values.size(), points.values.size() - todo.size(), todo.size(), a.jobs,
                 a.jobs == 1 ? "" : "s",
                 devices.empty() ? "" : (", on " + std::to_string(devices.size()) + " GPU(s)").c_str());
  }
  install_stop_handlers();
  run_points(zona, dir, config, points, todo, a.jobs, devices, a.quiet);

  std::map<std::string, size_t> counts;
  if (Status s = collect(dir, config, points, &counts); !s) return fail(s.error().message);
  std::printf("%zu points: %s; wrote %s/sweep.csv\n", points.values.size(), counts_text(counts).c_str(),
              out.c_str());
  if (g_signal != 0) {
    std::fprintf(stderr, "zona sweep: stopped by signal %d; `zona sweep --out %s` resumes\n",
                 static_cast<int>(g_signal), out.c_str());
    exit_code() = 128 + g_signal;
  }
}

}  // namespace

void add_sweep_command(CLI::App& app) {
  auto args = std::make_shared<SweepArgs>();
  auto* cmd = app.add_subcommand(
      "sweep", "Run a scene at many parameter points (local workers or a SLURM array) into one table");
  cmd->add_option("scene", args->scene, "Scene file or name (omit with --out DIR to resume DIR's sweep)");
  cmd->add_option("--set", args->sets,
                  "KEY=A,B,C: sweep a scene key over these values (the points are the product of "
                  "all lists); KEY=VALUE: a fixed override (repeatable)");
  cmd->add_option("--manifest", args->manifest,
                  "CSV of points: a header of scene keys, one point per row (combined with --set lists)");
  cmd->add_option("--jobs", args->jobs, "Local workers (with --backend cuda: one GPU each)")
      ->capture_default_str();
  cmd->add_option("--backend", args->backend, "Compute backend of every point: auto, cpu or cuda")
      ->capture_default_str();
  cmd->add_option("--threads", args->threads,
                  "CPU threads per point (default: the cores over --jobs; with --slurm, each "
                  "task's --slurm-cpus)");
  cmd->add_option("--solver", args->solver, "Solver of every point: sets solver.method (explicit, static)");
  cmd->add_option("--deformations", args->deformations,
                  "Deformations [um] at which the table gives the force: comma list")
      ->capture_default_str();
  cmd->add_option("--out", args->out, "Sweep folder (default: zona_sweep)");
  cmd->add_flag("--retry-failed", args->retry_failed, "Run failed and crashed points again");
  cmd->add_flag("--quiet", args->quiet, "No line per point on stderr");
  cmd->add_flag("--slurm", args->slurm,
                "Write DIR/sweep.sbatch (a job array, one task per point) instead of running");
  cmd->add_option("--slurm-time", args->slurm_options.time, "--slurm: time limit per task")
      ->capture_default_str();
  cmd->add_option("--slurm-cpus", args->slurm_options.cpus_per_task, "--slurm: CPUs per task")
      ->capture_default_str();
  cmd->add_option("--slurm-max-parallel", args->slurm_options.max_parallel,
                  "--slurm: tasks running at once (the array's %N; 0: no limit)");
  cmd->add_option("--slurm-option", args->slurm_options.extra,
                  "--slurm: another #SBATCH option, e.g. --partition=gpu (repeatable)");
  cmd->add_option("--task", args->task,
                  "Run point I of the sweep in --out DIR (what each SLURM array task runs)");
  auto* collect_cmd = cmd->add_subcommand("collect", "Build DIR/sweep.csv from the sweep's point folders");
  collect_cmd->add_option("dir", args->collect_dir, "Sweep folder")->required();
  collect_cmd->callback([args] { collect_command(args->collect_dir); });
  cmd->callback([args, cmd] {
    if (cmd->got_subcommand("collect")) return;
    sweep_command(*args);
  });
}

}  // namespace zona::cli
