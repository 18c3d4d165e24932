// force.csv, summary.json (with provenance), training metrics, VTU frames of a run, and the
// clean-up of an earlier run's outputs.
#include "engine/sim/recorder.h"

#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <ctime>
#include <filesystem>
#include <fstream>
#include <thread>
#include <utility>

#include <nlohmann/json.hpp>

#include "engine/core/thread_pool.h"
#include "engine/fem/fem_element.h"

namespace zona {

TrainingMetrics compute_training_metrics(const RunResult& run, double cell_diameter,
                                         double fluctuation_window) {
  TrainingMetrics m;
  m.fluctuation_window = fluctuation_window;
  const std::vector<ForceSample>& s = run.samples;
  if (s.empty()) return m;
  // Mean insertion speed: start to puncture, or to the last sample.
  const double t_end = run.puncture.punctured ? run.puncture.time : s.back().time;
  const double travel_end = run.puncture.punctured ? run.puncture.needle_travel : s.back().travel;
  if (t_end > 0) m.mean_insertion_speed = travel_end / t_end;
  if (run.puncture.punctured && cell_diameter > 0)
    m.deformation_percent = 100.0 * run.puncture.deformation / cell_diameter;

  // MFAR over the loading phase: from the first sample in contact to the last before puncture.
  size_t first = s.size(), last = 0;
  for (size_t i = 0; i < s.size(); ++i) {
    if (s[i].punctured) break;
    if (s[i].contacts > 0) {
      first = std::min(first, i);
      last = i;
    }
  }
  if (first >= last) return m;
  const size_t n = last - first + 1;
  const size_t half = std::max<size_t>(1, static_cast<size_t>(std::lround(0.5 * fluctuation_window * static_cast<double>(n))));
  if (n < 2 * half + 1) return m;
  double peak = 0;
  for (size_t i = first; i <= last; ++i) peak = std::max(peak, s[i].force);
  if (!(peak > 0)) return m;
  // Centred moving average by a running sum.
  double sum = 0;
  for (size_t i = first; i < first + 2 * half + 1; ++i) sum += s[i].force;
  double amplitude = 0;
  const double width = static_cast<double>(2 * half + 1);
  for (size_t c = first + half; c + half <= last; ++c) {
    amplitude = std::max(amplitude, std::fabs(s[c].force - sum / width));
    if (c + half + 1 <= last) sum += s[c + half + 1].force - s[c - half].force;
  }
  m.force_fluctuation_percent = 100.0 * amplitude / peak;
  return m;
}

std::vector<std::string> step_flag_names(StepStatus status) {
  static constexpr std::pair<StepStatusBits, const char*> kNames[] = {
      {kStepNonFinite, "non-finite values"},
      {kStepEnergyBlowUp, "energy blow-up"},
      {kStepInvertedElement, "inverted elements"},
      {kStepCollapsingElement, "collapsing elements"},
      {kStepClampedElement, "clamped elements"},
      {kStepDtAboveCritical, "dt above critical"},
      {kStepToolBreach, "needle through the surface"},
      {kStepNotQuasiStatic, "not quasi-static"}};
  std::vector<std::string> names;
  for (const auto& [bit, name] : kNames)
    if (status & bit) names.emplace_back(name);
  return names;
}

const std::vector<std::string>& force_csv_columns() {
  static const std::vector<std::string> columns = {
      "time_s",     "needle_travel_m", "deformation_m",    "force_N",
      "force_x_N",  "force_y_N",       "force_z_N",        "holding_force_N",
      "contacts",   "elastic_energy_J", "kinetic_energy_J", "punctured", "raw_force_N",
      "imbalance",  "kinetic_share", "newton_iterations", "krylov_iterations", "residual_N",
      "holding_contacts"};
  return columns;
}

namespace {

// The longest row: 14 doubles of at most 24 characters ("-1.2345678901234567e-308"), five
// integers of at most 20, 18 commas and the newline come to 455; the rest is margin.
constexpr size_t kMaxRowBytes = 512;
constexpr size_t kRowBufferBytes = size_t{1} << 16;

int64_t steady_ns() {
  return std::chrono::duration_cast<std::chrono::nanoseconds>(
             std::chrono::steady_clock::now().time_since_epoch())
      .count();
}

}  // namespace

void ForceCsvWriter::FileCloser::operator()(std::FILE* f) const { std::fclose(f); }

Result<ForceCsvWriter> ForceCsvWriter::open(const std::string& path, double flush_interval) {
  ForceCsvWriter w;
  w.path_ = path;
  w.flush_interval_ = flush_interval;
  w.file_.reset(std::fopen(path.c_str(), "w"));
  if (!w.file_)
    return make_error("%s: cannot open for writing: %s", path.c_str(), std::strerror(errno));
  // Unbuffered: the rows are buffered here, whole, and each flush is one write of whole rows.
  std::setvbuf(w.file_.get(), nullptr, _IONBF, 0);
  w.buffer_.resize(kRowBufferBytes);
  const std::vector<std::string>& columns = force_csv_columns();
  std::string header = "# zona force.csv schema " + std::to_string(kOutputSchemaVersion) +
                       " (docs/outputs.md)\n";
  for (size_t i = 0; i < columns.size(); ++i)
    header += columns[i] + (i + 1 < columns.size() ? "," : "\n");
  if (std::fwrite(header.data(), 1, header.size(), w.file_.get()) != header.size())
    return make_error("%s: write failed: %s", path.c_str(), std::strerror(errno));
  return w;
}

ForceCsvWriter::~ForceCsvWriter() {
  if (file_) (void)close();
}

Status ForceCsvWriter::append(const ForceSample& s) {
  if (!error_.empty()) return Error{error_};
  if (!file_) return make_error("%s: append after close", path_.c_str());
  if (used_ + kMaxRowBytes > buffer_.size())
    if (Status st = flush(); !st) return st;
  const int n = std::snprintf(
      buffer_.data() + used_, kMaxRowBytes,
      "%.17g,%.17g,%.17g,%.17g,%.17g,%.17g,%.17g,%.17g,%d,%.17g,%.17g,%d,%.17g,%.9g,%.9g,%d,%lld,"
      "%.9g,%d\n",
      s.time, s.travel, s.deformation, s.force, s.force_vector.x, s.force_vector.y,
      s.force_vector.z, s.holding_force, s.contacts, s.elastic_energy, s.kinetic_energy,
      s.punctured ? 1 : 0, s.raw_force, s.imbalance, s.kinetic_share, s.newton_iterations,
      static_cast<long long>(s.krylov_iterations), s.residual, s.holding_contacts);
  ZONA_ASSERT(n > 0 && static_cast<size_t>(n) < kMaxRowBytes);
  used_ += static_cast<size_t>(n);
  // The first row goes out at once (a reader sees the run has started), then by wall time.
  const int64_t now = steady_ns();
  if (last_flush_ns_ == 0 || static_cast<double>(now - last_flush_ns_) * 1e-9 >= flush_interval_) {
    if (Status st = flush(); !st) return st;
    last_flush_ns_ = now;
  }
  return Status::ok_status();
}

Status ForceCsvWriter::flush() {
  if (!error_.empty()) return Error{error_};
  if (!file_ || used_ == 0) return Status::ok_status();
  if (std::fwrite(buffer_.data(), 1, used_, file_.get()) != used_) {
    error_ = path_ + ": write failed: " + std::strerror(errno);
    return Error{error_};
  }
  used_ = 0;
  return Status::ok_status();
}

Status ForceCsvWriter::close() {
  if (!file_) return error_.empty() ? Status::ok_status() : Status(Error{error_});
  Status st = flush();
  if (std::fclose(file_.release()) != 0 && st.ok()) {
    error_ = path_ + ": write failed: " + std::strerror(errno);
    return Error{error_};
  }
  return st;
}

Status write_force_csv(const std::string& path, std::span<const ForceSample> samples) {
  Result<ForceCsvWriter> writer = ForceCsvWriter::open(path, /*flush_interval=*/1e30);
  if (!writer) return writer.error();
  for (const ForceSample& s : samples)
    if (Status st = writer->append(s); !st) return st;
  return writer->close();
}

Status write_file_atomic(const std::string& path, const std::string& text) {
  const std::string tmp = path + ".tmp";
  std::FILE* f = std::fopen(tmp.c_str(), "w");
  if (!f) return make_error("%s: cannot open for writing: %s", tmp.c_str(), std::strerror(errno));
  // The first failure's errno; on disk (fsync) before the rename, otherwise a crash can leave
  // the new name on empty contents.
  int e = -1;
  auto check = [&e](bool ok) {
    if (!ok && e < 0) e = errno;
  };
  check(std::fwrite(text.data(), 1, text.size(), f) == text.size());
  check(std::fflush(f) == 0);
  check(::fsync(::fileno(f)) == 0);
  check(std::fclose(f) == 0);
  std::error_code ec;
  if (e >= 0) {
    std::filesystem::remove(tmp, ec);
    return make_error("%s: write failed: %s", tmp.c_str(), std::strerror(e));
  }
  std::filesystem::rename(tmp, path, ec);
  if (ec) {
    std::filesystem::remove(tmp, ec);
    return make_error("%s: cannot rename %s over it: %s", path.c_str(), tmp.c_str(),
                      ec.message().c_str());
  }
  return Status::ok_status();
}

RunProvenance local_provenance() {
  RunProvenance p;
  p.zona_version = ZONA_VERSION;
  char date[32];
  const std::time_t now = std::time(nullptr);
  std::tm utc{};
  gmtime_r(&now, &utc);
  std::strftime(date, sizeof date, "%Y-%m-%dT%H:%M:%SZ", &utc);
  p.date_utc = date;
  char host[256] = {};
  if (::gethostname(host, sizeof host - 1) == 0) p.hostname = host;
  std::ifstream cpuinfo("/proc/cpuinfo");
  std::string line;
  while (std::getline(cpuinfo, line)) {
    if (line.rfind("model name", 0) != 0) continue;
    const size_t colon = line.find(':');
    if (colon != std::string::npos) {
      p.cpu_model = line.substr(colon + 1);
      p.cpu_model.erase(0, p.cpu_model.find_first_not_of(" \t"));
    }
    break;
  }
  if (p.cpu_model.empty()) p.cpu_model = "unknown CPU";
  p.hardware_threads = static_cast<int>(std::thread::hardware_concurrency());
  return p;
}

nlohmann::json run_summary_json(const Simulation& sim, const RunResult& run,
                                const TrainingMetrics& metrics, const RunProvenance& provenance) {
  using nlohmann::json;
  const Scene& scene = sim.scene();
  const Model& model = sim.model();
  json j;
  j["schema_version"] = kOutputSchemaVersion;
  j["scene"] = scene.name;
  j["source"] = scene.source;
  j["model"] = model_name(scene.model);
  j["interrupted"] = run.interrupted;
  j["backend"] = scene.solver.method == SolverMethod::kStatic
                     ? "cpu static solver: " + std::to_string(shared_pool_threads()) +
                           " thread(s), float64"
                     : sim.backend_description();
  // The simulation runs on a Backend object only off the CPU (the CPU reference works in place).
  j["backend_kind"] = sim.backend() ? sim.backend()->name() : "cpu";
  if (scene.solver.method == SolverMethod::kStatic) {
    const SolverDef& d = scene.solver;
    j["solver"] = "static";
    j["static_solver"] = {{"linear", d.linear == LinearSolverKind::kDirect ? "direct" : "cg"},
                          {"preconditioner", preconditioner_used(d, model.vertex_count())},
                          {"tolerance", d.tolerance},
                          {"travel_step_m", d.travel_step},
                          {"barrier_volume", d.barrier_volume},
                          {"load_steps", run.steps},
                          {"threads", shared_pool_threads()}};
  } else {
    j["solver"] = "explicit";
  }
  j["provenance"] = {{"zona_version", provenance.zona_version},
                     {"commit", provenance.commit},
                     {"command", provenance.command},
                     {"date_utc", provenance.date_utc},
                     {"machine",
                      {{"hostname", provenance.hostname},
                       {"cpu_model", provenance.cpu_model},
                       {"hardware_threads", provenance.hardware_threads},
                       {"gpu", provenance.gpu.empty() ? json(nullptr) : json(provenance.gpu)}}}};
  j["mesh"] = {{"vertices", model.vertex_count()},
               {"tets", model.tet_count()},
               {"surface_vertices", sim.surface().vertices.size()}};
  j["cell_diameter_m"] = sim.cell_diameter();
  static constexpr const char* kCriteria[] = {"none", "force", "strain", "energy"};
  json p = {{"punctured", run.puncture.punctured},
            {"criterion", kCriteria[static_cast<int>(scene.puncture.criterion)]},
            {"threshold", scene.puncture.threshold}};
  if (run.puncture.punctured) {
    p["time_s"] = run.puncture.time;
    p["needle_travel_m"] = run.puncture.needle_travel;
    p["deformation_m"] = run.puncture.deformation;
    p["force_N"] = run.puncture.force;
    p["max_strain"] = run.puncture.max_strain;
    p["elastic_energy_J"] = run.puncture.energy;
  }
  j["puncture"] = p;
  j["peak_force_N"] = run.peak_force;
  // The quasi-static check (engine/sim/quasi_static.h, docs/outputs.md). A static run is in
  // equilibrium at every row by construction: the check of the explicit step's dynamics does
  // not apply to it.
  if (scene.solver.method == SolverMethod::kStatic) {
    j["quasi_static"] = scene.needle.enabled ? json(true) : json(nullptr);
    j["quasi_static_check"] = nullptr;
  } else {
    const QuasiStaticLimits& lim = run.quasi_limits;
    const QuasiStaticState& q = run.quasi;
    const bool needle = scene.needle.enabled;
    json c = {{"experiment", scene.experiment == Experiment::kDynamic ? "dynamic" : "quasi_static"},
              {"enforced", lim.enforce != 0},
              {"imbalance_measured", needle && lim.has_holder != 0},
              {"kinetic_share_judged", needle && lim.max_kinetic_share < 1},
              {"max_imbalance", lim.max_imbalance},
              {"max_kinetic_share", lim.max_kinetic_share},
              {"force_floor_N", lim.force_floor},
              {"failed_steps", q.failed_steps},
              {"worst_imbalance", q.worst_imbalance},
              {"worst_imbalance_time_s", q.worst_imbalance_time},
              {"worst_imbalance_deformation_m", q.worst_imbalance_deformation},
              {"worst_kinetic_share", q.worst_kinetic_share},
              {"worst_kinetic_share_time_s", q.worst_kinetic_time},
              {"worst_kinetic_share_deformation_m", q.worst_kinetic_deformation}};
    if (q.failed_steps > 0)
      c["first_failed"] = {{"step", q.first_failed_step},
                           {"time_s", q.first_failed_time},
                           {"deformation_m", q.first_failed_deformation},
                           {"force_N", q.first_failed_force},
                           {"imbalance", q.first_failed_imbalance},
                           {"kinetic_share", q.first_failed_kinetic_share}};
    // Without a needle, or with nothing to judge by (no holder's force, no kinetic-share
    // limit): null, not a verdict.
    j["quasi_static"] =
        needle && quasi_static_measured(lim) ? json(run.quasi_static()) : json(nullptr);
    j["quasi_static_check"] = c;
  }
  j["peak_deformation_m"] = run.peak_deformation;
  j["training"] = {{"mean_insertion_speed_m_per_s", metrics.mean_insertion_speed},
                   {"deformation_at_puncture_percent_of_diameter", metrics.deformation_percent},
                   {"force_fluctuation_mfar_percent", metrics.force_fluctuation_percent},
                   {"mfar_window_fraction", metrics.fluctuation_window}};
  j["numerics"] = {
      {"steps", run.steps},
      {"dt_s", model.dt},
      {"dt_critical_s", model.dt_critical},
      {"mass_scaling", model.mass_scaling},
      {"mass_scaling_mode",
       scene.integrator.mass_scaling_mode == MassScalingMode::kSelective ? "selective" : "uniform"},
      {"inversion", model.inversion == InversionHandling::kClampStretch ? "clamp_stretch" : "report"},
      {"simulated_time_s", run.simulated_time},
      {"wall_time_s", run.wall_seconds},
      {"flags_seen", step_flag_names(run.status)},
      {"stopped_early", run.stopped_early},
      {"sample_buffer_full", run.sample_buffer_full},
      {"mass_raises", run.mass_raises},
      {"samples", run.samples.size()}};
  if (run.stopped_early) j["numerics"]["stop_reason"] = run.stop_reason;
  if (scene.solver.method == SolverMethod::kStatic) {
    j["numerics"]["static"] = {{"newton_iterations", run.newton_iterations},
                               {"krylov_iterations", run.krylov_iterations},
                               {"failed_solves", run.failed_solves}};
    // The explicit step's time step and mass scaling: a static run has neither (its
    // regulariser takes the real mass, docs/static.md).
    for (const char* key : {"dt_s", "dt_critical_s", "mass_scaling", "mass_scaling_mode",
                            "mass_raises"})
      j["numerics"][key] = nullptr;
  }
  if (run.oracle_solves > 0 || run.oracle_failures > 0)
    j["numerics"]["oracle"] = {{"solves", run.oracle_solves},
                               {"failures", run.oracle_failures},
                               {"max_relative_difference", run.oracle_max_difference}};
  if (const ParticleModel* pm = sim.particle_model()) {
    // Particle model (Asgari et al.): how well eq. 6 kept the volume, and the model's size.
    j["volume_change_max_rel"] = sim.volume_change_max_rel();
    j["particles"] = {{"membrane_particles", pm->membrane_count},
                      {"springs", pm->spring_count()},
                      {"rest_volume_m3", pm->rest_volume},
                      {"final_volume_change_rel", sim.volume_change_rel()}};
  }
  j["notes"] = sim.notes();
  return j;
}

FrameRecorder::FrameRecorder(const std::string& directory, FrameFormat format)
    : directory_(directory),
      format_(format),
      pvd_((std::filesystem::path(directory) / "frames.pvd").string()) {}

std::string FrameRecorder::xdmf_path() const {
  return (std::filesystem::path(directory_) / "frames.xdmf").string();
}

Status FrameRecorder::write(const Simulation& sim) {
  frame_fields(sim, &point_data_, &cell_data_);
  const double time = sim.state().time;
  // The rest positions with the displacement beside them: one Warp By Vector shows the
  // deformed cell (deformed points and a displacement array would show it deformed twice).
  if (writes_vtu(format_)) {
    VtuOptions options;
    options.field_data = {{"TimeValue", 1, {time}}, {"points_at_rest", 1, {1.0}}};
    options.comment = kFramePointsNote;
    if (Status s = pvd_.write_frame(time, sim.mesh(), point_data_, cell_data_, options); !s)
      return s;
  }
  if (writes_xdmf(format_)) {
    if (!xdmf_) {
      XdmfOptions options;
      options.field_data = {{"points_at_rest", 1, {1.0}}};
      options.comment = kSeriesPointsNote;
      Result<XdmfWriter> writer = XdmfWriter::create(xdmf_path(), sim.mesh(), options);
      if (!writer) return writer.error();
      xdmf_.emplace(std::move(writer).value());
    }
    if (Status s = xdmf_->write_frame(time, point_data_, cell_data_); !s) return s;
  }
  ++frame_count_;
  return Status::ok_status();
}

Status FrameRecorder::close() { return xdmf_ ? xdmf_->close() : Status::ok_status(); }

bool is_run_output(const std::string& file_name) {
  static constexpr const char* kNames[] = {"force.csv",   "summary.json",
                                           "scene.json",  "frames.pvd",
                                           "frames.xdmf", "frames.h5",
                                           "force_deformation.png", "force_deformation.svg"};
  for (const char* name : kNames) {
    const std::string n = name;
    if (file_name == n || file_name == n + ".tmp") return true;
  }
  // frames_<digits>.vtu (PvdWriter numbers them with six digits; more past a million frames).
  const std::string prefix = "frames_", suffix = ".vtu";
  if (file_name.size() <= prefix.size() + suffix.size() || file_name.rfind(prefix, 0) != 0 ||
      file_name.compare(file_name.size() - suffix.size(), suffix.size(), suffix) != 0)
    return false;
  for (size_t i = prefix.size(); i < file_name.size() - suffix.size(); ++i)
    if (file_name[i] < '0' || file_name[i] > '9') return false;
  return true;
}

Status remove_run_outputs(const std::string& directory, std::vector<std::string>* removed) {
  namespace fs = std::filesystem;
  std::error_code ec;
  if (!fs::is_directory(directory, ec)) return Status::ok_status();
  // Names first, removal after: removing while iterating a directory is unspecified.
  std::vector<fs::path> doomed;
  for (fs::directory_iterator it(directory, ec), end; !ec && it != end; it.increment(ec)) {
    const fs::file_status st = it->symlink_status(ec);
    if (ec) break;
    // A folder that happens to carry an output's name is the user's, never zona's.
    if (fs::is_directory(st)) continue;
    if (is_run_output(it->path().filename().string())) doomed.push_back(it->path());
  }
  if (ec)
    return make_error("%s: cannot list the output folder: %s", directory.c_str(),
                      ec.message().c_str());
  std::sort(doomed.begin(), doomed.end());
  for (const fs::path& p : doomed) {
    if (!fs::remove(p, ec) && ec)
      return make_error("%s: cannot remove an earlier run's output: %s", p.string().c_str(),
                        ec.message().c_str());
    if (removed) removed->push_back(p.filename().string());
  }
  return Status::ok_status();
}

}  // namespace zona
