// Tests for engine/recorder: training metrics with known answers, force.csv, summary.json (with
// its provenance), the .pvd frames (rest positions and the note), the clean-up of an earlier
// run's outputs. The frame fields: recorder_fields_test.cpp.
#include "engine/sim/recorder.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <nlohmann/json.hpp>
#include <numbers>
#include <sstream>
#include <string>
#include <vector>

#include "engine/mesh/mesh_generate.h"
#include "engine/mesh/mesh_io.h"

namespace zona {
namespace {

namespace fs = std::filesystem;

// A loading ramp of n samples from 0 to 1 uN over 1 s (in contact), with an optional ripple.
RunResult ramp(int n, double ripple, int period) {
  RunResult r;
  for (int i = 0; i < n; ++i) {
    ForceSample s;
    s.time = static_cast<double>(i) / (n - 1);
    s.travel = 1e-4 * s.time;
    s.deformation = 0.8 * s.travel;
    s.force = 1e-6 * s.time + ripple * std::sin(2 * std::numbers::pi * i / period);
    s.contacts = 5;
    r.samples.push_back(s);
  }
  return r;
}

TEST(Recorder, TrainingMetricsOfKnownCurves) {
  // A straight ramp has no fluctuation: its moving average is itself.
  RunResult smooth = ramp(1001, 0.0, 4);
  TrainingMetrics m = compute_training_metrics(smooth, 56e-6);
  EXPECT_LT(m.force_fluctuation_percent, 1e-9);
  EXPECT_NEAR(m.mean_insertion_speed, 1e-4, 1e-12);
  EXPECT_EQ(m.deformation_percent, 0.0);  // no puncture
  // A ripple of 0.05 uN (period 4 samples, far shorter than the 5 % window) is 0.05 / 1.05 of
  // the peak, up to the window's residue of the sine (one sample in 51).
  RunResult rippled = ramp(1001, 0.05e-6, 4);
  m = compute_training_metrics(rippled, 56e-6);
  EXPECT_NEAR(m.force_fluctuation_percent, 100 * 0.05 / 1.05, 0.1);
  // Puncture: speed and deformation measured up to it; samples after it are not counted.
  rippled.puncture.punctured = true;
  rippled.puncture.time = 0.5;
  rippled.puncture.needle_travel = 50e-6;
  rippled.puncture.deformation = 42e-6;
  for (ForceSample& s : rippled.samples) s.punctured = s.time > 0.5;
  m = compute_training_metrics(rippled, 56e-6);
  EXPECT_NEAR(m.mean_insertion_speed, 1e-4, 1e-12);
  EXPECT_NEAR(m.deformation_percent, 75.0, 1e-9);
  EXPECT_NEAR(m.force_fluctuation_percent, 100 * 0.05 / 0.55, 0.4);
}

TEST(Recorder, ForceCsvHasTheDocumentedColumns) {
  const fs::path path = fs::temp_directory_path() / "zona_recorder_force.csv";
  const RunResult r = ramp(5, 0.0, 4);
  ASSERT_TRUE(write_force_csv(path.string(), r.samples).ok());
  std::ifstream in(path);
  std::string schema, header;
  std::getline(in, schema);
  EXPECT_EQ(schema, "# zona force.csv schema " + std::to_string(kOutputSchemaVersion) +
                        " (docs/outputs.md)");
  std::getline(in, header);
  EXPECT_EQ(header.rfind("time_s,needle_travel_m,deformation_m,force_N,", 0), 0u) << header;
  std::stringstream ss(header);
  std::string column;
  size_t count = 0;
  while (std::getline(ss, column, ',')) EXPECT_EQ(column, force_csv_columns()[count++]);
  EXPECT_EQ(count, force_csv_columns().size());
  int rows = 0;
  std::string line;
  double last_force = 0;
  while (std::getline(in, line)) {
    ++rows;
    std::stringstream row(line);
    std::string cell;
    for (int c = 0; c < 4; ++c) std::getline(row, cell, ',');
    last_force = std::stod(cell);
  }
  EXPECT_EQ(rows, 5);
  EXPECT_DOUBLE_EQ(last_force, r.samples.back().force);  // full precision round trip
  fs::remove(path);
  EXPECT_FALSE(write_force_csv("/nonexistent/dir/force.csv", r.samples).ok());
}

// The lines of a file as it is on disk now (a second reader, as a person tailing the run).
std::vector<std::string> lines_on_disk(const fs::path& path) {
  std::ifstream in(path);
  std::vector<std::string> lines;
  for (std::string line; std::getline(in, line);) lines.push_back(line);
  return lines;
}

TEST(Recorder, ForceCsvWriterStreamsRowsWhileTheRunGoes) {
  const fs::path path = fs::temp_directory_path() / "zona_recorder_stream.csv";
  const RunResult r = ramp(5, 0.0, 4);
  {
    // Flush interval 0: every row is on disk when append returns.
    Result<ForceCsvWriter> w = ForceCsvWriter::open(path.string(), 0.0);
    ASSERT_TRUE(w.ok()) << w.error().message;
    EXPECT_EQ(lines_on_disk(path).size(), 2u);  // the schema line and the header, at open
    for (size_t i = 0; i < 3; ++i) {
      ASSERT_TRUE(w->append(r.samples[i]).ok());
      EXPECT_EQ(lines_on_disk(path).size(), 3 + i);
    }
    ASSERT_TRUE(w->close().ok());
    EXPECT_FALSE(w->append(r.samples[3]).ok());  // closed
  }
  {
    // A long interval: the first row goes out at once, later rows at close (or a flush).
    Result<ForceCsvWriter> w = ForceCsvWriter::open(path.string(), 1e9);
    ASSERT_TRUE(w.ok());
    for (const ForceSample& s : r.samples) ASSERT_TRUE(w->append(s).ok());
    EXPECT_EQ(lines_on_disk(path).size(), 3u);
    ASSERT_TRUE(w->flush().ok());
    EXPECT_EQ(lines_on_disk(path).size(), 7u);
    ASSERT_TRUE(w->close().ok());
  }
  // The streamed file is byte for byte the one write_force_csv writes.
  const std::vector<std::string> streamed = lines_on_disk(path);
  ASSERT_TRUE(write_force_csv(path.string(), r.samples).ok());
  EXPECT_EQ(lines_on_disk(path), streamed);
  fs::remove(path);
  EXPECT_FALSE(ForceCsvWriter::open("/nonexistent/dir/force.csv").ok());
}

TEST(Recorder, ForceCsvWriterKeepsRowsWhole) {
  // More rows than the buffer holds: every line on disk is a whole row of 15 columns.
  const fs::path path = fs::temp_directory_path() / "zona_recorder_whole.csv";
  const RunResult r = ramp(2000, 1e-8, 7);
  Result<ForceCsvWriter> w = ForceCsvWriter::open(path.string(), 1e9);
  ASSERT_TRUE(w.ok());
  for (const ForceSample& s : r.samples) ASSERT_TRUE(w->append(s).ok());
  const std::vector<std::string> before_close = lines_on_disk(path);
  EXPECT_GT(before_close.size(), 3u);     // buffer-full flushes happened
  EXPECT_LT(before_close.size(), 2002u);  // and some rows are still buffered
  for (size_t i = 2; i < before_close.size(); ++i)
    EXPECT_EQ(std::count(before_close[i].begin(), before_close[i].end(), ','),
              static_cast<std::ptrdiff_t>(force_csv_columns().size() - 1))
        << i;
  ASSERT_TRUE(w->close().ok());
  EXPECT_EQ(lines_on_disk(path).size(), 2002u);
  fs::remove(path);
}

TEST(Recorder, WriteFileAtomicReplacesTheWholeFile) {
  const fs::path dir = fs::temp_directory_path() / "zona_recorder_atomic";
  fs::create_directories(dir);
  const fs::path path = dir / "summary.json";
  ASSERT_TRUE(write_file_atomic(path.string(), "{\"a\": 1}\n").ok());
  ASSERT_TRUE(write_file_atomic(path.string(), "{\"b\": 2}\n").ok());
  EXPECT_EQ(lines_on_disk(path), std::vector<std::string>{"{\"b\": 2}"});
  EXPECT_FALSE(fs::exists(dir / "summary.json.tmp"));
  // A folder in the way of the rename: an error, the .tmp removed, the folder untouched.
  fs::create_directories(dir / "taken");
  EXPECT_FALSE(write_file_atomic((dir / "taken").string(), "x").ok());
  EXPECT_FALSE(fs::exists(dir / "taken.tmp"));
  EXPECT_TRUE(fs::is_directory(dir / "taken"));
  EXPECT_FALSE(write_file_atomic("/nonexistent/dir/summary.json", "x").ok());
  fs::remove_all(dir);
}

TEST(Recorder, FramesAndSummaryOfAShortRun) {
  const fs::path dir = fs::temp_directory_path() / "zona_recorder_frames";
  fs::create_directories(dir);
  Result<Scene> scene = parse_scene(nlohmann::json::parse(R"({
    "mesh": {"generate": {"diameter": "20 um", "vertices": 120}},
    "materials": {"default": {"young": "10 kPa", "poisson": 0.4, "damping": "100 1/s"}},
    "integrator": {"target_dt": "20 us", "mass_scaling_mode": "selective"},
    "needle": {"tip_radius": "2 um", "standoff": "0.5 um", "speed": "1 mm/s", "max_travel": "2 um"},
    "holding_pipette": {"mode": "fixed", "inner_radius": "5 um"},
    "output": {"frames": 3, "sample_interval": "0.1 ms"}
  })"), "short.json");
  ASSERT_TRUE(scene.ok()) << scene.error().message;
  auto sim = Simulation::create(*scene);
  ASSERT_TRUE(sim.ok());
  FrameRecorder frames(dir.string());
  RunOptions o;
  o.frame = [&](const Simulation& s, int) { ASSERT_TRUE(frames.write(s).ok()); };
  const RunResult run = run_simulation(**sim, o);
  EXPECT_EQ(frames.frame_count(), 3u);
  EXPECT_TRUE(fs::exists(dir / "frames.pvd"));
  EXPECT_TRUE(fs::exists(dir / "frames_000002.vtu"));
  const nlohmann::json j = run_summary_json(**sim, run, compute_training_metrics(run, 20e-6));
  EXPECT_EQ(j["model"], "svk");
  EXPECT_EQ(j["interrupted"], false);
  EXPECT_EQ(j["puncture"]["punctured"], false);
  EXPECT_GT(j["peak_force_N"].get<double>(), 0.0);
  EXPECT_EQ(j["numerics"]["steps"].get<int64_t>(), run.steps);
  EXPECT_EQ(j["numerics"]["mass_scaling_mode"], "selective");
  EXPECT_NEAR(j["training"]["mean_insertion_speed_m_per_s"].get<double>(), 1e-3, 1e-6);
  EXPECT_EQ(j["schema_version"], kOutputSchemaVersion);
  EXPECT_EQ(j["backend_kind"], "cpu");
  EXPECT_EQ(j["solver"], "explicit");
  EXPECT_EQ(j["provenance"]["zona_version"], ZONA_VERSION);
  EXPECT_TRUE(j["provenance"]["machine"]["gpu"].is_null());
  EXPECT_GT(j["provenance"]["machine"]["hardware_threads"].get<int>(), 0);
  // The frames hold the rest positions; the displacement beside them gives the deformed cell.
  Result<Mesh> read = read_mesh((dir / "frames_000002.vtu").string());
  ASSERT_TRUE(read.ok()) << read.error().message;
  ASSERT_EQ(read->vertex_count(), (*sim)->mesh().vertex_count());
  auto same = [](Vec3d a, Vec3d b) { return a.x == b.x && a.y == b.y && a.z == b.z; };
  for (size_t v = 0; v < read->vertex_count(); ++v)
    ASSERT_TRUE(same(read->rest_positions[v], (*sim)->mesh().rest_positions[v])) << v;
  const fs::path last = dir / "last";
  fs::create_directories(last);
  FrameRecorder final_frame(last.string());
  ASSERT_TRUE(final_frame.write(**sim).ok());
  Result<std::vector<Vec3d>> deformed = read_positions((last / "frames_000000.vtu").string());
  ASSERT_TRUE(deformed.ok()) << deformed.error().message;
  double largest = 0;
  for (size_t v = 0; v < deformed->size(); ++v) {
    const Vec3d want = (*sim)->model().rest_positions[v] + (*sim)->state().u[v];
    ASSERT_TRUE(same((*deformed)[v], want)) << v;
    largest = std::max(largest, norm((*sim)->state().u[v]));
  }
  EXPECT_GT(largest, 0.1e-6);  // the needle moved the cell: the two readings differ
  std::ifstream in(last / "frames_000000.vtu");
  const std::string xml((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  EXPECT_NE(xml.find("REST positions"), std::string::npos);
  EXPECT_NE(xml.find("Name=\"TimeValue\""), std::string::npos);
  fs::remove_all(dir);
}

TEST(Recorder, ProvenanceOfThisMachine) {
  const RunProvenance p = local_provenance();
  EXPECT_EQ(p.zona_version, ZONA_VERSION);
  // ISO 8601 UTC: 2026-11-27T10:15:02Z.
  ASSERT_EQ(p.date_utc.size(), 20u) << p.date_utc;
  EXPECT_EQ(p.date_utc[4], '-');
  EXPECT_EQ(p.date_utc[10], 'T');
  EXPECT_EQ(p.date_utc.back(), 'Z');
  EXPECT_FALSE(p.hostname.empty());
  EXPECT_FALSE(p.cpu_model.empty());
  EXPECT_TRUE(p.gpu.empty());
}

TEST(Recorder, RunOutputNames) {
  for (const char* name : {"force.csv", "summary.json", "summary.json.tmp", "scene.json",
                           "force_deformation.png", "force_deformation.svg", "frames.pvd",
                           "frames.pvd.tmp", "frames_000000.vtu", "frames_1234567.vtu",
                           "frames.xdmf", "frames.h5", "frames.xdmf.tmp"})
    EXPECT_TRUE(is_run_output(name)) << name;
  for (const char* name : {"notes.txt", "force.csv.bak", "my_force.csv", "frames_.vtu",
                           "frames_12a.vtu", "frames_000001.vtu.bak", "frames_000001.vtk",
                           "Frames_000001.vtu", "frames.pvd.old", "mesh.vtu", "frames.hdf5",
                           "series.xdmf", "frames_000001.h5", "frames.xmf", "frames.h5.bak"})
    EXPECT_FALSE(is_run_output(name)) << name;
}

TEST(Recorder, RemoveRunOutputsRemovesOnlyZonasFiles) {
  const fs::path dir = fs::temp_directory_path() / "zona_recorder_stale";
  fs::remove_all(dir);
  fs::create_directories(dir / "frames_000005.vtu");  // a user's folder with an output's name
  fs::create_directories(dir / "frames.h5");  // and one named as the XDMF series' data
  for (const char* name : {"force.csv", "summary.json", "frames.pvd", "frames_000000.vtu",
                           "frames_000009.vtu", "notes.txt", "frames_notes.vtu", "mesh.vtu",
                           "frames.xdmf", "run.h5", "series.xdmf"})
    std::ofstream(dir / name) << "x\n";
  std::vector<std::string> removed;
  ASSERT_TRUE(remove_run_outputs(dir.string(), &removed).ok());
  EXPECT_EQ(removed, (std::vector<std::string>{"force.csv", "frames.pvd", "frames.xdmf",
                                               "frames_000000.vtu", "frames_000009.vtu",
                                               "summary.json"}));
  for (const char* name : {"notes.txt", "frames_notes.vtu", "mesh.vtu", "frames_000005.vtu",
                           "frames.h5", "run.h5", "series.xdmf"})
    EXPECT_TRUE(fs::exists(dir / name)) << name;
  for (const std::string& name : removed) EXPECT_FALSE(fs::exists(dir / name)) << name;
  // A folder that does not exist: nothing to do.
  EXPECT_TRUE(remove_run_outputs((dir / "absent").string()).ok());
  fs::remove_all(dir);
}

}  // namespace
}  // namespace zona
