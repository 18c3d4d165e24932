// `zona bench --job`: the injection job as the user runs it (contact, holding, damping,
// puncture test, recording: everything `zona run` does), at a list of mesh sizes, beside the
// bare step that `zona bench` times on the same mesh and law. One CSV row per size.
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <string>
#include <vector>

#include "apps/bench_job.h"
#include "apps/commands.h"
#include "bench/scaling/scaling_bench.h"
#include "engine/sim/simulation.h"
#include "kernels/backend_factory.h"

namespace zona::cli {
namespace {

using Clock = std::chrono::steady_clock;

double seconds_since(Clock::time_point t) {
  return std::chrono::duration<double>(Clock::now() - t).count();
}

double quantile(std::vector<double> v, double q) {
  if (v.empty()) return 0;
  std::sort(v.begin(), v.end());
  const double pos = q * static_cast<double>(v.size() - 1);
  const size_t lo = static_cast<size_t>(std::floor(pos));
  const size_t hi = std::min(v.size() - 1, lo + 1);
  return v[lo] + (pos - static_cast<double>(lo)) * (v[hi] - v[lo]);
}

// Steps per timed block: about 50 ms of work at the expected speed, at least 20.
int block_steps(int64_t vertices, bool gpu) {
  const double per_step_ms = gpu ? 0.004 + 2.8e-7 * static_cast<double>(vertices)
                                 : 5e-5 * static_cast<double>(vertices);
  // The GPU's bare step replays one captured graph of this many sub-steps: keep it modest.
  return static_cast<int>(std::clamp(50.0 / per_step_ms, 20.0, gpu ? 2000.0 : 20000.0));
}

// A static run's row: the whole run to the puncture and its release (no time step, no bare
// kernel: those columns stay empty), wall to the puncture's state, and the solver's work.
Status static_row(const MachineInfo& machine, const Scene& scene,
                  Simulation& sim, int64_t target, double setup_s, FILE* csv) {
  const Model& model = sim.model();
  std::fprintf(stderr, "zona bench --job: static, %lld vertices: setup %.2f s\n",
               static_cast<long long>(model.vertex_count()), setup_s);
  RunOptions ro;
  ro.stop_after_puncture = 0;
  const RunResult run = run_simulation(sim, ro);
  std::string status = run.stopped_early ? "stopped: " + run.stop_reason
                       : run.puncture.punctured ? "ok" : "no puncture";
  for (char& c : status)
    if (c == ',') c = ';';
  const bool measured = run.puncture.punctured && run.puncture_wall_seconds >= 0;
  std::fprintf(csv,
               "cpu,%s,%s,%lld,%zu,%zu,,,%d,,,,,,,,%.4g,,%.4g,%d,%.4g,%.4g,%s,static,%lld,%lld,"
               "%lld,%s\n",
               machine.cpu_model.c_str(), scene.name.c_str(), static_cast<long long>(target),
               model.vertex_count(), model.tet_count(), 1, setup_s,
               measured ? setup_s + run.puncture_wall_seconds : 0.0, measured ? 1 : 0,
               run.puncture.deformation * 1e6, run.puncture.force * 1e6, status.c_str(),
               static_cast<long long>(run.newton_iterations),
               static_cast<long long>(run.krylov_iterations),
               static_cast<long long>(run.failed_solves),
               preconditioner_used(scene.solver, model.vertex_count()));
  std::fflush(csv);
  std::fprintf(stderr,
               "zona bench --job: static, %lld vertices: to puncture %.3g s, %lld Newton "
               "iterations (%lld failed solves)%s\n",
               static_cast<long long>(model.vertex_count()),
               measured ? setup_s + run.puncture_wall_seconds : 0.0,
               static_cast<long long>(run.newton_iterations),
               static_cast<long long>(run.failed_solves), measured ? "" : " (no puncture)");
  return {};
}

}  // namespace

std::string job_bench_csv_header() {
  return "backend,device,scene,target_vertices,vertices,tets,dt_s,steps_per_block,repeats,"
         "job_ms_median,job_ms_p10,job_ms_p90,kernel_ms_median,job_over_kernel,realtime_factor,"
         "host_bytes_per_step,setup_s,puncture_step,wall_to_puncture_s,puncture_measured,"
         "puncture_deformation_um,puncture_force_un,status,solver,newton_iterations,"
         "krylov_iterations,failed_solves,preconditioner";
}

Status run_job_bench(const JobBenchArgs& a, FILE* csv) {
  Result<std::vector<int64_t>> sizes = parse_vertex_list(a.vertices, int64_t{1} << 30);
  if (!sizes) return sizes.error();
  Result<BackendKind> kind = parse_backend_kind(a.backend);
  if (!kind) return kind.error();
  if (*kind == BackendKind::kAuto) return make_error("--backend: give cpu or cuda for --job");
  Result<std::string> path = find_scene_file(a.scene);
  if (!path) return path.error();
  if (a.repeats < 1) return make_error("--repeats: must be >= 1, got %d", a.repeats);
  const bool gpu = *kind == BackendKind::kCuda;

  MachineInfo machine = local_machine_info();
  std::fprintf(csv, "# zona bench --job: the injection job (zona run) beside the bare step\n");
  std::fprintf(csv, "# machine: %s, %d hardware threads%s%s\n", machine.cpu_model.c_str(),
               machine.hardware_threads, a.device_name.empty() ? "" : ", GPU ",
               a.device_name.c_str());
  std::fprintf(csv, "# date: %s; commit: %s\n", machine.date.c_str(), a.commit.c_str());
  std::fprintf(csv, "# command: %s\n", a.command.c_str());
  std::fprintf(csv,
               "# job_ms: wall time per step of the whole job in blocks of steps_per_block "
               "(launch, tools, element pass, update, measurement, record; the GPU's blocks end "
               "with a stream synchronisation); kernel_ms: the bare step of the same model "
               "(Backend::step, zona bench's row); realtime_factor: simulated s per wall s\n");
  std::fprintf(csv,
               "# solver static (--solver static or the scene's solver.method): one run to the "
               "puncture and its release per size; wall_to_puncture_s: setup and the run to the "
               "puncture's state; newton_iterations, krylov_iterations, failed_solves: over the "
               "whole run; the step columns empty (docs/static.md)\n");
  std::fprintf(csv, "%s\n", job_bench_csv_header().c_str());
  std::fflush(csv);

  BackendOptions backend_options;
  backend_options.cpu_threads = a.threads;
  for (const int64_t target : *sizes) {
    std::vector<std::string> sets = a.sets;
    sets.push_back("mesh.generate.vertices=" + std::to_string(target));
    sets.push_back("output.frames=0");
    Result<Scene> scene = load_scene(*path, sets);
    if (!scene) return scene.error();
    SimulationOptions so;
    so.threads = a.threads;
    if (gpu)
      so.backend_factory = [&](std::string* notice) {
        return make_backend(BackendKind::kCuda, backend_options, notice);
      };
    const auto setup_start = Clock::now();
    Result<std::unique_ptr<Simulation>> created = Simulation::create(*scene, so);
    if (!created) return created.error();
    Simulation& sim = **created;
    const double setup_s = seconds_since(setup_start);
    if (!sim.job_mode())
      return make_error("%s: the scene does not run the injection step (contact.model)",
                        scene->name.c_str());
    const Model& model = sim.model();
    if (scene->solver.method == SolverMethod::kStatic) {
      if (gpu) return make_error("--solver static: the static solver runs on the CPU (--backend cpu)");
      if (Status s = static_row(machine, *scene, sim, target, setup_s, csv); !s) return s;
      continue;
    }
    const int steps = a.steps > 0 ? a.steps : block_steps(static_cast<int64_t>(model.vertex_count()), gpu);
    std::fprintf(stderr, "zona bench --job: %s %lld vertices: setup %.2f s, %d steps per block\n",
                 a.backend.c_str(), static_cast<long long>(model.vertex_count()), setup_s, steps);

    // The bare step on the same model (a backend of its own, zero state).
    double kernel_ms = 0;
    {
      Result<std::unique_ptr<Backend>> bare = make_backend(*kind, backend_options);
      if (!bare) return bare.error();
      State zero = make_state(model, a.threads);
      if (Status s = (*bare)->upload(model, zero); !s) return s;
      std::vector<double> ms;
      (*bare)->step(steps);  // warm-up (graph capture, caches)
      for (int r = 0; r < a.repeats; ++r) {
        const auto t0 = Clock::now();
        const StepReport rep = (*bare)->step(steps);
        const double wall_ms = 1e3 * seconds_since(t0);
        ms.push_back((gpu && rep.device_ms > 0 ? rep.device_ms : wall_ms) / steps);
      }
      kernel_ms = quantile(ms, 0.5);
    }

    // The job, in blocks, from the start of the injection.
    JobRunner& job = *sim.job();
    const double job_start_wall = setup_s;
    const auto run_start = Clock::now();
    std::vector<double> ms;
    if (Status s = job.advance(steps); !s) return s;  // warm-up
    if (Status s = job.finish(); !s) return s;
    const uint64_t bytes_before = job.host_bytes_moved();
    const int64_t steps_before = job.steps_advanced();
    for (int r = 0; r < a.repeats; ++r) {
      const auto t0 = Clock::now();
      if (Status s = job.advance(steps); !s) return s;
      if (Status s = job.finish(); !s) return s;
      ms.push_back(1e3 * seconds_since(t0) / steps);
    }
    const double bytes_per_step =
        static_cast<double>(job.host_bytes_moved() - bytes_before) /
        static_cast<double>(std::max<int64_t>(1, job.steps_advanced() - steps_before));
    const double job_ms = quantile(ms, 0.5);
    // A job that halted (a blow-up) within the timed blocks stepped no further: its time is not
    // a step's. The row says so and the run to puncture is skipped.
    JobRecord last;
    const bool halted = job.latest(&last) && last.halted;

    // To puncture: run on (the blocks above were its first steps) when it fits the budget.
    const int64_t total = static_cast<int64_t>(std::ceil(sim.end_time() / model.dt - 0.5));
    const double estimate_s = job_ms * 1e-3 * static_cast<double>(total);
    bool measured = false;
    double wall_to_puncture = 0;
    int64_t puncture_step = -1;
    double deformation_um = 0, force_un = 0;
    std::string status = "ok";
    if (halted) {
      status = "halted at step " + std::to_string(last.step) +
               " within the timed blocks (health check failed): job_ms is not a step's time";
    } else if (estimate_s <= a.max_run_seconds) {
      RunOptions ro;
      ro.stop_after_puncture = 0;
      const RunResult run = run_simulation(sim, ro);
      const double run_s = seconds_since(run_start);
      if (run.stopped_early) status = "stopped: " + run.stop_reason;
      if (run.puncture.punctured) {
        measured = true;
        puncture_step = run.puncture.step;
        // Wall to puncture: setup plus the stepping up to the puncture step (the run stops
        // within a batch after it; that tail is taken off at the measured pace).
        const double tail_steps = static_cast<double>(run.steps - run.puncture.step);
        wall_to_puncture = job_start_wall + run_s - tail_steps * job_ms * 1e-3;
        deformation_um = run.puncture.deformation * 1e6;
        force_un = run.puncture.force * 1e6;
      } else if (status == "ok") {
        status = "no puncture";
      }
    } else {
      wall_to_puncture = setup_s + estimate_s;  // estimate: the whole run at the measured pace
    }
    for (char& c : status)
      if (c == ',') c = ';';
    std::fprintf(csv,
                 "%s,%s,%s,%lld,%zu,%zu,%.6g,%d,%d,%.6g,%.6g,%.6g,%.6g,%.4g,%.4g,%.4g,%.4g,%lld,"
                 "%.4g,%d,%.4g,%.4g,%s,explicit,,,,\n",
                 a.backend.c_str(), gpu ? a.device_name.c_str() : machine.cpu_model.c_str(),
                 scene->name.c_str(), static_cast<long long>(target), model.vertex_count(),
                 model.tet_count(), model.dt, steps, a.repeats, job_ms, quantile(ms, 0.1),
                 quantile(ms, 0.9), kernel_ms, kernel_ms > 0 ? job_ms / kernel_ms : 0.0,
                 job_ms > 0 ? model.dt / (job_ms * 1e-3) : 0.0, bytes_per_step, setup_s,
                 static_cast<long long>(puncture_step), wall_to_puncture, measured ? 1 : 0,
                 deformation_um, force_un, status.c_str());
    std::fflush(csv);
    std::fprintf(stderr,
                 "zona bench --job: %lld vertices: job %.4g ms/step, kernel %.4g ms/step "
                 "(x%.3g), real time x%.3g, to puncture %.3g s%s\n",
                 static_cast<long long>(model.vertex_count()), job_ms, kernel_ms,
                 kernel_ms > 0 ? job_ms / kernel_ms : 0.0, model.dt / (job_ms * 1e-3),
                 wall_to_puncture, halted ? " (HALTED: see the CSV's status)" : (measured ? "" : " (estimated)"));
  }
  return {};
}

}  // namespace zona::cli
