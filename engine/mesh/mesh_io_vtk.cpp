// VTK XML writers for ParaView: .vtu unstructured grids of linear tetrahedra with point and cell
// fields (ASCII or inline base64), and .pvd collections of .vtu frames over time.
#include <bit>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <type_traits>

#include "engine/mesh/mesh_io.h"
#include "engine/mesh/mesh_io_internal.h"

namespace zona {
namespace {

using io_detail::append_int;
using io_detail::append_real;
using io_detail::xml_comment_text;
using io_detail::xml_escape;

constexpr uint8_t kVtkTetra = 10;  // VTK cell type of the linear tetrahedron


// Encodes into space reserved up front: arrays reach hundreds of megabytes, so no per-character
// appends.
void append_base64(std::string& out, const unsigned char* data, size_t n) {
  static constexpr char kAlphabet[] =
      "ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
  const size_t start = out.size();
  out.resize(start + 4 * ((n + 2) / 3));
  char* o = out.data() + start;
  size_t i = 0;
  for (; i + 3 <= n; i += 3, o += 4) {
    const uint32_t v = (uint32_t{data[i]} << 16) | (uint32_t{data[i + 1]} << 8) | data[i + 2];
    o[0] = kAlphabet[(v >> 18) & 63];
    o[1] = kAlphabet[(v >> 12) & 63];
    o[2] = kAlphabet[(v >> 6) & 63];
    o[3] = kAlphabet[v & 63];
  }
  if (i < n) {
    const uint32_t v = (uint32_t{data[i]} << 16) | (i + 1 < n ? uint32_t{data[i + 1]} << 8 : 0);
    o[0] = kAlphabet[(v >> 18) & 63];
    o[1] = kAlphabet[(v >> 12) & 63];
    o[2] = i + 1 < n ? kAlphabet[(v >> 6) & 63] : '=';
    o[3] = '=';
  }
}

template <class T>
const char* vtk_type_name();
template <>
const char* vtk_type_name<double>() { return "Float64"; }
template <>
const char* vtk_type_name<int64_t>() { return "Int64"; }
template <>
const char* vtk_type_name<int32_t>() { return "Int32"; }
template <>
const char* vtk_type_name<uint8_t>() { return "UInt8"; }

// One <DataArray>. Binary: base64 of a UInt64 byte count followed by the raw values, encoded as
// one stream (VTK decodes header and data from a single stream when there is no compression).
// `tuples` >= 0 writes NumberOfTuples (field data arrays need it).
template <class T>
void append_array(std::string& out, const char* name, int components, const T* values,
                  size_t count, bool binary, int64_t tuples = -1) {
  out += "        <DataArray type=\"";
  out += vtk_type_name<T>();
  out += "\"";
  if (name) out += " Name=\"" + xml_escape(name) + "\"";
  if (components != 1) out += " NumberOfComponents=\"" + std::to_string(components) + "\"";
  if (tuples >= 0) out += " NumberOfTuples=\"" + std::to_string(tuples) + "\"";
  out += binary ? " format=\"binary\">\n          " : " format=\"ascii\">\n          ";
  if (binary) {
    const uint64_t bytes = count * sizeof(T);
    std::string raw(sizeof(uint64_t) + bytes, '\0');
    std::memcpy(raw.data(), &bytes, sizeof bytes);
    if (bytes) std::memcpy(raw.data() + sizeof bytes, values, bytes);
    append_base64(out, reinterpret_cast<const unsigned char*>(raw.data()), raw.size());
  } else {
    for (size_t i = 0; i < count; ++i) {
      if constexpr (std::is_floating_point_v<T>)
        append_real(out, values[i]);
      else
        append_int(out, static_cast<int64_t>(values[i]));
      out.push_back((i + 1) % 12 == 0 && i + 1 < count ? '\n' : ' ');
    }
  }
  out += "\n        </DataArray>\n";
}

Status check_fields(const std::vector<VtkField>& fields, size_t count, const char* kind,
                    const std::string& path) {
  for (const VtkField& f : fields) {
    if (f.name.empty()) return make_error("%s: a %s field has no name", path.c_str(), kind);
    if (f.components != 1 && f.components != 3 && f.components != 6 && f.components != 9)
      return make_error("%s: %s field '%s' has %d components (1, 3, 6 or 9 allowed)",
                        path.c_str(), kind, f.name.c_str(), f.components);
    if (f.values.size() != count * static_cast<size_t>(f.components))
      return make_error("%s: %s field '%s' has %zu values; expected %zu x %d", path.c_str(),
                        kind, f.name.c_str(), f.values.size(), count, f.components);
  }
  return {};
}

}  // namespace

Status write_vtu(const std::string& path, const Mesh& mesh, const std::vector<VtkField>& point_data,
                 const std::vector<VtkField>& cell_data, const VtuOptions& options) {
  if (Status s = io_detail::check_mesh_for_write(mesh, path); !s) return s;
  const size_t nv = mesh.vertex_count();
  const size_t nt = mesh.tet_count();
  const std::vector<Vec3d>& positions = options.positions ? *options.positions : mesh.rest_positions;
  if (positions.size() != nv)
    return make_error("%s: %zu positions for %zu vertices", path.c_str(), positions.size(), nv);
  if (Status s = check_fields(point_data, nv, "point", path); !s) return s;
  if (Status s = check_fields(cell_data, nt, "cell", path); !s) return s;
  for (const VtkField& f : options.field_data) {
    const size_t tuples = f.components > 0 ? f.values.size() / static_cast<size_t>(f.components) : 0;
    if (Status s = check_fields({f}, tuples, "field", path); !s) return s;
  }
  const bool bin = options.binary;

  std::string out;
  out.reserve(bin ? 200 + nv * 32 + nt * 60 : 200 + nv * 64 + nt * 64);
  out += "<?xml version=\"1.0\"?>\n<VTKFile type=\"UnstructuredGrid\" version=\"1.0\" byte_order=\"";
  out += std::endian::native == std::endian::little ? "LittleEndian" : "BigEndian";
  out += "\" header_type=\"UInt64\">\n";
  if (!options.comment.empty()) out += "  <!-- " + xml_comment_text(options.comment) + " -->\n";
  out += "  <UnstructuredGrid>\n";
  // Whole-data-set arrays: the caller's, then the region names (VTK string arrays would keep
  // the names more plainly, but meshio cannot read them: one Int32 per name instead).
  std::vector<const Region*> named;
  for (const Region& r : mesh.regions)
    if (!r.name.empty()) named.push_back(&r);
  if (!options.field_data.empty() || !named.empty()) {
    out += "    <FieldData>\n";
    for (const VtkField& f : options.field_data)
      append_array(out, f.name.c_str(), f.components, f.values.data(), f.values.size(), bin,
                   static_cast<int64_t>(f.values.size() / static_cast<size_t>(f.components)));
    for (const Region* r : named)
      append_array(out, ("region:" + r->name).c_str(), 1, &r->tag, 1, bin, 1);
    out += "    </FieldData>\n";
  }
  out += "    <Piece NumberOfPoints=\"" + std::to_string(nv) + "\" NumberOfCells=\"" +
         std::to_string(nt) + "\">\n";

  out += "      <PointData>\n";
  for (const VtkField& f : point_data)
    append_array(out, f.name.c_str(), f.components, f.values.data(), f.values.size(), bin);
  out += "      </PointData>\n      <CellData>\n";
  std::vector<int32_t> region(mesh.tet_region);
  region.resize(nt, 0);
  append_array(out, "region", 1, region.data(), nt, bin);
  for (const VtkField& f : cell_data)
    append_array(out, f.name.c_str(), f.components, f.values.data(), f.values.size(), bin);
  out += "      </CellData>\n";

  // Vec3d is three packed doubles (static_assert below), so the array is x y z per vertex.
  static_assert(sizeof(Vec3d) == 3 * sizeof(double));
  out += "      <Points>\n";
  append_array(out, "Points", 3, reinterpret_cast<const double*>(positions.data()), 3 * nv, bin);
  out += "      </Points>\n      <Cells>\n";
  std::vector<int64_t> connectivity(4 * nt), offsets(nt);
  for (size_t t = 0; t < nt; ++t) {
    for (int k = 0; k < 4; ++k) connectivity[4 * t + k] = mesh.tets[t][k];
    offsets[t] = static_cast<int64_t>(4 * (t + 1));
  }
  const std::vector<uint8_t> types(nt, kVtkTetra);
  append_array(out, "connectivity", 1, connectivity.data(), connectivity.size(), bin);
  append_array(out, "offsets", 1, offsets.data(), nt, bin);
  append_array(out, "types", 1, types.data(), nt, bin);
  out += "      </Cells>\n    </Piece>\n  </UnstructuredGrid>\n</VTKFile>\n";
  return io_detail::write_file(path, out);
}

// ---- .pvd ----

PvdWriter::PvdWriter(std::string pvd_path) : pvd_path_(std::move(pvd_path)) {}

Status PvdWriter::write_frame(double time, const Mesh& mesh,
                              const std::vector<VtkField>& point_data,
                              const std::vector<VtkField>& cell_data, const VtuOptions& options) {
  namespace fs = std::filesystem;
  if (!std::isfinite(time))
    return make_error("%s: frame time %g is not finite", pvd_path_.c_str(), time);
  const fs::path pvd(pvd_path_);
  char index[32];
  std::snprintf(index, sizeof index, "_%06zu.vtu", frames_.size());
  const std::string file = pvd.stem().string() + index;
  if (Status s = write_vtu((pvd.parent_path() / file).string(), mesh, point_data, cell_data,
                           options);
      !s)
    return s;
  frames_.push_back({time, file});
  return rewrite();
}

Status PvdWriter::add_frame(double time, const std::string& vtu_path) {
  namespace fs = std::filesystem;
  if (!std::isfinite(time))
    return make_error("%s: frame time %g is not finite", pvd_path_.c_str(), time);
  // ParaView resolves the file attribute against the .pvd's folder.
  std::error_code ec;
  const fs::path base = fs::absolute(fs::path(pvd_path_), ec).parent_path();
  const fs::path target = fs::absolute(fs::path(vtu_path), ec);
  fs::path rel = ec ? fs::path(vtu_path) : target.lexically_proximate(base);
  frames_.push_back({time, rel.generic_string()});
  return rewrite();
}

Status PvdWriter::rewrite() const {
  std::string out = "<?xml version=\"1.0\"?>\n<VTKFile type=\"Collection\" version=\"0.1\" "
                    "byte_order=\"LittleEndian\">\n  <Collection>\n";
  for (const Frame& f : frames_) {
    out += "    <DataSet timestep=\"";
    append_real(out, f.time);
    out += "\" group=\"\" part=\"0\" file=\"" + xml_escape(f.file) + "\"/>\n";
  }
  out += "  </Collection>\n</VTKFile>\n";
  // Write beside and rename, so a reader never sees a half-written collection.
  const std::string tmp = pvd_path_ + ".tmp";
  if (Status s = io_detail::write_file(tmp, out); !s) return s;
  std::error_code ec;
  std::filesystem::rename(tmp, pvd_path_, ec);
  if (ec) return make_error("%s: cannot replace: %s", pvd_path_.c_str(), ec.message().c_str());
  return {};
}

namespace io_detail {

std::string xml_escape(std::string_view s) {
  std::string out;
  for (char ch : s) {
    switch (ch) {
      case '&': out += "&amp;"; break;
      case '<': out += "&lt;"; break;
      case '>': out += "&gt;"; break;
      case '"': out += "&quot;"; break;
      case '\'': out += "&apos;"; break;
      default:
        out.push_back(static_cast<unsigned char>(ch) < 0x20 ? ' ' : ch);
    }
  }
  return out;
}

std::string xml_comment_text(std::string_view text) {
  // One line, and no "--" (not allowed inside an XML comment).
  std::string note;
  for (char ch : text) {
    if (ch == '\n' || ch == '\r') ch = ' ';
    if (ch == '-' && !note.empty() && note.back() == '-') note.push_back(' ');
    note.push_back(ch);
  }
  return note;
}

}  // namespace io_detail

}  // namespace zona
