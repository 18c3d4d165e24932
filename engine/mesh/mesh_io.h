// Mesh files: Gmsh .msh (2.2 / 4.1, ASCII / binary), TetGen .node/.ele and VTK .vtu (the
// tetrahedra zona writes) readers; Gmsh 4.1, VTK .vtu and ParaView .pvd writers.
//
// Readers never trust the file: every count is checked against the bytes that remain before
// anything is reserved, every index against its range, every number for syntax and finiteness.
// A malformed file gives one Error line "<path>:<line>: <what>" (binary sections: "<path>:byte
// <offset>: <what>"); never a crash, a hang or an unbounded allocation.
#pragma once

#include <string>
#include <string_view>
#include <vector>

#include "engine/core/base.h"
#include "engine/mesh/mesh.h"
#include "engine/core/vec.h"

namespace zona {

/// Options for the mesh readers.
struct ReadMeshOptions {
  /// Multiplies every coordinate: 1e-6 for a file written in micrometres [m per file unit].
  double scale = 1.0;
  /// Passed to validate_mesh after reading (inverted elements, degenerate volumes, ...).
  ValidateOptions validate{};
};

/// Reads a tetrahedral mesh, choosing the format by extension: `.msh` (Gmsh 2.x or 4.1, ASCII
/// or binary, either byte order), `.node` (TetGen; its `.ele` lies beside it with the same
/// stem; naming the `.ele` works too) or `.vtu` (a VTK XML UnstructuredGrid of linear
/// tetrahedra as write_vtu writes it: one piece, ascii or inline base64 arrays, uncompressed,
/// little-endian; anything else is refused with one line naming what is not supported). Only
/// linear tetrahedra (Gmsh type 4, the first four corners of TetGen's 10-node elements, VTK
/// type 10) are kept; vertices that no tetrahedron uses are dropped and the rest renumbered
/// compactly in file order. Regions: Gmsh physical tags (the tag of each tetrahedron's volume
/// entity in 4.1, the first element tag in 2.x; 0 when absent) with names from $PhysicalNames;
/// TetGen's first element attribute (its region attribute under `tetgen -A`), which must be an
/// integer; the VTU cell array "region" with names from the field arrays "region:NAME". A
/// VTU's points are taken as they are (zona's frames hold the rest positions). The result has
/// passed validate_mesh(); its warnings (and the reader's, e.g. dropped vertices) are appended
/// to `warnings` when given.
Result<Mesh> read_mesh(const std::string& path, const ReadMeshOptions& options = {},
                       std::vector<std::string>* warnings = nullptr);

/// Reads only vertex positions [m] (scaled by options.scale), (vertex_count), from any file
/// read_mesh reads, numbered as read_mesh numbers them; a file without tetrahedra (a TetGen
/// `.node` with no `.ele` beside it, a `.msh` with nodes only) gives every point in file order.
/// No mesh validation runs, so a deformed configuration with inverted elements still loads.
/// A `.vtu` frame of zona's (field array "points_at_rest" 1 and a 3-component point array
/// "displacement") gives its deformed positions, points + displacement.
Result<std::vector<Vec3d>> read_positions(const std::string& path,
                                          const ReadMeshOptions& options = {});

/// Parses a Gmsh .msh held in memory; `name` stands for the path in messages.
Result<Mesh> read_gmsh_from_memory(std::string_view data, const std::string& name,
                                   const ReadMeshOptions& options = {},
                                   std::vector<std::string>* warnings = nullptr);

/// Parses a TetGen mesh held in memory: the `.node` text and the `.ele` text, named in
/// messages by `node_name` and `ele_name`.
Result<Mesh> read_tetgen_from_memory(std::string_view node, std::string_view ele,
                                     const std::string& node_name, const std::string& ele_name,
                                     const ReadMeshOptions& options = {},
                                     std::vector<std::string>* warnings = nullptr);

/// Parses a TetGen `.node` held in memory into its points [m] (scaled), (point_count).
Result<std::vector<Vec3d>> read_tetgen_node_from_memory(std::string_view node,
                                                        const std::string& name,
                                                        const ReadMeshOptions& options = {});

/// Writes Gmsh MSH 4.1 (ASCII, or binary in native byte order), positions in metres. Each
/// region becomes one volume entity carrying its tag as physical tag (tag 0: no physical tag)
/// and its name in $PhysicalNames, so read_mesh gives back the same mesh. Tags must be >= 0.
Status write_gmsh41(const std::string& path, const Mesh& mesh, bool binary = false);

/// A named per-point or per-cell array for VTK output.
struct VtkField {
  std::string name;
  /// 1 (scalar), 3 (vector), 6 (symmetric tensor xx yy zz xy yz xz) or 9 (tensor, row-major).
  int components = 1;
  std::vector<double> values;  ///< (count x components), count = vertices or tetrahedra
};

/// Options for write_vtu.
struct VtuOptions {
  /// Positions to write instead of the rest positions (e.g. deformed) [m], (vertex_count);
  /// null writes the rest positions.
  const std::vector<Vec3d>* positions = nullptr;
  /// Base64 inline binary (compact, what ParaView writes) or plain ASCII.
  bool binary = true;
  /// Arrays of the whole data set (VTK FieldData), any number of tuples of `components` each
  /// (e.g. "TimeValue", the frame's time [s], which ParaView shows as the data set's time).
  std::vector<VtkField> field_data;
  /// A note for whoever opens the file, written as an XML comment after the header (one line;
  /// "--" is replaced: XML comments cannot hold it).
  std::string comment;
};

/// Writes a VTK XML UnstructuredGrid (.vtu) of linear tetrahedra with the given point and cell
/// fields, plus a cell field "region" with each tetrahedron's tag and, per named region, a
/// one-value Int32 field array "region:NAME" holding its tag (read_mesh reads the names back).
Status write_vtu(const std::string& path, const Mesh& mesh,
                 const std::vector<VtkField>& point_data = {},
                 const std::vector<VtkField>& cell_data = {}, const VtuOptions& options = {});

/// A `.vtu` as the file holds it, with every data array (read_vtu). Nothing is dropped or
/// renumbered (read_mesh drops unused points), so the point arrays stay aligned with `points`.
struct VtuFile {
  std::vector<Vec3d> points;         ///< as written, no scale [file units], (point_count)
  std::vector<Tet> tets;             ///< point indices, (cell_count)
  std::vector<Region> regions;       ///< names of region tags, from the "region:NAME" fields
  std::vector<VtkField> point_data;  ///< in file order, each (point_count x components)
  std::vector<VtkField> cell_data;   ///< in file order ("region" among them), (cell_count x c)
  std::vector<VtkField> field_data;  ///< in file order (TimeValue, points_at_rest, region:NAME)
};

/// Reads a `.vtu` with all its point, cell and field arrays (the files read_mesh reads: one
/// piece of linear tetrahedra, inline ascii or base64, uncompressed, little-endian). Errors are
/// one line naming the file and line, as read_mesh's.
Result<VtuFile> read_vtu(const std::string& path);

/// Writes a mesh choosing the format by extension: `.msh` (Gmsh 4.1 ASCII) or `.vtu`.
Status write_mesh(const std::string& path, const Mesh& mesh);

/// A ParaView time series: a `.pvd` collection of `.vtu` frames. The collection file is
/// rewritten after every frame, so it is complete and openable even if the run stops early.
class PvdWriter {
 public:
  /// Frames go to "<pvd stem>_<index>.vtu" beside the .pvd file.
  explicit PvdWriter(std::string pvd_path);

  /// Writes frame `time` [s] as a .vtu (see write_vtu) and adds it to the collection.
  Status write_frame(double time, const Mesh& mesh, const std::vector<VtkField>& point_data = {},
                     const std::vector<VtkField>& cell_data = {}, const VtuOptions& options = {});

  /// Adds an existing .vtu file written elsewhere at `time` [s]; stored relative to the .pvd.
  Status add_frame(double time, const std::string& vtu_path);

  /// Path of the .pvd file.
  const std::string& path() const { return pvd_path_; }
  /// Number of frames in the collection.
  size_t frame_count() const { return frames_.size(); }

 private:
  struct Frame {
    double time;
    std::string file;  // relative to the .pvd's folder when possible
  };
  Status rewrite() const;

  std::string pvd_path_;
  std::vector<Frame> frames_;
};

}  // namespace zona
