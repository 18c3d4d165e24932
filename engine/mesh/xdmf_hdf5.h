// The HDF5 half of XdmfWriter (engine/mesh/xdmf_writer.h): creating the .h5 with the mesh and
// writing a frame's arrays. Two implementations, one linked: xdmf_hdf5.cpp with libhdf5 and
// xdmf_hdf5_none.cpp without it (every call an error), chosen by engine/CMakeLists.txt.
// Internal to engine/mesh; not part of the public API.
#pragma once

#include <memory>
#include <string>
#include <vector>

#include "engine/core/base.h"
#include "engine/mesh/mesh.h"
#include "engine/mesh/mesh_io.h"
#include "engine/mesh/xdmf_writer.h"

namespace zona::xdmf_detail {

using H5SeriesPtr = std::unique_ptr<H5Series, H5SeriesCloser>;

/// Whether libhdf5 is linked (xdmf_supported()).
bool hdf5_available();

/// Creates (truncates) `path` with /mesh/points, /mesh/tets, /mesh/region, the region names
/// as attributes "region:NAME" of /mesh, `options.field_data` (one value each) and the string
/// `options.comment` ("note") as attributes of the root group, then flushes it. The mesh has
/// passed check_mesh_for_write.
Result<H5SeriesPtr> h5_create(const std::string& path, const Mesh& mesh,
                              const XdmfOptions& options);

/// Writes group `/frames/<group>` with attribute "time_s" [s] and one dataset per array, each
/// (tuples x components), or (tuples) for one component; then flushes the file. The arrays'
/// sizes and names have been checked by the caller.
Status h5_write_frame(H5Series& series, const std::string& group, double time,
                      const std::vector<VtkField>& point_data,
                      const std::vector<VtkField>& cell_data);

/// Closes the file; the first failure as an error.
Status h5_close(H5Series& series);

}  // namespace zona::xdmf_detail
