// zona.run's C++ half: a scene (its JSON) through the one run driver, run_simulation
// (engine/sim/run.cpp), with the GIL released while it steps. Progress calls and Ctrl-C checks
// take the GIL back between batches of steps; a KeyboardInterrupt, an exception from the
// progress callback or a callback returning False stops the run through RunOptions::stop, and
// the result up to there comes back. With an output folder it writes what `zona run` writes
// (force.csv streamed, scene.json, summary.json, VTU or XDMF frames; not the PNG plot).
#include <atomic>
#include <chrono>
#include <filesystem>
#include <memory>
#include <optional>
#include <string>
#include <type_traits>
#include <vector>

#include <nanobind/stl/string.h>
#include <nanobind/stl/vector.h>
#include <nlohmann/json.hpp>

#include "build_commit.h"  // generated: ZONA_BUILD_COMMIT
#include "engine/mesh/mesh_io.h"
#include "engine/sim/recorder.h"
#include "engine/sim/simulation.h"
#include "kernels/backend_factory.h"
#include "kernels/backend_info.h"
#include "kernels/particle_backend.h"
#include "python/module.h"

namespace zona::py {
namespace {

namespace fs = std::filesystem;

// What the arrays of one result keep alive: the simulation (rest positions and displacement are
// views into its mesh and state) and the fields computed from its final state.
struct RunHold {
  std::unique_ptr<Simulation> sim;
  std::vector<VtkField> point_data, cell_data;
};

// The force.csv columns as arrays, in force_csv_columns() order; the values are the ones the
// CSV writer formats (ForceCsvWriter::append).
nb::dict sample_columns(const std::vector<ForceSample>& samples) {
  const size_t n = samples.size();
  const std::vector<std::string>& names = force_csv_columns();
  nb::dict columns;
  // Each column in its getter's type: float64, int32 / int64 counts, the uint8 puncture flag.
  auto column = [&](size_t index, auto get) {
    std::vector<std::decay_t<decltype(get(samples.front()))>> v(n);
    for (size_t i = 0; i < n; ++i) v[i] = get(samples[i]);
    columns[names.at(index).c_str()] = array_of(std::move(v), {n});
  };
  column(0, [](const ForceSample& s) { return s.time; });
  column(1, [](const ForceSample& s) { return s.travel; });
  column(2, [](const ForceSample& s) { return s.deformation; });
  column(3, [](const ForceSample& s) { return s.force; });
  column(4, [](const ForceSample& s) { return s.force_vector.x; });
  column(5, [](const ForceSample& s) { return s.force_vector.y; });
  column(6, [](const ForceSample& s) { return s.force_vector.z; });
  column(7, [](const ForceSample& s) { return s.holding_force; });
  column(8, [](const ForceSample& s) { return s.contacts; });
  column(9, [](const ForceSample& s) { return s.elastic_energy; });
  column(10, [](const ForceSample& s) { return s.kinetic_energy; });
  column(11, [](const ForceSample& s) { return static_cast<uint8_t>(s.punctured ? 1 : 0); });
  column(12, [](const ForceSample& s) { return s.raw_force; });
  column(13, [](const ForceSample& s) { return s.imbalance; });
  column(14, [](const ForceSample& s) { return s.kinetic_share; });
  column(15, [](const ForceSample& s) { return s.newton_iterations; });
  column(16, [](const ForceSample& s) { return s.krylov_iterations; });
  column(17, [](const ForceSample& s) { return s.residual; });
  column(18, [](const ForceSample& s) { return s.holding_contacts; });
  if (names.size() != 19)
    throw ZonaError("force.csv has " + std::to_string(names.size()) +
                    " columns; this module knows 19 (python/module_run.cpp)");
  return columns;
}

// The fields of the final state: views into the simulation and into the frame_fields arrays.
void add_fields(nb::dict& out, const std::shared_ptr<RunHold>& hold) {
  const Simulation& sim = *hold->sim;
  const size_t nv = sim.mesh().vertex_count(), nt = sim.mesh().tet_count();
  out["rest_positions"] = positions_view(sim.mesh().rest_positions, hold);
  static_assert(sizeof(Tet) == 4 * sizeof(int32_t), "Tet must be four packed int32");
  out["tets"] = array_view(reinterpret_cast<const int32_t*>(sim.mesh().tets.data()), {nt, 4}, hold);
  out["tet_region"] = array_view(sim.mesh().tet_region.data(), {nt}, hold);
  nb::dict regions;
  for (const Region& r : sim.mesh().regions) regions[r.name.c_str()] = r.tag;
  out["regions"] = regions;
  nb::dict point, cell;
  // Tensors (9 components) as (n x 3 x 3), vectors as (n x 3), scalars as (n).
  auto shape_of = [](size_t count, int components) -> std::vector<size_t> {
    if (components == 1) return {count};
    if (components == 9) return {count, 3, 3};
    return {count, static_cast<size_t>(components)};
  };
  for (const VtkField& f : hold->point_data)
    point[f.name.c_str()] = array_view(f.values.data(), shape_of(nv, f.components), hold);
  for (const VtkField& f : hold->cell_data)
    cell[f.name.c_str()] = array_view(f.values.data(), shape_of(nt, f.components), hold);
  out["point_fields"] = point;
  out["cell_fields"] = cell;
}

// The progress record handed to the Python callback.
nb::dict progress_dict(const RunProgress& p) {
  nb::dict d;
  d["time_s"] = p.time;
  d["end_time_s"] = p.end_time;
  d["wall_s"] = p.wall_seconds;
  if (p.report) {
    d["travel_m"] = p.report->travel;
    d["deformation_m"] = p.report->deformation;
    d["force_N"] = p.report->force;
    d["punctured"] = p.report->punctured;
  }
  return d;
}

struct RunArgs {
  std::string scene_json;
  std::string source;      // the scene file the JSON came from, "" for none
  std::string backend = "cpu";
  std::string out;         // output folder, "" for none
  nb::object progress;     // callable or None
  double progress_interval = 0.5;
  int threads = 0;
  double stop_after_puncture = -1;
  int frames = -1;         // -1: the scene's output.frames
  bool full_duration = false;
  std::string command;     // for summary.json's provenance
};

nb::dict run(const RunArgs& a) {
  RunProvenance provenance = local_provenance();  // the date is the run's start
  provenance.commit = ZONA_BUILD_COMMIT;
  provenance.command = a.command;
  nlohmann::json json = nlohmann::json::parse(a.scene_json, nullptr, false);
  if (json.is_discarded()) throw ZonaError("scene: not valid JSON");
  const std::string name = a.source.empty() ? std::string("scene dict") : a.source;
  Scene scene = take(parse_scene(json, name));
  const BackendKind kind = take(parse_backend_kind(a.backend));

  RunOptions options;
  options.simulation.threads = a.threads;
  if (kind != BackendKind::kCpu) {
    BackendOptions backend_options;
    backend_options.cpu_threads = a.threads;
    options.simulation.backend_factory = [kind, backend_options](std::string* notice) {
      return make_backend(kind, backend_options, notice);
    };
    options.simulation.particle_backend_factory = [kind, backend_options](
                                                      const ParticleModel& pm, std::string* notice) {
      return make_particle_backend(kind, pm, backend_options, notice);
    };
  }
  options.stop_after_puncture = a.stop_after_puncture;
  if (a.frames >= 0) {
    scene.output.frames = a.frames;
    scene.output.frame_interval.reset();
  }
  // As `zona run`: a haptic scene's hour-long duration ends with the needle unless
  // full_duration (end_run_with_needle, engine/scene/scene.h).
  std::vector<std::string> notes;
  if (!a.full_duration) {
    const double duration = scene.integrator.duration;
    if (const double needle_end = end_run_with_needle(scene); needle_end > 0)
      notes.push_back("integrator.duration is " + std::to_string(duration) +
                      " s but the needle stops at " + std::to_string(needle_end) +
                      " s: the run ends with the needle (full_duration=True simulates it all)");
  }

  auto hold = std::make_shared<RunHold>();
  const auto setup_start = std::chrono::steady_clock::now();
  std::optional<Result<std::unique_ptr<Simulation>>> created;
  {
    nb::gil_scoped_release release;  // building the mesh and model may take seconds
    created.emplace(Simulation::create(scene, options.simulation));
  }
  hold->sim = take(std::move(*created));
  Simulation& sim = *hold->sim;
  const double setup_seconds =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - setup_start).count();
  for (const std::string& n : sim.notes()) notes.push_back(n);

  // Outputs as `zona run` writes them: an earlier run's outputs removed, scene.json before the
  // run, force.csv row by row, VTU frames as the run goes.
  std::optional<ForceCsvWriter> csv;
  std::unique_ptr<FrameRecorder> frames;
  std::string output_error;
  if (!a.out.empty()) {
    std::error_code ec;
    fs::create_directories(a.out, ec);
    if (ec) throw ZonaError(a.out + ": cannot create the output folder: " + ec.message());
    check(remove_run_outputs(a.out));
    check(write_file_atomic((fs::path(a.out) / "scene.json").string(),
                            scene_to_json(scene).dump(2) + "\n"));
    csv.emplace(take(ForceCsvWriter::open((fs::path(a.out) / "force.csv").string())));
    options.on_sample = [&](const ForceSample& s) {
      if (output_error.empty())
        if (Status st = csv->append(s); !st) output_error = st.error().message;
    };
    if (scene.output.frames > 0 || scene.output.frame_interval) {
      frames = std::make_unique<FrameRecorder>(a.out, scene.output.format);
      options.frame = [&](const Simulation& s, int) {
        if (output_error.empty())
          if (Status st = frames->write(s); !st) output_error = st.error().message;
      };
    }
  }

  // Progress and Ctrl-C: the driver calls back every 0.1 s of wall time at most; the Python
  // callback runs at its own interval. Both need the GIL, taken only here.
  std::atomic<bool> stop{false};
  std::optional<nb::object> error;  // the exception that stopped the run
  bool stopped_by_callback = false;
  double next_call = 0;
  options.stop = &stop;
  options.progress_interval = std::min(0.1, std::max(a.progress_interval, 0.0));
  options.progress = [&](const RunProgress& p) {
    nb::gil_scoped_acquire acquire;
    if (stop.load()) return;
    try {
      if (PyErr_CheckSignals() != 0) throw nb::python_error();
      if (!a.progress.is_none() && p.wall_seconds >= next_call) {
        next_call = p.wall_seconds + a.progress_interval;
        nb::object answer = a.progress(progress_dict(p));
        if (answer.is(nb::bool_(false))) {
          stopped_by_callback = true;
          stop.store(true);
        }
      }
    } catch (nb::python_error& e) {
      error = nb::borrow(e.value());
      stop.store(true);
    } catch (const std::exception& e) {
      // Nothing may unwind through the driver: the run stops and the error is raised after.
      error = nb::module_::import_("builtins").attr("RuntimeError")(e.what());
      stop.store(true);
    }
  };
  std::vector<std::string> warnings;
  options.warning = [&](const std::string& line) { warnings.push_back(line); };

  RunResult result;
  {
    nb::gil_scoped_release release;
    result = run_simulation(sim, options);
  }

  // Outputs: the summary through the engine's builder, as `zona run` writes it.
  if (csv) {
    if (Status s = csv->close(); !s && output_error.empty()) output_error = s.error().message;
  }
  if (frames)
    if (Status s = frames->close(); !s && output_error.empty()) output_error = s.error().message;
  const TrainingMetrics metrics = compute_training_metrics(result, sim.cell_diameter());
  if (sim.backend() && std::string(sim.backend()->name()) == "cuda")
    for (const DeviceInfo& d : cuda_devices(nullptr))
      if (d.ordinal == 0) provenance.gpu = d.name;
  nlohmann::json summary = run_summary_json(sim, result, metrics, provenance);
  summary["numerics"]["setup_time_s"] = setup_seconds;
  if (!a.source.empty()) summary["scene_file"] = a.source;
  if (!a.out.empty() && output_error.empty())
    if (Status s = write_file_atomic((fs::path(a.out) / "summary.json").string(),
                                     summary.dump(2) + "\n");
        !s)
      output_error = s.error().message;

  // The final state's fields (on the GPU path the state comes to the host first).
  if (Status s = sim.sync_state(); !s) throw ZonaError(s.error().message);
  frame_fields(sim, &hold->point_data, &hold->cell_data);

  nb::dict out;
  out["columns"] = sample_columns(result.samples);
  out["summary"] = summary.dump();
  out["scene"] = scene_to_json(scene).dump();
  out["interrupted"] = result.interrupted;
  out["stopped_by_callback"] = stopped_by_callback;
  out["stopped_early"] = result.stopped_early;
  out["stop_reason"] = result.stop_reason;
  out["quasi_static_enforced"] = result.quasi_limits.enforce;
  out["quasi_static"] = result.quasi_static();
  out["warnings"] = warnings;
  out["notes"] = notes;
  out["output_error"] = output_error;
  out["error"] = error ? *error : nb::none();
  add_fields(out, hold);
  return out;
}

}  // namespace

void add_run(nb::module_& m) {
  m.def(
      "run",
      [](const std::string& scene_json, const std::string& source, const std::string& backend,
         const std::string& out, nb::object progress, double progress_interval, int threads,
         double stop_after_puncture, int frames, bool full_duration, const std::string& command) {
        RunArgs a{scene_json, source,        backend, out,    std::move(progress), progress_interval,
                  threads,    stop_after_puncture, frames, full_duration, command};
        return run(a);
      },
      nb::arg("scene_json"), nb::arg("source"), nb::arg("backend"), nb::arg("out"),
      nb::arg("progress").none(), nb::arg("progress_interval"), nb::arg("threads"),
      nb::arg("stop_after_puncture"), nb::arg("frames"), nb::arg("full_duration"),
      nb::arg("command"),
      "Runs a scene given as JSON (zona.run wraps this); returns a dict of arrays and texts.");
}

}  // namespace zona::py
