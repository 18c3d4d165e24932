// XdmfWriter: the .xdmf (XML) half of an XDMF 3 time series, written as frames come, and the
// checks on each frame's arrays; the .h5 half is engine/mesh/xdmf_hdf5.cpp.
#include "engine/mesh/xdmf_writer.h"

#include <cerrno>
#include <cstring>
#include <filesystem>
#include <cstdio>
#include <set>
#include <tuple>
#include <utility>

#include "engine/mesh/mesh_io_internal.h"
#include "engine/mesh/xdmf_hdf5.h"

namespace zona {
namespace {

using io_detail::append_int;
using io_detail::append_real;
using io_detail::xml_escape;

// What closes the .xdmf after the last grid. Each frame seeks back over it, writes its grid and
// writes it again: the file is whole XML after every frame, and writing frame n costs one grid,
// not the n grids a rewrite of the whole file would (long runs have thousands of frames).
constexpr std::string_view kTail = "    </Grid>\n  </Domain>\n</Xdmf>\n";

// Any count but 1 and 9 is written as a Vector: ParaView's XDMF (2) reader takes a Vector of c
// columns as c components, but a Matrix as one tuple of every value, and expands a Tensor6 to
// nine components in XDMF's order (xx xy xz yy yz zz), which is not zona's 6-component order
// (xx yy zz xy yz xz). Its Xdmf3 readers take the columns as components whatever the type.
const char* attribute_type(int components) {
  switch (components) {
    case 1: return "Scalar";
    case 9: return "Tensor";
    default: return "Vector";
  }
}

// One DataItem naming a dataset of the .h5: (rows) or (rows x cols).
void append_data_item(std::string& out, size_t rows, int cols, const char* type, int precision,
                      const std::string& h5_name, const std::string& dataset) {
  out += "          <DataItem Dimensions=\"";
  append_int(out, static_cast<int64_t>(rows));
  if (cols != 1) {
    out += ' ';
    append_int(out, cols);
  }
  out += "\" DataType=\"";
  out += type;
  out += "\" Precision=\"";
  append_int(out, precision);
  out += "\" Format=\"HDF\">" + xml_escape(h5_name) + ":" + xml_escape(dataset) + "</DataItem>\n";
}

// A name the .h5 and the .xdmf can both carry: a dataset name of its own ("/" would make a
// path) and no ":" (the DataItem text is FILE:PATH, and readers split at the colon).
Status check_name(const std::string& path, const std::string& name) {
  if (name.empty() || name == "." || name.find_first_of("/:") != std::string::npos)
    return make_error("%s: array name \"%s\" cannot be written (empty, \".\", \"/\" or \":\")",
                      path.c_str(), name.c_str());
  return Status::ok_status();
}

}  // namespace

bool xdmf_supported() { return xdmf_detail::hdf5_available(); }

void XdmfWriter::FileCloser::operator()(std::FILE* f) const { std::fclose(f); }

XdmfWriter::XdmfWriter(XdmfWriter&&) noexcept = default;
XdmfWriter& XdmfWriter::operator=(XdmfWriter&&) noexcept = default;
XdmfWriter::~XdmfWriter() = default;

Result<XdmfWriter> XdmfWriter::create(const std::string& xdmf_path, const Mesh& mesh,
                                      XdmfOptions options) {
  if (!xdmf_supported()) return make_error("%s: %s", xdmf_path.c_str(), kXdmfUnsupportedMessage);
  if (Status s = io_detail::check_mesh_for_write(mesh, xdmf_path); !s) return s.error();
  for (const VtkField& f : options.field_data) {
    if (Status s = check_name(xdmf_path, f.name); !s) return s.error();
    if (f.components != 1 || f.values.size() != 1)
      return make_error("%s: field array \"%s\" must hold one value", xdmf_path.c_str(),
                        f.name.c_str());
  }
  XdmfWriter w;
  w.xdmf_path_ = xdmf_path;
  const std::filesystem::path h5 = std::filesystem::path(xdmf_path).replace_extension(".h5");
  w.h5_path_ = h5.string();
  w.h5_name_ = h5.filename().string();
  w.vertex_count_ = mesh.vertex_count();
  w.tet_count_ = mesh.tet_count();
  Result<xdmf_detail::H5SeriesPtr> series = xdmf_detail::h5_create(w.h5_path_, mesh, options);
  if (!series) return series.error();
  w.h5_ = std::move(series).value();

  // The series' constants and region names, repeated in every grid (an Information element
  // belongs to the grid it is in).
  for (const VtkField& f : options.field_data) {
    w.information_ += "        <Information Name=\"" + xml_escape(f.name) + "\" Value=\"";
    append_real(w.information_, f.values[0]);
    w.information_ += "\"/>\n";
  }
  for (const Region& r : mesh.regions) {
    if (r.name.empty()) continue;
    w.information_ += "        <Information Name=\"region:" + xml_escape(r.name) + "\" Value=\"";
    append_int(w.information_, r.tag);
    w.information_ += "\"/>\n";
  }

  w.xml_.reset(std::fopen(xdmf_path.c_str(), "w"));
  if (!w.xml_)
    return make_error("%s: cannot open for writing: %s", xdmf_path.c_str(), std::strerror(errno));
  std::string head = "<?xml version=\"1.0\"?>\n";
  if (!options.comment.empty())
    head += "<!-- " + io_detail::xml_comment_text(options.comment) + " -->\n";
  head +=
      "<Xdmf Version=\"3.0\">\n  <Domain>\n"
      "    <Grid Name=\"frames\" GridType=\"Collection\" CollectionType=\"Temporal\">\n";
  head += kTail;
  if (std::fwrite(head.data(), 1, head.size(), w.xml_.get()) != head.size() ||
      std::fflush(w.xml_.get()) != 0)
    return make_error("%s: write failed: %s", xdmf_path.c_str(), std::strerror(errno));
  return w;
}

Status XdmfWriter::write_frame(double time, const std::vector<VtkField>& point_data,
                               const std::vector<VtkField>& cell_data) {
  if (!xml_ || !h5_) return make_error("%s: frame written after close", xdmf_path_.c_str());
  // Sizes and names first: a frame is written whole or not at all.
  std::set<std::string> names = {"region"};  // the cell array every grid names (/mesh/region)
  for (const auto& [fields, count] :
       {std::pair{&point_data, vertex_count_}, std::pair{&cell_data, tet_count_}})
    for (const VtkField& f : *fields) {
      if (Status s = check_name(xdmf_path_, f.name); !s) return s;
      if (!names.insert(f.name).second)
        return make_error("%s: array \"%s\" given twice in a frame", xdmf_path_.c_str(),
                          f.name.c_str());
      if (f.components < 1 || f.values.size() != count * static_cast<size_t>(f.components))
        return make_error("%s: array \"%s\" has %zu values, expected %zu x %d",
                          xdmf_path_.c_str(), f.name.c_str(), f.values.size(), count,
                          f.components);
    }
  char group[32];
  std::snprintf(group, sizeof group, "%06zu", frame_count_);
  if (Status s = xdmf_detail::h5_write_frame(*h5_, group, time, point_data, cell_data); !s)
    return s;
  if (Status s = append_grid(time, point_data, cell_data); !s) return s;
  ++frame_count_;
  return Status::ok_status();
}

Status XdmfWriter::append_grid(double time, const std::vector<VtkField>& point_data,
                               const std::vector<VtkField>& cell_data) {
  char group[32];
  std::snprintf(group, sizeof group, "%06zu", frame_count_);
  const std::string frame_path = std::string("/frames/") + group + "/";
  // The mesh's Geometry and Topology in every grid (not an xi:include of the first grid's):
  // each grid reads on its own, in ParaView, meshio and any XDMF reader.
  std::string out = "      <Grid Name=\"frame_" + std::string(group) + "\" GridType=\"Uniform\">\n";
  out += "        <Time Value=\"";
  append_real(out, time);
  out += "\"/>\n" + information_;
  out += "        <Topology TopologyType=\"Tetrahedron\" NumberOfElements=\"";
  append_int(out, static_cast<int64_t>(tet_count_));
  out += "\" NodesPerElement=\"4\">\n";
  append_data_item(out, tet_count_, 4, "Int", 8, h5_name_, "/mesh/tets");
  out += "        </Topology>\n        <Geometry GeometryType=\"XYZ\">\n";
  append_data_item(out, vertex_count_, 3, "Float", 8, h5_name_, "/mesh/points");
  out += "        </Geometry>\n";
  for (const auto& [fields, center, rows] : {std::tuple{&point_data, "Node", vertex_count_},
                                             std::tuple{&cell_data, "Cell", tet_count_}})
    for (const VtkField& f : *fields) {
      out += "        <Attribute Name=\"" + xml_escape(f.name) + "\" AttributeType=\"" +
             attribute_type(f.components) + "\" Center=\"" + center + "\">\n";
      append_data_item(out, rows, f.components, "Float", 8, h5_name_, frame_path + f.name);
      out += "        </Attribute>\n";
    }
  out += "        <Attribute Name=\"region\" AttributeType=\"Scalar\" Center=\"Cell\">\n";
  append_data_item(out, tet_count_, 1, "Int", 4, h5_name_, "/mesh/region");
  out += "        </Attribute>\n      </Grid>\n";
  out += kTail;
  std::FILE* f = xml_.get();
  if (std::fseek(f, -static_cast<long>(kTail.size()), SEEK_END) != 0 ||
      std::fwrite(out.data(), 1, out.size(), f) != out.size() || std::fflush(f) != 0)
    return make_error("%s: write failed: %s", xdmf_path_.c_str(), std::strerror(errno));
  return Status::ok_status();
}

Status XdmfWriter::close() {
  Status st;
  if (h5_) st = xdmf_detail::h5_close(*h5_);
  h5_.reset();
  if (xml_ && std::fclose(xml_.release()) != 0 && st.ok())
    st = make_error("%s: write failed: %s", xdmf_path_.c_str(), std::strerror(errno));
  return st;
}

}  // namespace zona
