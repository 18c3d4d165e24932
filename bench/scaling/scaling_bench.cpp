// The scaling benchmark's measurement: meshes per size, model builds timed, loaded states
// stepped through the Backend interface in timed blocks, bytes per step, copy bandwidth, hash,
// and the CSV text.
// (About 800 lines: the benchmark's meshes, its timing loops per backend and formulation, the
// Ladjal et al.'s Table II and the CSV are one measurement; kept together.)
#include "bench/scaling/scaling_bench.h"

#include <algorithm>
#include <bit>
#include <chrono>
#include <cmath>
#include <cstring>
#include <ctime>
#include <fstream>
#include <limits>
#include <optional>
#include <sstream>
#include <thread>

#include "engine/fem/forces_cpu.h"
#include "engine/sim/integrator.h"
#include "engine/core/parallel.h"
#include "engine/mesh/mesh_generate.h"
#include "engine/fem/model.h"
#include "engine/fem/state.h"

namespace zona {
namespace {

using Clock = std::chrono::steady_clock;

double ms_since(Clock::time_point t0) {
  return std::chrono::duration<double, std::milli>(Clock::now() - t0).count();
}

// Ladjal et al. Table II, transcribed (vertices, tetrahedra, precompute ms, step ms).
constexpr SeedTable2Row kSeedTable2[] = {
    {115, 332, 0.875, 0.047},    {123, 379, 0.99, 0.047},    {128, 407, 1.094, 0.063},
    {165, 546, 1.718, 0.078},    {176, 614, 2.031, 0.094},   {192, 672, 2.359, 0.109},
    {271, 979, 4.546, 0.156},    {282, 1019, 4.859, 0.156},  {346, 1269, 7.39, 0.187},
    {516, 2130, 18.828, 0.328},  {731, 3060, 36.5, 0.453},   {1093, 4819, 88.734, 0.703},
};

// Splits "a,b,c" into trimmed, non-empty-checked tokens.
Result<std::vector<std::string>> split_list(std::string_view text, const char* option) {
  std::vector<std::string> out;
  size_t i = 0;
  while (i <= text.size()) {
    size_t j = text.find(',', i);
    if (j == std::string_view::npos) j = text.size();
    std::string token(text.substr(i, j - i));
    token.erase(0, token.find_first_not_of(" \t"));
    token.erase(token.find_last_not_of(" \t") + 1);
    if (token.empty())
      return make_error("%s: empty entry in '%s'", option, std::string(text).c_str());
    out.push_back(token);
    i = j + 1;
  }
  return out;
}

// A count such as "1093", "1e6" or "2.5e5": a non-negative whole number below 2^62.
std::optional<int64_t> parse_count(const std::string& s) {
  if (s.empty() || s.find_first_not_of("0123456789.eE+") != std::string::npos) return {};
  if (s.find_first_of(".eE") == std::string::npos) {
    if (s.size() > 18) return {};
    return std::stoll(s);
  }
  char* end = nullptr;
  const double x = std::strtod(s.c_str(), &end);
  if (end != s.c_str() + s.size() || !std::isfinite(x) || x < 0 || x > 4e18 ||
      x != std::floor(x))
    return {};
  return static_cast<int64_t>(x);
}

const char* step_flag_names(StepStatus s, std::string& out) {
  out.clear();
  auto add = [&out](const char* name) {
    if (!out.empty()) out += '|';
    out += name;
  };
  if (s & kStepNonFinite) add("nonfinite");
  if (s & kStepEnergyBlowUp) add("blowup");
  if (s & kStepInvertedElement) add("inverted");
  if (s & kStepCollapsingElement) add("collapsing");
  if (s & kStepClampedElement) add("clamped");
  if (s & kStepDtAboveCritical) add("dt_above_critical");
  if (out.empty()) out = "ok";
  return out.c_str();
}

// Blocks of bytes a timed step block should move: long enough to time (tens of ms), short
// enough to keep a sweep to minutes. Auto step counts derive from it and the mesh only.
constexpr double kCpuBlockBytes = 2e9;
constexpr double kGpuBlockBytes = 64e9;

// Threads the CPU backend runs: its description starts "cpu: N thread(s)" (backend_cpu.cpp);
// the requested count when that cannot be read.
int backend_thread_count(const Backend& backend, int requested) {
  const std::string d = backend.description();
  int n = 0;
  if (std::sscanf(d.c_str(), "cpu: %d thread", &n) == 1 && n > 0) return n;
  return setup_thread_count(requested);
}

std::string format_double(double x, const char* format = "%.6g") {
  char buf[64];
  std::snprintf(buf, sizeof buf, format, x);
  return buf;
}

}  // namespace

std::span<const SeedTable2Row> seed_table2() { return kSeedTable2; }

const char* constitutive_name(ConstitutiveModel model) {
  return model == ConstitutiveModel::kSvk      ? "svk"
         : model == ConstitutiveModel::kLinear ? "linear"
                                               : "neohookean";
}

const char* formulation_name(Formulation formulation) {
  switch (formulation) {
    case Formulation::kGradient:
      return "gradient";
    case Formulation::kTensorRebuilt:
      return "tensor_rebuilt";
    case Formulation::kTensorStored:
      return "tensor_stored";
  }
  return "unknown";
}

// ---------------------------------------------------------------------------------------------
// Arguments.

Result<std::vector<int64_t>> parse_vertex_list(std::string_view text, int64_t max_vertices) {
  std::vector<int64_t> out;
  if (text == "table2") {
    for (const SeedTable2Row& r : kSeedTable2) out.push_back(r.vertices);
    return out;
  }
  if (text == "sweep") {
    if (max_vertices < 128)
      return make_error("--vertices sweep: the largest size %lld is below 2^7 = 128",
                        static_cast<long long>(max_vertices));
    for (int64_t n = 128; n <= max_vertices; n *= 2) out.push_back(n);
    return out;
  }
  Result<std::vector<std::string>> tokens = split_list(text, "--vertices");
  if (!tokens) return tokens.error();
  for (const std::string& t : *tokens) {
    const std::optional<int64_t> n = parse_count(t);
    if (!n)
      return make_error("--vertices: '%s' is not a vertex count (give counts like 1093 or 1e6, "
                        "'table2' or 'sweep')",
                        t.c_str());
    if (*n < kMinBenchVertices || *n > max_vertices)
      return make_error("--vertices: %s is outside [%lld, %lld]", t.c_str(),
                        static_cast<long long>(kMinBenchVertices),
                        static_cast<long long>(max_vertices));
    out.push_back(*n);
  }
  return out;
}

Result<std::vector<BackendKind>> parse_bench_backends(std::string_view text) {
  if (text == "cpu") return std::vector<BackendKind>{BackendKind::kCpu};
  if (text == "cuda") return std::vector<BackendKind>{BackendKind::kCuda};
  if (text == "all") return std::vector<BackendKind>{BackendKind::kCpu, BackendKind::kCuda};
  return make_error("--backend: '%s' is not one of cpu, cuda, all", std::string(text).c_str());
}

Result<std::vector<ConstitutiveModel>> parse_bench_models(std::string_view text) {
  if (text == "all") return std::vector<ConstitutiveModel>{ConstitutiveModel::kSvk,
                                                           ConstitutiveModel::kLinear};
  Result<std::vector<std::string>> tokens = split_list(text, "--model");
  if (!tokens) return tokens.error();
  std::vector<ConstitutiveModel> out;
  for (const std::string& t : *tokens) {
    ConstitutiveModel m;
    if (t == "svk")
      m = ConstitutiveModel::kSvk;
    else if (t == "linear")
      m = ConstitutiveModel::kLinear;
    else
      return make_error("--model: '%s' is not one of svk, linear, all", t.c_str());
    if (std::find(out.begin(), out.end(), m) == out.end()) out.push_back(m);
  }
  return out;
}

Result<std::vector<Formulation>> parse_bench_formulations(std::string_view text) {
  if (text == "all")
    return std::vector<Formulation>{Formulation::kGradient, Formulation::kTensorRebuilt,
                                    Formulation::kTensorStored};
  Result<std::vector<std::string>> tokens = split_list(text, "--formulation");
  if (!tokens) return tokens.error();
  std::vector<Formulation> out;
  for (const std::string& t : *tokens) {
    Formulation f;
    if (t == "gradient")
      f = Formulation::kGradient;
    else if (t == "tensor_rebuilt")
      f = Formulation::kTensorRebuilt;
    else if (t == "tensor_stored")
      f = Formulation::kTensorStored;
    else
      return make_error(
          "--formulation: '%s' is not one of gradient, tensor_rebuilt, tensor_stored, all",
          t.c_str());
    if (std::find(out.begin(), out.end(), f) == out.end()) out.push_back(f);
  }
  return out;
}

Result<std::vector<int>> parse_thread_list(std::string_view text) {
  Result<std::vector<std::string>> tokens = split_list(text, "--threads");
  if (!tokens) return tokens.error();
  std::vector<int> out;
  for (const std::string& t : *tokens) {
    const std::optional<int64_t> n = parse_count(t);
    if (!n || *n > 1024)
      return make_error("--threads: '%s' is not a thread count in [0, 1024] (0: automatic)",
                        t.c_str());
    out.push_back(static_cast<int>(*n));
  }
  return out;
}

// ---------------------------------------------------------------------------------------------
// Pieces.

int auto_steps(BackendKind backend, ConstitutiveModel model, Formulation formulation,
               int64_t vertices, int64_t tets) {
  const bool gpu = backend == BackendKind::kCuda;
  const double block = gpu ? kGpuBlockBytes : kCpuBlockBytes;
  double cost = step_bytes(backend, model, Formulation::kGradient, BackendOptions{}.assembly,
                           vertices, tets);
  if (formulation != Formulation::kGradient)
    cost *= model == ConstitutiveModel::kSvk ? 40.0 : 3.0;
  const double steps = std::floor(block / std::max(cost, 1.0));
  return static_cast<int>(std::clamp(steps, gpu ? 10.0 : 1.0, 1000.0));
}

std::vector<Vec3d> bench_displacement(const Mesh& mesh) {
  const Aabb box = mesh_bounds(mesh);
  const Vec3d c = 0.5 * (box.lo + box.hi);
  const double height = box.hi.z - box.lo.z;
  const double r = 0.5 * height;
  const double z_fix = box.lo.z + 0.05 * height;
  const Vec3d pole{c.x, c.y, box.hi.z};
  const double width = 0.3 * r;
  std::vector<Vec3d> u(mesh.vertex_count(), Vec3d{0, 0, 0});
  for (size_t v = 0; v < u.size(); ++v) {
    const Vec3d x = mesh.rest_positions[v];
    // Weight 0 on the held bottom cap, 1 at the top: the held vertices start at rest.
    const double w = std::max(0.0, (x.z - z_fix) / (box.hi.z - z_fix));
    // Non-uniform stretch: the strain grows with height (2 %, -1 %, 1.5 %).
    Vec3d d{0.01 * w * (x.x - c.x), -0.005 * w * (x.y - c.y), 0.0075 * w * (x.z - z_fix)};
    // Indentation at the top pole (the needle): 4 % of the radius, Gaussian of 0.3 radii.
    const Vec3d q = x - pole;
    d.z -= 0.02 * r * w * std::exp(-0.5 * dot(q, q) / (width * width));
    u[v] = d;
  }
  return u;
}

std::vector<int32_t> bench_fixed_vertices(const Mesh& mesh) {
  const Aabb box = mesh_bounds(mesh);
  const double z_fix = box.lo.z + 0.05 * (box.hi.z - box.lo.z);
  std::vector<int32_t> fixed;
  for (size_t v = 0; v < mesh.vertex_count(); ++v)
    if (mesh.rest_positions[v].z <= z_fix) fixed.push_back(static_cast<int32_t>(v));
  return fixed;
}

double step_bytes(BackendKind backend, ConstitutiveModel model, Formulation formulation,
                  Assembly assembly, int64_t vertices, int64_t tets) {
  const double nv = static_cast<double>(vertices), nt = static_cast<double>(tets);
  const bool svk = model == ConstitutiveModel::kSvk;
  double per_tet = 0, per_vertex = 0;
  if (backend == BackendKind::kCuda) {
    // Device layout (kernels/device_layout.h): indices and packed shape, 56 bytes; stored
    // tensors in float32, built on the device.
    per_tet = 56;
    if (formulation == Formulation::kTensorStored)
      per_tet += 4.0 * (svk ? kSvkTensorSize : kTensorBSize);
    // u_n, u_{n-1} read and u_{n+1} written in float64, two float update coefficients.
    per_vertex = 3 * 24 + 8;
    // (A default branch, not one case per enumerator: the GPU engineer adds and retires
    // assembly variants; the scatter ones share the atomic one's traffic.)
    switch (assembly) {
      case Assembly::kScatterFixed:  // 3 x int64 accumulated, read, cleared; float force written
        per_vertex += 4 * 24 + 16;
        break;
      case Assembly::kGatherRecompute:  // gather lists; force written
        per_tet += 16;
        per_vertex += 4 + 16;
        break;
      case Assembly::kGatherStored:  // corner forces written and read, gather lists; force
        per_tet += 64 + 64 + 16;
        per_vertex += 4 + 16;
        break;
      default:  // float4 force: accumulated (read + write), read by the update, cleared
        per_vertex += 4 * 16;
        break;
    }
    return per_tet * nt + per_vertex * nv;
  }
  // CPU, element pass (engine/fem/forces_cpu.cpp): corner displacement offsets (16) and assembly
  // codes (16) read, displacements gathered (24 per vertex), each vertex's force block (32)
  // accumulated in cache and written back once (AssemblyPlan; the late slots, a few per cent of
  // the corners, are not counted).
  per_tet = 16 + 16;
  per_vertex = 24 + 32;
  switch (formulation) {
    case Formulation::kGradient:  // Model::cpu_tet_batches: 12 doubles per tetrahedron
      per_tet += 12 * 8;
      break;
    case Formulation::kTensorRebuilt:  // TetShape (13 doubles) and the material index
      per_tet += 13 * 8 + 4;
      break;
    case Formulation::kTensorStored:  // the tensors, and the shape for the health checks
      per_tet += 8.0 * (svk ? kSvkTensorSize : kTensorBSize) + 13 * 8;
      break;
  }
  // Vertex pass (engine/sim/integrator.cpp): force block (32) and late offsets (4), u, u_prev,
  // external force, update coefficients, constraint kind and mass read; force and u_next
  // written.
  per_vertex += 32 + 4 + 24 + 24 + 24 + 24 + 1 + 8 + 24 + 24;
  return per_tet * nt + per_vertex * nv;
}

double estimate_row_bytes(BackendKind backend, ConstitutiveModel model, Formulation formulation,
                          int64_t vertices, int64_t tets) {
  const double nv = static_cast<double>(vertices), nt = static_cast<double>(tets);
  const bool svk = model == ConstitutiveModel::kSvk;
  // The mesh (kept for the size's rows): positions, tetrahedra, regions.
  double bytes = 24 * nv + 20 * nt;
  // The model: positions, masses, coefficients, flags, build temporaries; tetrahedra,
  // adjacency, corner offsets, materials, shapes, the CPU batches.
  bytes += 150 * nv + (16 + 20 + 16 + 4 + 104 + 96) * nt;
  const bool gpu = backend == BackendKind::kCuda;
  if (formulation == Formulation::kTensorStored && !gpu)
    bytes += 8.0 * (svk ? kSvkTensorSize : kTensorBSize) * nt;
  // Two states (the benchmark's and the backend's): five vertex arrays and the force blocks;
  // assembly codes, late slots (~10 % of the corners) and the plan's build temporaries.
  bytes += 2 * (153 * nv + 48 * nt);
  // GPU: the host copy of the device layout while it is built and uploaded.
  if (gpu) bytes += 60 * nv + 120 * nt;
  return bytes;
}

uint64_t displacement_hash(std::span<const Vec3d> u) {
  uint64_t h = 14695981039346656037ull;
  for (const Vec3d& p : u)
    for (int i = 0; i < 3; ++i) {
      const uint64_t bits = std::bit_cast<uint64_t>(p[i]);
      for (int b = 0; b < 8; ++b) {
        h ^= (bits >> (8 * b)) & 0xffu;
        h *= 1099511628211ull;
      }
    }
  return h;
}

double quantile(std::vector<double> x, double q) {
  if (x.empty()) return 0;
  std::sort(x.begin(), x.end());
  const double pos = std::clamp(q, 0.0, 1.0) * static_cast<double>(x.size() - 1);
  return x[static_cast<size_t>(std::lround(pos))];
}

double measure_cpu_copy_bandwidth(size_t bytes, int threads, int repeats) {
  threads = setup_thread_count(threads);
  repeats = std::max(repeats, 1);
  bytes = std::max<size_t>(bytes, size_t{1} << 20);
  std::vector<unsigned char> src(bytes), dst(bytes);
  // Touch every page (and give the source non-zero contents) before timing.
  for (size_t i = 0; i < bytes; i += 4096) src[i] = static_cast<unsigned char>(i >> 12);
  std::memset(dst.data(), 0, bytes);
  auto copy_once = [&]() {
    if (threads == 1) {
      std::memcpy(dst.data(), src.data(), bytes);
      return;
    }
    std::vector<std::thread> pool;
    pool.reserve(static_cast<size_t>(threads));
    for (int k = 0; k < threads; ++k)
      pool.emplace_back([&, k] {
        const size_t b = bytes * static_cast<size_t>(k) / static_cast<size_t>(threads);
        const size_t e = bytes * static_cast<size_t>(k + 1) / static_cast<size_t>(threads);
        std::memcpy(dst.data() + b, src.data() + b, e - b);
      });
    for (std::thread& t : pool) t.join();
  };
  copy_once();
  std::vector<double> rates;
  for (int r = 0; r < repeats; ++r) {
    const auto t0 = Clock::now();
    copy_once();
    const double s = std::chrono::duration<double>(Clock::now() - t0).count();
    rates.push_back(2.0 * static_cast<double>(bytes) / s * 1e-9);
  }
  // Keep the copy from being optimised away.
  volatile unsigned char sink = dst[bytes / 2];
  (void)sink;
  return quantile(rates, 0.5);
}

int64_t memory_fit_vertices(const ScalingBenchConfig& config, double memory_bytes) {
  if (memory_bytes <= 0) memory_bytes = 0.75 * available_memory_bytes();
  auto cheapest = [&config](int64_t n) {
    double best = std::numeric_limits<double>::infinity();
    const int64_t nt = static_cast<int64_t>(kBenchTetsPerVertex * static_cast<double>(n));
    for (BackendKind b : config.backends)
      for (ConstitutiveModel m : config.models)
        for (Formulation f : config.formulations)
          best = std::min(best, estimate_row_bytes(b, m, f, n, nt));
    return best;
  };
  int64_t n = 128;
  // 2^28 vertices: beyond the 32-bit tetrahedron indices of the layouts anyway.
  while (n < (int64_t{1} << 28) && cheapest(2 * n) <= memory_bytes) n *= 2;
  return n;
}

double available_memory_bytes() {
  std::ifstream f("/proc/meminfo");
  std::string key;
  double value = 0;
  std::string unit;
  while (f >> key >> value) {
    std::getline(f, unit);
    if (key == "MemAvailable:") return value * 1024.0;
  }
  return 0;
}

MachineInfo local_machine_info() {
  MachineInfo m;
  std::ifstream f("/proc/cpuinfo");
  std::string line;
  while (std::getline(f, line)) {
    if (line.rfind("model name", 0) == 0) {
      const size_t colon = line.find(':');
      if (colon != std::string::npos) {
        m.cpu_model = line.substr(colon + 1);
        m.cpu_model.erase(0, m.cpu_model.find_first_not_of(" \t"));
      }
      break;
    }
  }
  if (m.cpu_model.empty()) m.cpu_model = "unknown CPU";
  m.hardware_threads = setup_thread_count(0);
  char date[32];
  const std::time_t now = std::time(nullptr);
  std::strftime(date, sizeof date, "%Y-%m-%d", std::gmtime(&now));
  m.date = date;
  m.zona_version = ZONA_VERSION;
  return m;
}

// ---------------------------------------------------------------------------------------------
// The run.

namespace {

// One planned row.
struct Job {
  BackendKind backend;
  ConstitutiveModel model;
  Formulation formulation;
  int threads;  // requested: > 0 fixed, 0 the CPU backend's automatic choice
};

std::string job_label(const Job& j, int64_t target) {
  return std::string(backend_kind_name(j.backend)) + " " + constitutive_name(j.model) + " " +
         formulation_name(j.formulation) + " " +
         (j.threads > 0 ? std::to_string(j.threads) + "t " : std::string("auto ")) +
         std::to_string(target);
}

}  // namespace

Result<ScalingBenchResult> run_scaling_bench(const ScalingBenchConfig& config,
                                             const ScalingBenchHooks& hooks,
                                             const MachineInfo& machine) {
  if (!hooks.make_backend) return make_error("scaling bench: no backend factory given");
  if (config.vertices.empty()) return make_error("scaling bench: no sizes given (--vertices)");
  if (config.backends.empty() || config.models.empty() || config.formulations.empty() ||
      config.threads.empty())
    return make_error("scaling bench: empty backend, model, formulation or thread list");
  if (config.repeats < 1) return make_error("--repeats: must be >= 1, got %d", config.repeats);
  if (config.steps < 0) return make_error("--steps: must be >= 0 (0: automatic), got %d",
                                          config.steps);
  auto notice = [&hooks](const std::string& text) {
    if (hooks.notice) hooks.notice(text);
  };

  ScalingBenchResult result;
  result.machine = machine;

  // Backends: probe each once so that a missing GPU is one notice (or one error), not a row
  // of failures; then the GPU's copy bandwidth.
  std::vector<BackendKind> backends;
  for (BackendKind kind : config.backends) {
    if (std::find(backends.begin(), backends.end(), kind) != backends.end()) continue;
    BackendOptions probe_options;
    probe_options.cpu_threads = 1;
    Result<std::unique_ptr<Backend>> probe = hooks.make_backend(kind, probe_options);
    if (!probe) {
      if (!config.skip_unavailable_backends)
        return make_error("%s: %s", backend_kind_name(kind), probe.error().message.c_str());
      notice(std::string(backend_kind_name(kind)) + ": " + probe.error().message +
             "; skipping its rows");
      continue;
    }
    backends.push_back(kind);
  }
  if (backends.empty()) return make_error("scaling bench: no usable backend");
  double gpu_gbps = 0;
  if (std::find(backends.begin(), backends.end(), BackendKind::kCuda) != backends.end() &&
      hooks.device_copy_bandwidth) {
    Result<double> bw = hooks.device_copy_bandwidth();
    if (bw)
      gpu_gbps = *bw;
    else
      notice("cuda: copy bandwidth not measured (" + bw.error().message + "): floor_ms is 0");
  }
  result.machine.gpu_copy_gb_per_s = gpu_gbps;
  if (gpu_gbps <= 0 && std::find(backends.begin(), backends.end(), BackendKind::kCuda) ==
                           backends.end())
    result.machine.gpu_name.clear();

  // CPU copy bandwidth per thread count in the list.
  // The automatic choice (0) may pick any count from 1 to the hardware's: measure both ends.
  std::vector<int> threads, copy_threads;
  for (int t : config.threads) {
    if (std::find(threads.begin(), threads.end(), t) == threads.end()) threads.push_back(t);
    for (int r : t > 0 ? std::vector<int>{t} : std::vector<int>{1, setup_thread_count(0)})
      if (std::find(copy_threads.begin(), copy_threads.end(), r) == copy_threads.end())
        copy_threads.push_back(r);
  }
  std::sort(copy_threads.begin(), copy_threads.end());
  if (std::find(backends.begin(), backends.end(), BackendKind::kCpu) != backends.end())
    for (int t : copy_threads)
      result.cpu_copy_gb_per_s.emplace_back(t, measure_cpu_copy_bandwidth(config.copy_bytes, t));
  // Copy bandwidth with t threads: the measurement at the largest count not above t.
  auto cpu_gbps = [&result](int t) {
    double g = 0;
    for (const auto& [n, rate] : result.cpu_copy_gb_per_s)
      if (n <= t || g == 0) g = rate;
    return g;
  };

  // The plan: the GPU rows once per model and formulation (host threads: the first entry).
  std::vector<Job> jobs;
  for (BackendKind b : backends)
    for (ConstitutiveModel m : config.models)
      for (Formulation f : config.formulations) {
        if (b == BackendKind::kCuda) {
          jobs.push_back({b, m, f, threads.front()});
          continue;
        }
        for (int t : threads) jobs.push_back({b, m, f, t});
      }
  if (hooks.started) hooks.started(result);
  const int row_count = static_cast<int>(jobs.size() * config.vertices.size());
  const double memory_limit = config.memory_limit_bytes > 0
                                  ? config.memory_limit_bytes
                                  : 0.75 * available_memory_bytes();
  ScalingProgress progress;
  progress.row_count = row_count;
  auto report = [&](const std::string& label, const char* phase) {
    progress.label = label;
    progress.phase = phase;
    if (hooks.progress) hooks.progress(progress);
  };

  for (int64_t target : config.vertices) {
    // Skip the mesh too when no row of this size can fit.
    const int64_t est_tets = static_cast<int64_t>(kBenchTetsPerVertex * static_cast<double>(target));
    bool any_fits = memory_limit <= 0;
    for (const Job& j : jobs)
      any_fits = any_fits || estimate_row_bytes(j.backend, j.model, j.formulation, target,
                                                est_tets) <= memory_limit;
    if (!any_fits) {
      notice("size " + std::to_string(target) + ": no row fits in " +
             format_double(memory_limit * 1e-9, "%.1f") + " GB of memory; skipped");
      progress.row += static_cast<int>(jobs.size());
      continue;
    }

    report("mesh " + std::to_string(target), "mesh");
    const auto m0 = Clock::now();
    Result<Mesh> mesh = generate_cell_mesh(table2_spec(target));
    if (!mesh)
      return make_error("mesh of %lld vertices: %s", static_cast<long long>(target),
                        mesh.error().message.c_str());
    const double mesh_ms = ms_since(m0);
    const int64_t nv = static_cast<int64_t>(mesh->vertex_count());
    const int64_t nt = static_cast<int64_t>(mesh->tet_count());
    const std::vector<Vec3d> u0 = bench_displacement(*mesh);
    const std::vector<int32_t> fixed = bench_fixed_vertices(*mesh);

    for (const Job& job : jobs) {
      const std::string label = job_label(job, target);
      const double need = estimate_row_bytes(job.backend, job.model, job.formulation, nv, nt);
      if (memory_limit > 0 && need > memory_limit) {
        notice(label + ": needs about " + format_double(need * 1e-9, "%.1f") + " GB, " +
               format_double(memory_limit * 1e-9, "%.1f") + " GB usable; skipped");
        ++progress.row;
        continue;
      }
      const bool gpu = job.backend == BackendKind::kCuda;

      // Precompute: build_model timed by the model itself, median over a few builds. The GPU
      // rows build the host model in the gradient form (the device builds its own tensors:
      // upload_ms), so that tensor_stored does not first fill gigabytes of host tensors.
      report(label, "precompute");
      ModelDesc desc;
      desc.constitutive = job.model;
      desc.formulation = gpu ? Formulation::kGradient : job.formulation;
      desc.fixed_vertices = fixed;
      // Half the critical step: SVK stiffens under the loaded state's stretch; the step's cost
      // does not depend on dt.
      desc.dt_safety = 0.5;
      desc.precompute_threads = setup_thread_count(job.threads);
      if (!gpu && job.formulation == Formulation::kGradient)
        desc.element_precision = config.element_precision;
      std::optional<Model> model;
      std::vector<double> precompute, tensor_precompute;
      double build_total = 0;
      for (int k = 0; k < std::max(1, config.precompute_repeats); ++k) {
        model.reset();
        Result<Model> built = build_model(*mesh, desc);
        if (!built) return make_error("%s: model: %s", label.c_str(), built.error().message.c_str());
        model.emplace(std::move(built).value());
        precompute.push_back(model->precompute_seconds * 1e3);
        tensor_precompute.push_back(model->tensor_precompute_seconds * 1e3);
        build_total += model->precompute_seconds;
        if (build_total > 2.0) break;  // large meshes: a few builds are enough
      }

      // The loaded state: the deformed field, at rest.
      State state = make_state(*model, 1);
      set_displacement(state, u0);

      BackendOptions options;
      options.cpu_threads = job.threads;
      options.assembly = config.assembly;
      if (gpu) options.formulation = static_cast<int32_t>(job.formulation);
      Result<std::unique_ptr<Backend>> made = hooks.make_backend(job.backend, options);
      if (!made) return make_error("%s: %s", label.c_str(), made.error().message.c_str());
      Backend& backend = **made;
      report(label, "upload");
      const auto u_start = Clock::now();
      if (Status s = backend.upload(*model, state); !s) {
        notice(label + ": upload failed (" + s.error().message + "); skipped");
        ++progress.row;
        continue;
      }
      const double upload_ms = ms_since(u_start);

      // Timed blocks after one warm-up block.
      ScalingRow row;
      row.bytes_per_step =
          step_bytes(job.backend, job.model, job.formulation, config.assembly, nv, nt);
      const int steps = config.steps > 0
                            ? config.steps
                            : auto_steps(job.backend, job.model, job.formulation, nv, nt);
      report(label, "steps");
      StepStatus status = kStepOk;
      bool stopped = false;
      const StepReport warm = backend.step(steps);
      status |= warm.status;
      stopped = warm.steps < steps;
      std::vector<double> step_ms, wall_ms;
      for (int r = 0; r < config.repeats && !stopped; ++r) {
        const auto w0 = Clock::now();
        const StepReport rep = backend.step(steps);
        wall_ms.push_back(ms_since(w0));
        status |= rep.status;
        if (rep.steps < steps) stopped = true;
        if (rep.steps > 0) step_ms.push_back(rep.device_ms / static_cast<double>(rep.steps));
      }
      if (Status s = backend.download(state); !s)
        return make_error("%s: download: %s", label.c_str(), s.error().message.c_str());

      row.backend = backend_kind_name(job.backend);
      row.model = constitutive_name(job.model);
      row.formulation = formulation_name(job.formulation);
      row.threads = gpu ? setup_thread_count(job.threads) : backend_thread_count(backend, job.threads);
      row.threads_requested = job.threads;
      row.target_vertices = target;
      row.vertices = nv;
      row.tets = nt;
      row.mesh_ms = mesh_ms;
      row.precompute_ms = quantile(precompute, 0.5);
      row.tensor_precompute_ms = quantile(tensor_precompute, 0.5);
      row.upload_ms = upload_ms;
      row.steps = steps;
      row.repeats = static_cast<int>(step_ms.size());
      row.step_ms_median = quantile(step_ms, 0.5);
      row.step_ms_p10 = quantile(step_ms, 0.1);
      row.step_ms_p90 = quantile(step_ms, 0.9);
      const double wall = quantile(wall_ms, 0.5);
      row.steps_per_s = wall > 0 ? 1e3 * steps / wall : 0;
      row.gb_per_s =
          row.step_ms_median > 0 ? row.bytes_per_step / (row.step_ms_median * 1e-3) * 1e-9 : 0;
      row.copy_gb_per_s = gpu ? gpu_gbps : cpu_gbps(job.threads);
      row.floor_ms = row.copy_gb_per_s > 0 ? row.bytes_per_step / (row.copy_gb_per_s * 1e9) * 1e3
                                           : 0;
      row.floor_ratio = row.floor_ms > 0 ? row.step_ms_median / row.floor_ms : 0;
      std::string flags;
      row.status = step_flag_names(status, flags);
      if (stopped) row.status += "|stopped";
      row.state_hash = displacement_hash(state.u);
      row.precision =
          gpu || model->element_precision == ElementPrecision::kFloat32 ? "float32" : "float64";
      ++progress.row;
      report(label, "done");
      if (hooks.row) hooks.row(row);
      result.rows.push_back(std::move(row));
    }
  }
  return result;
}

// ---------------------------------------------------------------------------------------------
// CSV.

std::string scaling_csv_header() {
  return "backend,model,formulation,threads,threads_requested,target_vertices,vertices,tets,mesh_ms,precompute_ms,"
         "tensor_precompute_ms,upload_ms,steps,repeats,step_ms_median,step_ms_p10,step_ms_p90,"
         "steps_per_s,bytes_per_step,gb_per_s,copy_gb_per_s,floor_ms,floor_ratio,status,"
         "state_hash,precision";
}

std::string scaling_csv_comments(const ScalingBenchResult& result,
                                 const ScalingBenchConfig& config) {
  const MachineInfo& m = result.machine;
  std::ostringstream out;
  out << "# zona bench: vertices-versus-time scaling (Ladjal et al. Table II), zona "
      << m.zona_version << ", commit " << (m.commit.empty() ? "unknown" : m.commit) << "\n";
  out << "# date: " << m.date << " (UTC)\n";
  if (!m.command.empty()) out << "# command: " << m.command << "\n";
  out << "# cpu: " << m.cpu_model << ", " << m.hardware_threads << " hardware threads"
      << "; float64 element pass: " << (cpu_element_fma() ? "fused" : "unfused") << ", "
      << cpu_simd_bits() << "-bit packs, " << cpu_simd_registers() << " vector registers\n";
  out << "# gpu: " << (m.gpu_name.empty() ? "none" : m.gpu_name);
  if (m.gpu_copy_gb_per_s > 0)
    out << ", device-to-device copy " << format_double(m.gpu_copy_gb_per_s, "%.0f")
        << " GB/s (read + write)";
  out << "\n";
  if (!result.cpu_copy_gb_per_s.empty()) {
    out << "# cpu copy bandwidth (memcpy of " << (config.copy_bytes >> 20)
        << " MiB, read + write, median):";
    for (const auto& [t, g] : result.cpu_copy_gb_per_s)
      out << " " << t << " thread(s) " << format_double(g, "%.2f") << " GB/s;";
    out << "\n";
  }
  std::ifstream load("/proc/loadavg");
  std::string l1, l5, l15;
  if (load >> l1 >> l5 >> l15)
    out << "# load average (1, 5, 15 min) when this header was written: " << l1 << " " << l5 << " " << l15 << "\n";
  out << "# meshes: table2_spec(target_vertices), a 56 um ball refined at the puncture pole; "
         "loaded state: bench_displacement (indentation + stretch, strains up to ~4 %), bottom "
         "5 % held; dt = 0.5 dt_critical; gpu assembly "
      << assembly_name(config.assembly) << "\n";
  out << "# step_ms: per step, median/p10/p90 over `repeats` blocks of `steps` steps after one "
         "warm-up block (StepReport::device_ms: CUDA events on the GPU, wall on the CPU); "
         "steps_per_s from the median block wall time\n";
  out << "# precompute_ms: build_model, median of up to 5 builds (cpu tensor_stored includes "
         "tensor_precompute_ms; gpu rows build the gradient form on the host and their tensors "
         "on the device, in upload_ms)\n";
  out << "# bytes_per_step: arrays one step streams, gathered vertex data counted once; "
         "floor_ms = bytes_per_step / copy_gb_per_s; state_hash: FNV-1a of the float64 "
         "displacements after (1 + repeats) x steps steps\n";
  return out.str();
}

std::string scaling_csv_row(const ScalingRow& r) {
  std::ostringstream out;
  char hash[20];
  std::snprintf(hash, sizeof hash, "%016llx", static_cast<unsigned long long>(r.state_hash));
  out << r.backend << ',' << r.model << ',' << r.formulation << ',' << r.threads << ','
      << r.threads_requested << ','
      << r.target_vertices << ',' << r.vertices << ',' << r.tets << ','
      << format_double(r.mesh_ms, "%.1f") << ',' << format_double(r.precompute_ms) << ','
      << format_double(r.tensor_precompute_ms) << ',' << format_double(r.upload_ms) << ','
      << r.steps << ',' << r.repeats << ',' << format_double(r.step_ms_median) << ','
      << format_double(r.step_ms_p10) << ',' << format_double(r.step_ms_p90) << ','
      << format_double(r.steps_per_s) << ',' << format_double(r.bytes_per_step, "%.0f") << ','
      << format_double(r.gb_per_s, "%.4g") << ',' << format_double(r.copy_gb_per_s, "%.4g") << ','
      << format_double(r.floor_ms) << ',' << format_double(r.floor_ratio, "%.4g") << ','
      << r.status << ',' << hash << ',' << r.precision;
  return out.str();
}

}  // namespace zona
