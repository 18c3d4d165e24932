// force.csv, summary.json, training metrics and VTU frames of a run.
#include "engine/sim/recorder.h"

#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <utility>

#include <nlohmann/json.hpp>

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
      "imbalance",  "kinetic_share"};
  return columns;
}

namespace {

// The longest row: 13 doubles of at most 24 characters ("-1.2345678901234567e-308"), two
// ints, 14 commas and the newline come to 339; the rest is margin.
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
      "%.17g,%.17g,%.17g,%.17g,%.17g,%.17g,%.17g,%.17g,%d,%.17g,%.17g,%d,%.17g,%.9g,%.9g\n",
      s.time, s.travel, s.deformation, s.force, s.force_vector.x, s.force_vector.y,
      s.force_vector.z, s.holding_force, s.contacts, s.elastic_energy, s.kinetic_energy,
      s.punctured ? 1 : 0, s.raw_force, s.imbalance, s.kinetic_share);
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

nlohmann::json run_summary_json(const Simulation& sim, const RunResult& run,
                                const TrainingMetrics& metrics) {
  using nlohmann::json;
  const Scene& scene = sim.scene();
  const Model& model = sim.model();
  json j;
  j["schema_version"] = kOutputSchemaVersion;
  j["scene"] = scene.name;
  j["source"] = scene.source;
  j["model"] = model_name(scene.model);
  j["interrupted"] = run.interrupted;
  j["backend"] = sim.backend_description();
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
  // The quasi-static check (engine/sim/quasi_static.h, docs/outputs.md).
  {
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
  if (const ParticleModel* pm = sim.particle_model()) {
    // Particle model (seed 001): how well eq. 6 kept the volume, and the model's size.
    j["volume_change_max_rel"] = sim.volume_change_max_rel();
    j["particles"] = {{"membrane_particles", pm->membrane_count},
                      {"springs", pm->spring_count()},
                      {"rest_volume_m3", pm->rest_volume},
                      {"final_volume_change_rel", sim.volume_change_rel()}};
  }
  j["notes"] = sim.notes();
  return j;
}

namespace {

double von_mises(const Mat3d& s) {
  const double a = s.m[0][0] - s.m[1][1], b = s.m[1][1] - s.m[2][2], c = s.m[2][2] - s.m[0][0];
  const double shear = s.m[0][1] * s.m[0][1] + s.m[1][2] * s.m[1][2] + s.m[0][2] * s.m[0][2];
  return std::sqrt(0.5 * (a * a + b * b + c * c) + 3.0 * shear);
}

}  // namespace

void frame_fields(const Simulation& sim, std::vector<VtkField>* point_data,
                  std::vector<VtkField>* cell_data) {
  frame_fields(sim.model(), sim.state(), sim.needle_contacts(), sim.holding_contacts(), point_data,
               cell_data);
  if (!sim.job_mode()) return;
  // The penalty step keeps no contact sets: mark what the tools touch in this state (the
  // needle's load stays at its puncture pose after puncture).
  const JobParams& p = sim.job_setup().params;
  const PunctureRecord& q = sim.puncture();
  const Vec3d tip = q.punctured ? p.needle_start + q.needle_travel * p.needle_direction
                                : sim.report().tip;
  const std::vector<uint8_t> marks =
      job_contact_marks(sim.job_setup(), sim.model(), sim.state(), tip);
  std::vector<double>& contact = (*point_data)[1].values;
  for (size_t v = 0; v < marks.size(); ++v) contact[v] = marks[v];
}

void frame_fields(const Model& model, const State& state, std::span<const Contact> needle,
                  std::span<const Contact> holding, std::vector<VtkField>* point_data,
                  std::vector<VtkField>* cell_data) {
  const size_t nv = model.vertex_count(), nt = model.tet_count();
  point_data->resize(2);
  VtkField& disp = (*point_data)[0];
  disp.name = "displacement";
  disp.components = 3;
  disp.values.resize(3 * nv);
  for (size_t v = 0; v < nv; ++v) {
    disp.values[3 * v] = state.u[v].x;
    disp.values[3 * v + 1] = state.u[v].y;
    disp.values[3 * v + 2] = state.u[v].z;
  }
  VtkField& contact = (*point_data)[1];
  contact.name = "contact";
  contact.components = 1;
  contact.values.assign(nv, 0.0);
  for (const Contact& c : needle) contact.values[static_cast<size_t>(c.vertex)] = 1.0;
  for (const Contact& c : holding) contact.values[static_cast<size_t>(c.vertex)] = 2.0;

  cell_data->resize(2);
  VtkField& strain = (*cell_data)[0];
  strain.name = "green_strain";
  strain.components = 6;
  strain.values.resize(6 * nt);
  VtkField& mises = (*cell_data)[1];
  mises.name = "von_mises_stress";
  mises.components = 1;
  mises.values.resize(nt);
  const bool svk = model.constitutive == ConstitutiveModel::kSvk;
  for (size_t t = 0; t < nt; ++t) {
    const Tet& e = model.tets[t];
    const Vec3d ue[4] = {state.u[e[0]], state.u[e[1]], state.u[e[2]], state.u[e[3]]};
    const Mat3d h = tet_displacement_gradient(model.tet_shape[t], ue);
    const Mat3d green = green_strain(h);
    const double* g = &green.m[0][0];
    const double comps[6] = {g[0], g[4], g[8], g[1], g[5], g[2]};
    std::copy(comps, comps + 6, strain.values.begin() + static_cast<std::ptrdiff_t>(6 * t));
    const Lame& lame = model.tet_lame(t);
    double psi = 0;
    Mat3d sigma;
    if (svk) {
      // Cauchy stress sigma = F S F^T / J; an inverted element reports its S.
      const Mat3d s = isotropic_stress(green, lame.lambda, lame.mu, &psi);
      Mat3d f = h;
      for (int i = 0; i < 3; ++i) f.m[i][i] += 1.0;
      const double det = determinant(f);
      sigma = det > 0 ? (1.0 / det) * (f * s * transpose(f)) : s;
    } else if (model.constitutive == ConstitutiveModel::kStableNeoHookean) {
      // Cauchy stress sigma = P F^T / J; an inverted element reports its P.
      Mat3d p;
      double jm1;
      psi = snh_first_piola(h, lame.lambda, lame.mu, &p, &jm1);
      Mat3d f = h;
      for (int i = 0; i < 3; ++i) f.m[i][i] += 1.0;
      sigma = jm1 > -1.0 ? (1.0 / (1.0 + jm1)) * (p * transpose(f)) : p;
    } else {
      sigma = isotropic_stress(small_strain(h), lame.lambda, lame.mu, &psi);
    }
    mises.values[t] = von_mises(sigma);
  }
}

FrameRecorder::FrameRecorder(const std::string& directory)
    : writer_((std::filesystem::path(directory) / "frames.pvd").string()) {}

Status FrameRecorder::write(const Simulation& sim) {
  const Model& model = sim.model();
  positions_.resize(model.vertex_count());
  for (size_t v = 0; v < model.vertex_count(); ++v)
    positions_[v] = model.rest_positions[v] + sim.state().u[v];
  frame_fields(sim, &point_data_, &cell_data_);
  VtuOptions options;
  options.positions = &positions_;
  return writer_.write_frame(sim.state().time, sim.mesh(), point_data_, cell_data_, options);
}

}  // namespace zona
