// GPU step benchmark: the device-to-device copy bandwidth first (the roofline's ceiling), then
// the median time of one explicit step for each kernel variant (formulation x assembly x
// gather precision) on cell meshes of 1e4..1e7 vertices, with the bytes each variant must move,
// the achieved bandwidth, the floor and the ratio to it. CSV on stdout (and --out), a summary
// table last. Runs through the Backend interface, so the numbers are what the product gets.
//
//   gpu_step_bench [--sizes 10000,100000,1000000] [--variants all|name,name]
//                  [--substeps 100] [--repeats 7] [--out FILE.csv] [--shuffle 1]
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <ctime>
#include <memory>
#include <string>
#include <vector>

#include "engine/sim/backend.h"
#include "engine/mesh/mesh_generate.h"
#include "engine/fem/model.h"
#include "engine/fem/state.h"
#include "kernels/backend_info.h"
#include "kernels/cuda_backend.h"
#include "kernels/cuda_probe.h"
#include "kernels/device_layout.h"

namespace zona {
namespace {

struct Variant {
  const char* name;
  ConstitutiveModel law;
  Formulation form;
  Assembly assembly;
  bool reorder;
  bool programmatic_launch;
  bool warp_aggregate;
};

// The variants; the first is the default configuration.
const Variant kVariants[] = {
    {"svk_gradient_atomic", ConstitutiveModel::kSvk, Formulation::kGradient,
     Assembly::kScatterAtomic, true, true, true},
    {"svk_gradient_atomic_plain", ConstitutiveModel::kSvk, Formulation::kGradient,
     Assembly::kScatterAtomic, true, true, false},
    {"svk_gradient_fixed_point", ConstitutiveModel::kSvk, Formulation::kGradient,
     Assembly::kScatterFixed, true, true, true},
    {"svk_gradient_gather_stored", ConstitutiveModel::kSvk, Formulation::kGradient,
     Assembly::kGatherStored, true, true, true},
    {"svk_gradient_gather_recompute", ConstitutiveModel::kSvk, Formulation::kGradient,
     Assembly::kGatherRecompute, true, true, true},
    {"svk_gradient_atomic_nopdl", ConstitutiveModel::kSvk, Formulation::kGradient,
     Assembly::kScatterAtomic, true, false, true},
    {"svk_gradient_atomic_noreorder", ConstitutiveModel::kSvk, Formulation::kGradient,
     Assembly::kScatterAtomic, false, true, true},
    {"svk_rebuilt_atomic", ConstitutiveModel::kSvk, Formulation::kTensorRebuilt,
     Assembly::kScatterAtomic, true, true, true},
    {"svk_stored_atomic", ConstitutiveModel::kSvk, Formulation::kTensorStored,
     Assembly::kScatterAtomic, true, true, true},
    {"linear_gradient_atomic", ConstitutiveModel::kLinear, Formulation::kGradient,
     Assembly::kScatterAtomic, true, true, true},
};

// Bytes one step must move through device memory for a variant, counting each array once
// (perfect caching of gathered vertices): the variant's own floor. Per tetrahedron and per
// vertex.
struct VariantBytes {
  double per_tet = 0, per_vertex = 0;
  double total(double nv, double nt) const { return per_tet * nt + per_vertex * nv; }
};

VariantBytes variant_bytes(const Variant& v) {
  VariantBytes b;
  b.per_tet = static_cast<double>(DeviceLayout::kTetBytes);  // indices + packed shape
  if (v.form == Formulation::kTensorStored)
    b.per_tet += 4.0 * (v.law == ConstitutiveModel::kSvk ? kSvkTensorSize : kTensorBSize);
  // Vertex arrays: u_n and u_{n-1} read, u_{n+1} written (float64), coefficients read.
  b.per_vertex = 3 * 24 + 8;
  switch (v.assembly) {
    case Assembly::kScatterAtomic:  // accumulate (read + write), read by the update, cleared
      b.per_vertex += 16 + 16 + 16 + 16;
      break;
    case Assembly::kScatterFixed:  // 3 x int64 accumulated, read, cleared; float force written
      b.per_vertex += 24 + 24 + 24 + 24 + 16;
      break;
    case Assembly::kGatherRecompute:  // gather lists; force written
      b.per_tet += 16;
      b.per_vertex += 4 + 16;
      break;
    case Assembly::kGatherStored:  // corner forces written and read, gather lists; force
      b.per_tet += 64 + 64 + 16;
      b.per_vertex += 4 + 16;
      break;
  }
  return b;
}

// The step's floor for every variant: the packed tetrahedra (56 bytes) plus the three
// displacement arrays and the coefficients (80 bytes per vertex), issue 4.
double floor_bytes(double nv, double nt) {
  return static_cast<double>(DeviceLayout::kTetBytes) * nt + 80.0 * nv;
}

uint64_t fnv1a(const void* data, size_t n, uint64_t h = 1469598103934665603ull) {
  const unsigned char* p = static_cast<const unsigned char*>(data);
  for (size_t i = 0; i < n; ++i) h = (h ^ p[i]) * 1099511628211ull;
  return h;
}

double percentile(std::vector<double> x, double q) {
  if (x.empty()) return 0;
  std::sort(x.begin(), x.end());
  return x[static_cast<size_t>(q * static_cast<double>(x.size() - 1) + 0.5)];
}

std::vector<int64_t> parse_sizes(const std::string& s) {
  std::vector<int64_t> out;
  size_t i = 0;
  while (i < s.size()) {
    size_t j = s.find(',', i);
    if (j == std::string::npos) j = s.size();
    out.push_back(std::stoll(s.substr(i, j - i)));
    i = j + 1;
  }
  return out;
}

bool wanted(const std::string& list, const char* name) {
  if (list == "all") return true;
  return ("," + list + ",").find(std::string(",") + name + ",") != std::string::npos;
}

int run(int argc, char** argv) {
  std::string sizes_arg = "10000,100000,1000000", variants_arg = "all", out_path;
  int substeps = 100, repeats = 7;
  bool shuffle = false;
  for (int i = 1; i + 1 < argc; i += 2) {
    const std::string k = argv[i], v = argv[i + 1];
    if (k == "--sizes")
      sizes_arg = v;
    else if (k == "--variants")
      variants_arg = v;
    else if (k == "--substeps")
      substeps = std::max(1, std::stoi(v));
    else if (k == "--repeats")
      repeats = std::max(1, std::stoi(v));
    else if (k == "--out")
      out_path = v;
    else if (k == "--shuffle")
      shuffle = v == "1";
    else {
      std::fprintf(stderr, "gpu_step_bench: unknown option %s\n", k.c_str());
      return 2;
    }
  }
  const BuildInfo info = build_info();
  if (info.devices.empty()) {
    std::fprintf(stderr, "gpu_step_bench: %s\n", info.device_notice.c_str());
    return 1;
  }
  const std::string device = info.devices[0].name;
  char date[32];
  const std::time_t now = std::time(nullptr);
  std::strftime(date, sizeof date, "%Y-%m-%d", std::gmtime(&now));

  // 1. The ceiling: a 2 GiB device-to-device copy.
  Result<CopyBandwidth> bw = measure_copy_bandwidth(size_t{1} << 31, 20);
  if (!bw) {
    std::fprintf(stderr, "gpu_step_bench: %s\n", bw.error().message.c_str());
    return 1;
  }
  const double gbps = bw->gb_per_s;
  std::printf("# device: %s, date %s\n", device.c_str(), date);
  std::printf(
      "# copy bandwidth (read+write): median %.0f GB/s (min %.0f, max %.0f) over 20 "
      "copies of %.1f GB\n",
      gbps, bw->min_gb_per_s, bw->max_gb_per_s, static_cast<double>(bw->bytes) * 1e-9);

  FILE* csv = out_path.empty() ? nullptr : std::fopen(out_path.c_str(), "w");
  const char* header =
      "device,date,vertices,tets,variant,substeps,ms_per_step_median,ms_per_step_p10,"
      "ms_per_step_p90,steps_per_s_wall,bytes_per_step,bytes_per_tet,achieved_GBps,"
      "copy_GBps,floor_ms,ratio_to_floor,variant_floor_ms,status,state_hash\n";
  std::printf("%s", header);
  if (csv) std::fprintf(csv, "%s", header);
  struct Row {
    int64_t nv;
    std::string variant;
    double ms, floor_ms, ratio, steps_per_s;
  };
  std::vector<Row> rows;

  for (int64_t target : parse_sizes(sizes_arg)) {
    // 2. The mesh: the product's cell generator at this size, zona shell and cytoplasm.
    const auto t0 = std::chrono::steady_clock::now();
    CellMeshSpec spec;
    spec.target_vertices = target;
    spec.zona_thickness = 4e-6;
    Result<Mesh> mesh = generate_cell_mesh(spec);
    if (!mesh) {
      std::fprintf(stderr, "gpu_step_bench: mesh %lld: %s\n", static_cast<long long>(target),
                   mesh.error().message.c_str());
      continue;
    }
    if (shuffle) {
      // A mesh numbered at random, as files from other meshers may come: what the device
      // layout's reordering is for.
      std::vector<int32_t> perm(mesh->vertex_count());
      for (size_t v = 0; v < perm.size(); ++v) perm[v] = static_cast<int32_t>(v);
      uint64_t x = 88172645463325252ull;
      for (size_t v = perm.size(); v > 1; --v) {
        x ^= x << 13, x ^= x >> 7, x ^= x << 17;
        std::swap(perm[v - 1], perm[x % v]);
      }
      std::vector<Vec3d> pos(perm.size());
      for (size_t v = 0; v < perm.size(); ++v) pos[perm[v]] = mesh->rest_positions[v];
      mesh->rest_positions = std::move(pos);
      for (Tet& t : mesh->tets)
        for (int32_t& v : t) v = perm[v];
    }
    const auto t1 = std::chrono::steady_clock::now();
    const double nv = static_cast<double>(mesh->vertex_count());
    const double nt = static_cast<double>(mesh->tet_count());
    std::fprintf(stderr, "# mesh %lld: %zu vertices, %zu tets, %.1f s\n",
                 static_cast<long long>(target), mesh->vertex_count(), mesh->tet_count(),
                 std::chrono::duration<double>(t1 - t0).count());
    // Bottom cap fixed, a patch at the north pole pushed in (the needle).
    const double r = 0.5 * spec.diameter;
    std::vector<int32_t> fixed, patch;
    for (size_t v = 0; v < mesh->vertex_count(); ++v) {
      const double z = mesh->rest_positions[v].z;
      if (z < -0.9 * r) fixed.push_back(static_cast<int32_t>(v));
      if (z > 0.97 * r) patch.push_back(static_cast<int32_t>(v));
    }

    // One model per constitutive law (stored tensors are built by the device from it).
    // The states are made once too: at 1e7 vertices a State holds gigabytes of CPU scratch.
    std::unique_ptr<Model> models[2];
    std::unique_ptr<State> states[2], outs[2];
    auto model_for = [&](ConstitutiveModel law) -> const Model* {
      const int i = law == ConstitutiveModel::kSvk ? 0 : 1;
      std::unique_ptr<Model>& slot = models[i];
      if (slot) return slot.get();
      ModelDesc desc;
      desc.material.young = 2e3;
      desc.material.poisson = 0.45;
      desc.material.damping = 100;
      RegionMaterial zona;
      zona.region = kRegionZona;
      zona.material.young = 17.9e3;
      zona.material.poisson = 0.49;
      zona.material.damping = 100;
      desc.region_materials.push_back(zona);
      desc.constitutive = law;
      desc.formulation = Formulation::kGradient;
      desc.fixed_vertices = fixed;
      desc.precompute_threads = 8;
      const auto m0 = std::chrono::steady_clock::now();
      Result<Model> built = build_model(*mesh, desc);
      if (!built) {
        std::fprintf(stderr, "gpu_step_bench: model: %s\n", built.error().message.c_str());
        return nullptr;
      }
      std::fprintf(stderr, "# model: %.1f s, dt %.3g s\n",
                   std::chrono::duration<double>(std::chrono::steady_clock::now() - m0).count(),
                   built->dt);
      slot = std::make_unique<Model>(std::move(built).value());
      states[i] = std::make_unique<State>(make_state(*slot, 1));
      outs[i] = std::make_unique<State>(make_state(*slot, 1));
      if (Status st = set_prescribed_vertices(*slot, *states[i], patch); !st) {
        std::fprintf(stderr, "gpu_step_bench: %s\n", st.error().message.c_str());
        slot.reset();
        return nullptr;
      }
      return slot.get();
    };

    for (const Variant& var : kVariants) {
      if (!wanted(variants_arg, var.name)) continue;
      const Model* model = model_for(var.law);
      if (!model) break;
      const int mi = var.law == ConstitutiveModel::kSvk ? 0 : 1;
      const State& state = *states[mi];
      BackendOptions options;
      options.assembly = var.assembly;
      options.reorder = var.reorder;
      options.programmatic_launch = var.programmatic_launch;
      options.warp_aggregate = var.warp_aggregate;
      options.formulation = static_cast<int32_t>(var.form);
      Result<std::unique_ptr<Backend>> backend = make_cuda_backend(options);
      if (!backend) {
        std::fprintf(stderr, "gpu_step_bench: %s\n", backend.error().message.c_str());
        return 1;
      }
      Backend& b = **backend;
      std::string status = "ok";
      if (Status s = b.upload(*model, state); !s) {
        status = s.error().message;
        std::fprintf(stderr, "# %s at %lld: skipped: %s\n", var.name,
                     static_cast<long long>(target), status.c_str());
        continue;
      }
      // Warm-up (graph capture, caches), then timed windows; the needle moves at 1 mm/s (the
      // top of Hajiyavand et al. 2019's injection speeds).
      std::vector<Vec3d> targets(patch.size(), Vec3d{0, 0, 0});
      double push = 0;
      auto window = [&](StepReport* report) {
        push -= 1e-3 * model->dt * substeps;
        for (Vec3d& t : targets) t = Vec3d{0, 0, push};
        (void)b.set_prescribed_targets(targets);
        const auto w0 = std::chrono::steady_clock::now();
        *report = b.step(substeps);
        return std::chrono::duration<double>(std::chrono::steady_clock::now() - w0).count();
      };
      StepReport report;
      StepStatus all = kStepOk;
      for (int i = 0; i < 2; ++i) {
        window(&report);
        all |= report.status;
      }
      std::vector<double> ms, wall;
      for (int i = 0; i < repeats; ++i) {
        wall.push_back(window(&report));
        ms.push_back(report.device_ms / substeps);
        all |= report.status;
      }
      if (all & ~kStepCollapsingElement) status = "flags " + std::to_string(all);
      State& out = *outs[mi];
      uint64_t hash = 0;
      if (Status s = b.download(out); s) hash = fnv1a(out.u.data(), out.u.size() * sizeof(Vec3d));

      const std::string name = std::string(var.name) + (shuffle ? "_shuffled_mesh" : "");
      const double median = percentile(ms, 0.5);
      const VariantBytes vb = variant_bytes(var);
      const double bytes = vb.total(nv, nt);
      const double floor_ms = floor_bytes(nv, nt) / (gbps * 1e9) * 1e3;
      const double vfloor_ms = bytes / (gbps * 1e9) * 1e3;
      const double steps_per_s = substeps / percentile(wall, 0.5);
      char line[1024];
      std::snprintf(line, sizeof line,
                    "%s,%s,%.0f,%.0f,%s,%d,%.5f,%.5f,%.5f,%.0f,%.0f,%.1f,%.0f,%.0f,%.5f,%.2f,"
                    "%.5f,%s,%016llx\n",
                    device.c_str(), date, nv, nt, name.c_str(), substeps, median,
                    percentile(ms, 0.1), percentile(ms, 0.9), steps_per_s, bytes, vb.per_tet,
                    bytes / (median * 1e-3) * 1e-9, gbps, floor_ms, median / floor_ms, vfloor_ms,
                    status.c_str(), static_cast<unsigned long long>(hash));
      std::printf("%s", line);
      std::fflush(stdout);
      if (csv) std::fprintf(csv, "%s", line);
      rows.push_back(
          {static_cast<int64_t>(nv), name, median, floor_ms, median / floor_ms, steps_per_s});
    }
  }
  if (csv) std::fclose(csv);

  std::printf("\n%-10s %-32s %10s %9s %7s %12s\n", "vertices", "variant", "ms/step", "floor_ms",
              "ratio", "steps/s");
  for (const Row& r : rows)
    std::printf("%-10lld %-32s %10.4f %9.4f %7.2f %12.0f\n", static_cast<long long>(r.nv),
                r.variant.c_str(), r.ms, r.floor_ms, r.ratio, r.steps_per_s);
  return 0;
}

}  // namespace
}  // namespace zona

int main(int argc, char** argv) {
  return zona::run(argc, argv);
}
