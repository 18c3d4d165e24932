// What a run leaves behind: force.csv (the recorded curve), summary.json (model, puncture, peak
// force, training metrics, numerics, provenance), and VTU frames (rest positions with the
// displacement, strain and stress at the vertices and per tetrahedron; Hajiyavand et al. 2019 Fig. 14) in a
// ParaView .pvd series; and the clean-up of an earlier run's outputs in the same folder.
#pragma once

#include <cstdio>
#include <memory>
#include <optional>
#include <span>
#include <string>
#include <vector>

#include <nlohmann/json_fwd.hpp>

#include "engine/core/base.h"
#include "engine/mesh/mesh_io.h"
#include "engine/mesh/xdmf_writer.h"
#include "engine/sim/simulation.h"

namespace zona {

/// Version of the output schema: force.csv's columns (its first line, "# zona force.csv schema
/// N") and summary.json's keys ("schema_version"), as docs/outputs.md lists them. Raised when a
/// column or key changes meaning or goes; new columns and keys come at the end and raise it too.
inline constexpr int kOutputSchemaVersion = 7;

/// Training metrics of one insertion (Hajiyavand et al. 2019's measures).
struct TrainingMetrics {
  /// Mean needle speed from the start to puncture (or the end of the run) [m/s].
  double mean_insertion_speed = 0;
  /// Deformation at puncture over the cell diameter along the needle axis [%]; 0 without puncture.
  double deformation_percent = 0;
  /// Hajiyavand et al. 2019's maximum force amplitude ratio (MFAR) [%]: the largest deviation of the force
  /// from its moving average over the loading phase (first contact to puncture), over the peak
  /// force. The window is `fluctuation_window` of the loading phase's duration.
  double force_fluctuation_percent = 0;
  double fluctuation_window = 0.05;  ///< [-]
};

/// Names of the step flags set in `status` ("inverted elements", "clamped elements", ...), for
/// a run's whole history (describe_step_status describes one step with its counts).
std::vector<std::string> step_flag_names(StepStatus status);

/// Computes the metrics from a run's samples (cell_diameter [m] along the needle axis).
TrainingMetrics compute_training_metrics(const RunResult& run, double cell_diameter,
                                         double fluctuation_window = 0.05);

/// The force.csv header, one name per column (time_s, needle_travel_m, deformation_m, force_N,
/// force_x_N, force_y_N, force_z_N, holding_force_N, contacts, elastic_energy_J,
/// kinetic_energy_J, punctured, raw_force_N). force_N is the filtered axial force
/// (needle.force_filter), raw_force_N the same before the filter.
const std::vector<std::string>& force_csv_columns();

/// Writes the samples as CSV with force_csv_columns(), full double precision.
Status write_force_csv(const std::string& path, std::span<const ForceSample> samples);

/// force.csv written as the run goes (RunOptions::on_sample): the header at open, then one row
/// per append, so that a run stopped half-way (signal, crash, power) leaves its curve up to
/// there. Rows are formatted into a buffer sized at open and written whole, one write per
/// flush, so the file never ends in half a row unless the write itself is cut; a flush happens
/// at the first append and then whenever `flush_interval` of wall time has passed, the buffer
/// is full, or close() is called.
class ForceCsvWriter {
 public:
  /// Creates (truncates) `path` and writes the header. Errors: cannot open, write failed.
  static Result<ForceCsvWriter> open(const std::string& path, double flush_interval = 0.5);
  /// Appends one row (flushing as described above). After a failed write every later call
  /// returns the same error.
  Status append(const ForceSample& sample);
  /// Writes what is buffered to the file.
  Status flush();
  /// Flushes and closes; later appends fail.
  Status close();
  const std::string& path() const { return path_; }

  ForceCsvWriter(ForceCsvWriter&&) noexcept = default;
  // No assignment: it would close an open file without flushing its buffered rows.
  ForceCsvWriter& operator=(ForceCsvWriter&&) = delete;
  ~ForceCsvWriter();  ///< close(), its error dropped: call close() to see it

 private:
  ForceCsvWriter() = default;
  struct FileCloser {
    void operator()(std::FILE* f) const;
  };
  std::unique_ptr<std::FILE, FileCloser> file_;
  std::string path_;
  std::vector<char> buffer_;  // formatted rows not yet written, (capacity fixed at open)
  size_t used_ = 0;
  double flush_interval_ = 0.5;   // [s] of wall time
  int64_t last_flush_ns_ = 0;     // steady clock [ns]; 0: never flushed a row
  std::string error_;             // first write error, empty while fine
};

/// Writes `text` to `path` atomically: into `path`.tmp, flushed to disk, then renamed over
/// `path`, so a reader (or a run killed while writing) sees the old file or the new one, never
/// half of one. The .tmp is removed on failure.
Status write_file_atomic(const std::string& path, const std::string& text);

/// Where, when and by what a run was made (summary.json "provenance", docs/outputs.md).
struct RunProvenance {
  std::string zona_version;   ///< ZONA_VERSION
  std::string commit;         ///< source commit of the build, "+dirty" when it had edits; "" unknown
  std::string command;        ///< the command line ("" when not run from one)
  std::string date_utc;       ///< ISO 8601, e.g. "2026-11-27T10:15:02Z"
  std::string hostname;
  std::string cpu_model;      ///< /proc/cpuinfo "model name"; "unknown CPU" without it
  int hardware_threads = 0;   ///< std::thread::hardware_concurrency()
  std::string gpu;            ///< the GPU the CUDA backend ran on; "" when it did not run
};

/// This machine now: version, date, hostname, CPU model and threads (commit, command and GPU
/// are the caller's: the build stamp and argv live in the program, devices in kernels/).
RunProvenance local_provenance();

/// The summary of a run: scene and model, interrupted (the run was stopped by
/// RunOptions::stop before its end), puncture {time_s, needle_travel_m, deformation_m,
/// force_N}, peak_force_N, training metrics, numerics (steps, dt, mass scaling, wall time),
/// backend_kind ("cpu" or "cuda"), solver ("explicit") and `provenance`.
nlohmann::json run_summary_json(const Simulation& simulation, const RunResult& run,
                                const TrainingMetrics& metrics,
                                const RunProvenance& provenance = local_provenance());

/// Per-frame fields. Point: "displacement" [m] (3), "contact" (1: 1 needle, 2 holding rim, 0
/// free; zeros here, marked by the simulation's overload), "stress" [Pa] (9, Cauchy,
/// row-major), "strain" [-] (9, Green-Lagrange, row-major),
/// "von_mises" [Pa] (1, of the vertex's "stress"); the vertex tensors are means over the
/// tetrahedra around the vertex weighted by their rest volume; under nodal pressure (Model::
/// nodal_pressure) the element part of the stress is averaged and the vertex's own pressure
/// lambda_v (Jbar_v - 1) added. Cell: "green_strain" [-] (6: xx yy zz xy yz xz),
/// "von_mises_stress" [Pa] (1). Cauchy stress of the model's law: F S F^T / J for SVK, P F^T /
/// J for the stable neo-Hookean law, the small-strain stress for linear; an inverted element
/// (J <= 0) gives the Kirchhoff stress J sigma (F S F^T or P F^T), symmetric and defined.
void frame_fields(const Model& model, const State& state, std::vector<VtkField>* point_data,
                  std::vector<VtkField>* cell_data);

/// frame_fields of a simulation's current state.
void frame_fields(const Simulation& simulation, std::vector<VtkField>* point_data,
                  std::vector<VtkField>* cell_data);

/// The note each frame carries (an XML comment) and docs/outputs.md repeats.
inline constexpr const char* kFramePointsNote =
    "zona frame: the points are the REST positions; the deformed cell is points + the point "
    "array 'displacement' (ParaView: Warp By Vector, vectors displacement, scale factor 1). "
    "Field arrays: TimeValue [s], points_at_rest = 1. docs/outputs.md lists every array.";

/// The same note in an XDMF series (an XML comment in the .xdmf, the .h5 root's "note").
inline constexpr const char* kSeriesPointsNote =
    "zona frames: the Geometry (/mesh/points) is the REST positions; the deformed cell is "
    "Geometry + the point attribute 'displacement' (ParaView: Warp By Vector, vectors "
    "displacement, scale factor 1). points_at_rest = 1 (an Information element of each grid, an "
    "attribute of the .h5 root). docs/outputs.md lists every array.";

/// Writes frames of a simulation into its output folder DIR, in `format`: VTU as DIR/frames.pvd
/// + DIR/frames_<i>.vtu, XDMF as DIR/frames.xdmf + DIR/frames.h5 (XdmfWriter's layout,
/// engine/mesh/xdmf_writer.h). Either way the points are the rest positions with
/// frame_fields' arrays (the displacement among them), the field data "points_at_rest" (1) and
/// the note kFramePointsNote; the VTU frames carry "TimeValue" [s] too, the XDMF grids their
/// Time. The XDMF files are created at the first write (the mesh is the simulation's).
class FrameRecorder {
 public:
  explicit FrameRecorder(const std::string& directory, FrameFormat format = FrameFormat::kVtu);
  /// Writes the simulation's current state as the next frame. Errors: a failed write; XDMF in
  /// a build without HDF5 (kXdmfUnsupportedMessage).
  Status write(const Simulation& simulation);
  /// Closes the XDMF files (the destructor does it too, dropping the error).
  Status close();
  const std::string& pvd_path() const { return pvd_.path(); }
  std::string xdmf_path() const;
  size_t frame_count() const { return frame_count_; }

 private:
  std::string directory_;
  FrameFormat format_;
  PvdWriter pvd_;
  std::optional<XdmfWriter> xdmf_;
  size_t frame_count_ = 0;
  std::vector<VtkField> point_data_, cell_data_;
};

/// Whether `file_name` (no folder) is one of the outputs `zona run` writes into its output
/// folder: force.csv, summary.json, scene.json, force_deformation.png and .svg, frames.pvd,
/// frames_<digits>.vtu, frames.xdmf, frames.h5, or the ".tmp" of one of them (atomic writes).
bool is_run_output(const std::string& file_name);

/// Removes from `directory` the files is_run_output names (an earlier run's outputs, so that a
/// rerun with fewer frames leaves none of the old ones beside its own) and nothing else: no
/// folder, no other file. The names removed are appended to `removed` when given. A folder that
/// does not exist holds nothing to remove. Errors: a listed file that cannot be removed.
Status remove_run_outputs(const std::string& directory,
                          std::vector<std::string>* removed = nullptr);

}  // namespace zona
