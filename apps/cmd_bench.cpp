// `zona bench`: the vertices-versus-time scaling benchmark (Ladjal et al. Table II and beyond) as a
// CSV, with a progress bar on stderr. The measurement lives in bench/scaling/scaling_bench.h; this file
// parses the options and wires in the backend factory and the GPU probes from kernels/.
#include <unistd.h>

#include <chrono>
#include <cstdio>
#include <fstream>
#include <memory>
#include <string>
#include <vector>

#include "apps/bench_job.h"
#include "apps/commands.h"
#include "bench/scaling/scaling_bench.h"
#include "kernels/backend_factory.h"
#include "kernels/backend_info.h"
#include "kernels/cuda_probe.h"

namespace zona::cli {
namespace {

// The "cpu" line of /proc/stat, in clock ticks: the sum of all fields and the steal field
// (zeros where the file is missing).
struct CpuTimes {
  uint64_t total = 0;
  uint64_t steal = 0;
};

CpuTimes read_cpu_times() {
  CpuTimes t;
  std::ifstream stat("/proc/stat");
  std::string label;
  if (!(stat >> label) || label != "cpu") return t;
  for (int field = 0; field < 10; ++field) {
    uint64_t v = 0;
    if (!(stat >> v)) break;
    t.total += v;
    if (field == 7) t.steal = v;
  }
  return t;
}

struct BenchArgs {
  std::string backend = "cpu";
  std::string model = "svk";
  std::string formulation = "gradient";
  std::string vertices = "table2";
  std::string max_vertices;
  std::string threads = "0";
  std::string assembly;
  int steps = 0;
  int repeats = 7;
  int copy_mib = 256;
  std::string precision = "float64";
  std::string out;
  bool job = false;
  std::string scene = "mouse_oocyte";
  std::vector<std::string> sets;
  std::string solver;
  double max_run_seconds = 120;
};

// The run's options in full (defaults included), for the CSV's comment lines.
std::string command_line(const BenchArgs& a) {
  std::string c = "zona bench --backend " + a.backend + " --model " + a.model +
                  " --formulation " + a.formulation + " --vertices " + a.vertices;
  if (!a.max_vertices.empty()) c += " --max-vertices " + a.max_vertices;
  c += " --steps " + std::to_string(a.steps) + " --repeats " + std::to_string(a.repeats) +
       " --threads " + a.threads;
  if (!a.assembly.empty()) c += " --assembly " + a.assembly;
  if (a.copy_mib != 256) c += " --copy-mib " + std::to_string(a.copy_mib);
  if (a.precision != "float64") c.append(" --precision ").append(a.precision);
  return c;
}

// stderr progress: a redrawn bar on a terminal, one line per finished row otherwise.
class ProgressPrinter {
 public:
  ProgressPrinter() : tty_(isatty(STDERR_FILENO) == 1), start_(std::chrono::steady_clock::now()) {}

  void progress(const ScalingProgress& p) {
    if (!tty_) return;
    row_ = p.row;
    row_count_ = p.row_count;
    label_ = p.label;
    phase_ = p.phase;
    draw();
  }

  void row(const ScalingRow& r) {
    clear();
    std::fprintf(stderr,
                 "zona bench: [%d/%d] %s %s %s %dt%s %lld: %lld vertices, %.4g ms/step, "
                 "precompute %.4g ms, %s\n",
                 row_, row_count_, r.backend.c_str(), r.model.c_str(), r.formulation.c_str(),
                 r.threads, r.threads_requested == 0 ? " (auto)" : "",
                 static_cast<long long>(r.target_vertices),
                 static_cast<long long>(r.vertices), r.step_ms_median, r.precompute_ms,
                 r.status.c_str());
    draw();
  }

  void notice(const std::string& text) {
    clear();
    std::fprintf(stderr, "zona: notice: %s\n", text.c_str());
    draw();
  }

  void finish() { clear(); }

  /// Rows finished so far (for the plain lines, which have no bar to count them).
  void count(const ScalingProgress& p) {
    row_ = p.row;
    row_count_ = p.row_count;
  }

 private:
  void draw() {
    if (!tty_ || row_count_ <= 0) return;
    constexpr int kWidth = 28;
    const int filled = row_count_ > 0 ? kWidth * row_ / row_count_ : 0;
    std::string bar(static_cast<size_t>(filled), '#');
    bar.resize(kWidth, '.');
    const double s =
        std::chrono::duration<double>(std::chrono::steady_clock::now() - start_).count();
    std::fprintf(stderr, "\r\033[K[%s] %d/%d %5.0fs  %s: %s", bar.c_str(), row_, row_count_, s,
                 label_.c_str(), phase_.c_str());
    std::fflush(stderr);
    drawn_ = true;
  }
  void clear() {
    if (tty_ && drawn_) std::fprintf(stderr, "\r\033[K");
    drawn_ = false;
  }

  bool tty_;
  bool drawn_ = false;
  std::chrono::steady_clock::time_point start_;
  int row_ = 0, row_count_ = 0;
  std::string label_, phase_;
};

// Parses the options into a config; one-line errors.
Result<ScalingBenchConfig> make_config(const BenchArgs& a) {
  ScalingBenchConfig c;
  Result<std::vector<BackendKind>> backends = parse_bench_backends(a.backend);
  if (!backends) return backends.error();
  c.backends = *backends;
  c.skip_unavailable_backends = a.backend == "all";
  Result<std::vector<ConstitutiveModel>> models = parse_bench_models(a.model);
  if (!models) return models.error();
  c.models = *models;
  Result<std::vector<Formulation>> forms = parse_bench_formulations(a.formulation);
  if (!forms) return forms.error();
  c.formulations = *forms;
  Result<std::vector<int>> threads = parse_thread_list(a.threads);
  if (!threads) return threads.error();
  c.threads = *threads;
  if (!a.assembly.empty()) {
    Result<Assembly> assembly = parse_assembly(a.assembly);
    if (!assembly) return make_error("--assembly: %s", assembly.error().message.c_str());
    c.assembly = *assembly;
  }
  if (a.steps < 0) return make_error("--steps: must be >= 0 (0: automatic), got %d", a.steps);
  if (a.repeats < 1) return make_error("--repeats: must be >= 1, got %d", a.repeats);
  if (a.copy_mib < 1 || a.copy_mib > 65536)
    return make_error("--copy-mib: must be in [1, 65536], got %d", a.copy_mib);
  if (a.precision == "float32")
    c.element_precision = ElementPrecision::kFloat32;
  else if (a.precision != "float64")
    return make_error("--precision: '%s' is neither float64 nor float32", a.precision.c_str());
  c.steps = a.steps;
  c.repeats = a.repeats;
  c.copy_bytes = static_cast<size_t>(a.copy_mib) << 20;
  // The largest size: --max-vertices, else (sweep) what fits in memory, else no cap.
  int64_t max_vertices = int64_t{1} << 30;
  if (!a.max_vertices.empty()) {
    Result<std::vector<int64_t>> cap = parse_vertex_list(a.max_vertices, int64_t{1} << 30);
    if (!cap || cap->size() != 1)
      return make_error("--max-vertices: '%s' is not one vertex count >= %lld",
                        a.max_vertices.c_str(), static_cast<long long>(kMinBenchVertices));
    max_vertices = cap->front();
  } else if (a.vertices == "sweep") {
    max_vertices = memory_fit_vertices(c);
  }
  Result<std::vector<int64_t>> sizes = parse_vertex_list(a.vertices, max_vertices);
  if (!sizes) return sizes.error();
  c.vertices = *sizes;
  return c;
}

void print_summary(const ScalingBenchResult& result) {
  std::printf("%-5s %-7s %-15s %3s %9s %9s %12s %12s %12s %9s %8s\n", "back", "model",
              "formulation", "thr", "vertices", "tets", "precomp_ms", "step_ms", "steps/s",
              "floor_ms", "GB/s");
  for (const ScalingRow& r : result.rows)
    std::printf("%-5s %-7s %-15s %3d %9lld %9lld %12.4g %12.4g %12.4g %9.3g %8.3g\n",
                r.backend.c_str(), r.model.c_str(), r.formulation.c_str(), r.threads,
                static_cast<long long>(r.vertices), static_cast<long long>(r.tets),
                r.precompute_ms, r.step_ms_median, r.steps_per_s, r.floor_ms, r.gb_per_s);
}

}  // namespace

void add_bench_command(CLI::App& app) {
  auto args = std::make_shared<BenchArgs>();
  auto* cmd = app.add_subcommand(
      "bench", "Vertices-versus-time scaling benchmark: precompute and step time per mesh size, "
               "CSV (Ladjal et al. Table II and beyond)");
  cmd->add_option("--backend", args->backend, "cpu, cuda or all")->capture_default_str();
  cmd->add_option("--model", args->model, "svk, linear or all")->capture_default_str();
  cmd->add_option("--formulation", args->formulation,
                  "gradient, tensor_rebuilt, tensor_stored, all, or a comma list")
      ->capture_default_str();
  cmd->add_option("--vertices", args->vertices,
                  "Comma list of vertex counts (1093,1e6), 'table2' (Ladjal et al. Table II's twelve sizes) or "
                  "'sweep' (powers of two from 128 to --max-vertices or what fits in memory)")
      ->capture_default_str();
  cmd->add_option("--max-vertices", args->max_vertices, "Largest size of a sweep (e.g. 1e6)");
  cmd->add_option("--steps", args->steps, "Steps per timed block (0: automatic, by size)")
      ->capture_default_str();
  cmd->add_option("--repeats", args->repeats, "Timed blocks per row (median and p90 over them)")
      ->capture_default_str();
  cmd->add_option("--threads", args->threads,
                  "CPU threads, or a comma list (1,2); 0: the backend's automatic choice "
                  "(one per ~2000 tetrahedra up to the hardware's count)")
      ->capture_default_str();
  cmd->add_option("--assembly", args->assembly,
                  std::string("GPU assembly (default ") + assembly_name(BackendOptions{}.assembly) +
                      ")");
  cmd->add_option("--copy-mib", args->copy_mib,
                  "Buffer of the CPU copy-bandwidth measurement [MiB] (larger than the caches)")
      ->capture_default_str();
  cmd->add_option("--precision", args->precision,
                  "CPU element math, gradient form: float64 (the reference) or float32 (eight "
                  "tetrahedra per AVX2 pack; displacements and force sums stay float64)")
      ->capture_default_str();
  cmd->add_option("--out", args->out, "Write the CSV here (else to stdout)");
  cmd->add_flag("--job", args->job,
                "Time the injection job (zona run of --scene: contact, holding, damping, puncture "
                "test, recording) per size, beside the bare step");
  cmd->add_option("--scene", args->scene, "--job: the scene (default mouse_oocyte)")
      ->capture_default_str();
  cmd->add_option("--set", args->sets, "--job: override a scene key, key.path=value (repeatable)");
  add_solver_option(cmd, &args->solver);
  cmd->add_option("--max-run-seconds", args->max_run_seconds,
                  "--job: run to puncture when the estimated run is shorter than this [s]; "
                  "otherwise the time to puncture is estimated from the measured step")
      ->capture_default_str();
  cmd->callback([args] {
    if (args->job) {
      JobBenchArgs j;
      j.scene = args->scene;
      j.sets = with_solver(args->sets, args->solver);
      j.backend = args->backend;
      j.vertices = args->vertices == "table2" ? "1e3,4e3,16e3" : args->vertices;
      j.threads = std::atoi(args->threads.c_str());
      j.steps = args->steps;
      j.repeats = args->repeats;
      j.max_run_seconds = args->max_run_seconds;
      j.commit = source_commit();
      j.command = "zona bench --job --backend " + args->backend + " --scene " + args->scene +
                  " --vertices " + j.vertices + " --repeats " + std::to_string(args->repeats);
      for (const std::string& s : args->sets) j.command += " --set " + s;
      if (!args->solver.empty()) j.command += " --solver " + args->solver;
      std::string notice;
      const std::vector<DeviceInfo> devices = cuda_devices(&notice);
      if (!devices.empty()) j.device_name = devices.front().name;
      FILE* csv = stdout;
      if (!args->out.empty()) {
        csv = std::fopen(args->out.c_str(), "w");
        if (!csv) return fail("--out: cannot write " + args->out);
      }
      const Status st = run_job_bench(j, csv);
      if (csv != stdout) std::fclose(csv);
      if (!st) return fail(st.error().message);
      if (csv != stdout) std::printf("wrote %s\n", args->out.c_str());
      return;
    }
    Result<ScalingBenchConfig> config = make_config(*args);
    if (!config) return fail(config.error().message);

    FILE* csv = stdout;
    if (!args->out.empty()) {
      csv = std::fopen(args->out.c_str(), "w");
      if (!csv) return fail("--out: cannot write " + args->out);
    }

    MachineInfo machine = local_machine_info();
    machine.commit = source_commit();
    machine.command = command_line(*args);
    std::string device_notice;
    const std::vector<DeviceInfo> devices = cuda_devices(&device_notice);
    if (!devices.empty()) machine.gpu_name = devices.front().name;

    ProgressPrinter printer;
    ScalingBenchHooks hooks;
    hooks.make_backend = [](BackendKind kind, const BackendOptions& options) {
      return make_backend(kind, options);
    };
    hooks.device_copy_bandwidth = []() -> Result<double> {
      Result<CopyBandwidth> bw = measure_copy_bandwidth(size_t{1} << 30, 20);
      if (!bw) return bw.error();
      return bw->gb_per_s;
    };
    const ScalingBenchConfig& cfg = *config;
    hooks.started = [csv, &cfg](const ScalingBenchResult& r) {
      std::fprintf(csv, "%s%s\n", scaling_csv_comments(r, cfg).c_str(),
                   scaling_csv_header().c_str());
      std::fflush(csv);
    };
    hooks.row = [csv, &printer](const ScalingRow& r) {
      std::fprintf(csv, "%s\n", scaling_csv_row(r).c_str());
      std::fflush(csv);
      printer.row(r);
    };
    hooks.progress = [&printer](const ScalingProgress& p) {
      printer.count(p);
      printer.progress(p);
    };
    hooks.notice = [&printer](const std::string& text) { printer.notice(text); };

    const CpuTimes before = read_cpu_times();
    Result<ScalingBenchResult> result = run_scaling_bench(cfg, hooks, machine);
    const CpuTimes after = read_cpu_times();
    printer.finish();
    // On a virtual machine the host may run other guests on this one's vCPUs ("steal"); a
    // timing taken then is slower for reasons that are not the code.
    if (result && after.total > before.total)
      std::fprintf(csv, "# host steal time during the run: %.1f %% of CPU time (/proc/stat)\n",
                   100.0 * static_cast<double>(after.steal - before.steal) /
                       static_cast<double>(after.total - before.total));
    if (csv != stdout) std::fclose(csv);
    if (!result) return fail(result.error().message);
    if (csv != stdout) {
      print_summary(*result);
      std::printf("wrote %s\n", args->out.c_str());
    }
  });
}

}  // namespace zona::cli
