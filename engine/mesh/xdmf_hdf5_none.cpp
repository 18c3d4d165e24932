// XdmfWriter's HDF5 half in a build without libhdf5: every call says so (kXdmfUnsupportedMessage),
// so that an XDMF output is refused with a reason, never skipped.
#include "engine/mesh/xdmf_hdf5.h"

namespace zona::xdmf_detail {

struct H5Series {};

void H5SeriesCloser::operator()(H5Series* series) const { delete series; }

bool hdf5_available() { return false; }

Result<H5SeriesPtr> h5_create(const std::string& path, const Mesh&, const XdmfOptions&) {
  return make_error("%s: %s", path.c_str(), kXdmfUnsupportedMessage);
}

Status h5_write_frame(H5Series&, const std::string&, double, const std::vector<VtkField>&,
                      const std::vector<VtkField>&) {
  return make_error("%s", kXdmfUnsupportedMessage);
}

Status h5_close(H5Series&) { return Status::ok_status(); }

}  // namespace zona::xdmf_detail
