// XDMF 3 time series of a tetrahedral mesh: one HDF5 file (.h5) holding the mesh once and each
// frame's arrays, and one XML file (.xdmf, a Temporal collection) that tells ParaView, meshio
// and zona's Python readers where each array lies. For long runs: the mesh is stored once and
// the arrays stay binary, where a VTU series repeats both in base64 text in every frame.
#pragma once

#include <cstdio>
#include <memory>
#include <string>
#include <vector>

#include "engine/core/base.h"
#include "engine/mesh/mesh.h"
#include "engine/mesh/mesh_io.h"

namespace zona {

/// Whether this build writes XDMF + HDF5 (libhdf5 was found when CMake configured it).
bool xdmf_supported();

/// What an XDMF output asked of a build without HDF5 is told (one line, no file name).
inline constexpr const char* kXdmfUnsupportedMessage =
    "XDMF output needs HDF5 and this zona was built without it (Debian's libhdf5-dev: bash "
    "scripts/setup.sh installs it; then rebuild)";

/// Options for XdmfWriter.
struct XdmfOptions {
  /// Whole-series constants of one value each (e.g. "points_at_rest" 1): attributes of the .h5's
  /// root group and, in the .xdmf, an Information element each.
  std::vector<VtkField> field_data;
  /// A note for whoever opens the files: an XML comment after the .xdmf's header and the
  /// .h5 root's string attribute "note".
  std::string comment;
};

namespace xdmf_detail {
/// An open .h5 file (HDF5's handles), defined where HDF5 is (engine/mesh/xdmf_hdf5.cpp).
struct H5Series;
struct H5SeriesCloser {
  void operator()(H5Series* series) const;
};
}  // namespace xdmf_detail

/// Writes a time series as `<stem>.xdmf` + `<stem>.h5`. In the .h5 (dataset shapes as rows x
/// columns; Float64 unless said):
///   /mesh/points   the mesh's rest positions [m], (vertex_count x 3)
///   /mesh/tets     vertex indices, Int64, (tet_count x 4)
///   /mesh/region   region tag per tetrahedron, Int32, (tet_count); region names as Int32
///                  attributes "region:NAME" of /mesh
///   /frames/<i>/<name>  frame i's (six digits) point array (vertex_count x components) or cell
///                  array (tet_count x components); the group's attribute "time_s" [s]
/// The .xdmf has one Uniform grid per frame (its Time, the mesh's Geometry and Topology, an
/// Attribute per array plus the cell array "region"), all inside one Temporal collection, so
/// that readers which take the first grid for the mesh (meshio) find it there.
/// Attribute types: 1 component Scalar, 9 Tensor (row-major), any other count Vector (3, and 6
/// for a symmetric tensor in zona's order xx yy zz xy yz xz, which is not XDMF's Tensor6 order
/// xx xy xz yy yz zz; ParaView's readers take a Vector's columns as its components).
class XdmfWriter {
 public:
  /// Creates (truncates) `xdmf_path` and the .h5 beside it with the mesh. Errors: built without
  /// HDF5, a path that cannot be created, a mesh the writers refuse; each one line naming the
  /// file.
  static Result<XdmfWriter> create(const std::string& xdmf_path, const Mesh& mesh,
                                   XdmfOptions options = {});

  /// Writes frame `time` [s]: the arrays into the .h5 (then flushed to the file), then the
  /// frame's grid into the .xdmf, which is complete XML after every frame. The arrays' names,
  /// counts and components may differ between frames; each must hold vertex_count (point) or
  /// tet_count (cell) tuples. Errors: a wrong size, a name used twice, a failed write.
  Status write_frame(double time, const std::vector<VtkField>& point_data,
                     const std::vector<VtkField>& cell_data);

  /// Closes both files (later writes fail). The destructor does it too, dropping the error.
  Status close();

  const std::string& path() const { return xdmf_path_; }
  const std::string& h5_path() const { return h5_path_; }
  size_t frame_count() const { return frame_count_; }

  XdmfWriter(XdmfWriter&&) noexcept;
  XdmfWriter& operator=(XdmfWriter&&) noexcept;
  ~XdmfWriter();

 private:
  XdmfWriter() = default;
  struct FileCloser {
    void operator()(std::FILE* f) const;
  };
  Status append_grid(double time, const std::vector<VtkField>& point_data,
                     const std::vector<VtkField>& cell_data);

  std::string xdmf_path_, h5_path_;
  std::string h5_name_;  // the .h5's file name, as the .xdmf's DataItems name it (relative)
  size_t vertex_count_ = 0, tet_count_ = 0;
  size_t frame_count_ = 0;
  std::string information_;  // the Information elements of every grid (field data)
  std::unique_ptr<xdmf_detail::H5Series, xdmf_detail::H5SeriesCloser> h5_;
  std::unique_ptr<std::FILE, FileCloser> xml_;
};

}  // namespace zona
