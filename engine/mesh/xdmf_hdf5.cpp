// XdmfWriter's HDF5 half with libhdf5 (the C API, Debian's libhdf5-dev): the .h5 of an XDMF
// series, its mesh written once and each frame's arrays as contiguous little-endian datasets.
#include <hdf5.h>

#include <cstdint>
#include <string>
#include <vector>

#include "engine/mesh/xdmf_hdf5.h"

namespace zona::xdmf_detail {

struct H5Series {
  std::string path;
  hid_t file = H5I_INVALID_HID;
  hid_t frames = H5I_INVALID_HID;  // the group "/frames"
};

namespace {

// An HDF5 handle closed at scope exit by the matching H5?close (H5Oclose for groups and data
// sets, H5Sclose, H5Aclose, H5Tclose): every early return stays leak-free.
class Handle {
 public:
  Handle(hid_t id, herr_t (*close)(hid_t)) : id_(id), close_(close) {}
  Handle(const Handle&) = delete;
  Handle& operator=(const Handle&) = delete;
  ~Handle() {
    if (id_ >= 0) close_(id_);
  }
  hid_t get() const { return id_; }
  bool ok() const { return id_ >= 0; }

 private:
  hid_t id_;
  herr_t (*close_)(hid_t);
};

Error h5_error(const std::string& path, const std::string& what) {
  return make_error("%s: HDF5: cannot %s", path.c_str(), what.c_str());
}

// A dataset `name` in `parent` of `rows` x `cols` (cols 1: one dimension) written from `data`
// in memory type `mem_type`, stored as `file_type`.
Status write_dataset(const std::string& path, hid_t parent, const std::string& name,
                     hid_t file_type, hid_t mem_type, const void* data, hsize_t rows,
                     hsize_t cols) {
  const hsize_t dims[2] = {rows, cols};
  Handle space(H5Screate_simple(cols == 1 ? 1 : 2, dims, nullptr), H5Sclose);
  if (!space.ok()) return h5_error(path, "make the dataspace of " + name);
  Handle set(H5Dcreate2(parent, name.c_str(), file_type, space.get(), H5P_DEFAULT, H5P_DEFAULT,
                        H5P_DEFAULT),
             H5Dclose);
  if (!set.ok()) return h5_error(path, "create dataset " + name);
  // An empty array has nothing to write (and HDF5 takes no null buffer).
  if (rows * cols > 0 && H5Dwrite(set.get(), mem_type, H5S_ALL, H5S_ALL, H5P_DEFAULT, data) < 0)
    return h5_error(path, "write dataset " + name);
  return Status::ok_status();
}

Status write_attribute(const std::string& path, hid_t object, const std::string& name,
                       hid_t file_type, hid_t mem_type, const void* value) {
  Handle space(H5Screate(H5S_SCALAR), H5Sclose);
  Handle attr(H5Acreate2(object, name.c_str(), file_type, space.get(), H5P_DEFAULT, H5P_DEFAULT),
              H5Aclose);
  if (!space.ok() || !attr.ok() || H5Awrite(attr.get(), mem_type, value) < 0)
    return h5_error(path, "write attribute " + name);
  return Status::ok_status();
}

Status write_string_attribute(const std::string& path, hid_t object, const std::string& name,
                              const std::string& text) {
  // A fixed-length string of the text's size (h5py reads it as bytes; zona's reader decodes).
  Handle type(H5Tcopy(H5T_C_S1), H5Tclose);
  if (!type.ok() || H5Tset_size(type.get(), text.empty() ? 1 : text.size()) < 0)
    return h5_error(path, "make the string type of attribute " + name);
  const std::string value = text.empty() ? std::string(1, '\0') : text;
  return write_attribute(path, object, name, type.get(), type.get(), value.data());
}

}  // namespace

void H5SeriesCloser::operator()(H5Series* series) const {
  if (series) (void)h5_close(*series);
  delete series;
}

bool hdf5_available() { return true; }

Result<H5SeriesPtr> h5_create(const std::string& path, const Mesh& mesh,
                              const XdmfOptions& options) {
  // HDF5 prints its error stack to stderr by default; the errors here are one line each.
  H5Eset_auto2(H5E_DEFAULT, nullptr, nullptr);
  H5SeriesPtr series(new H5Series);
  series->path = path;
  series->file = H5Fcreate(path.c_str(), H5F_ACC_TRUNC, H5P_DEFAULT, H5P_DEFAULT);
  if (series->file < 0) return h5_error(path, "create the file");

  // The mesh, once: rest positions, tetrahedra, region tags.
  Handle mesh_group(H5Gcreate2(series->file, "mesh", H5P_DEFAULT, H5P_DEFAULT, H5P_DEFAULT),
                    H5Gclose);
  if (!mesh_group.ok()) return h5_error(path, "create group /mesh");
  std::vector<double> points(3 * mesh.vertex_count());
  for (size_t v = 0; v < mesh.vertex_count(); ++v)
    for (int k = 0; k < 3; ++k) points[3 * v + static_cast<size_t>(k)] = mesh.rest_positions[v][k];
  std::vector<int64_t> tets(4 * mesh.tet_count());
  for (size_t t = 0; t < mesh.tet_count(); ++t)
    for (int k = 0; k < 4; ++k) tets[4 * t + static_cast<size_t>(k)] = mesh.tets[t][static_cast<size_t>(k)];
  // A mesh without tags is one region, tag 0 (as write_vtu writes it).
  std::vector<int32_t> region = mesh.tet_region;
  region.resize(mesh.tet_count(), 0);
  if (Status s = write_dataset(path, mesh_group.get(), "points", H5T_IEEE_F64LE,
                               H5T_NATIVE_DOUBLE, points.data(), mesh.vertex_count(), 3);
      !s)
    return s.error();
  if (Status s = write_dataset(path, mesh_group.get(), "tets", H5T_STD_I64LE, H5T_NATIVE_INT64,
                               tets.data(), mesh.tet_count(), 4);
      !s)
    return s.error();
  if (Status s = write_dataset(path, mesh_group.get(), "region", H5T_STD_I32LE, H5T_NATIVE_INT32,
                               region.data(), mesh.tet_count(), 1);
      !s)
    return s.error();
  for (const Region& r : mesh.regions)
    if (!r.name.empty())
      if (Status s = write_attribute(path, mesh_group.get(), "region:" + r.name, H5T_STD_I32LE,
                                     H5T_NATIVE_INT32, &r.tag);
          !s)
        return s.error();

  // The series' constants and note on the root group.
  for (const VtkField& f : options.field_data)
    if (!f.values.empty())
      if (Status s = write_attribute(path, series->file, f.name, H5T_IEEE_F64LE,
                                     H5T_NATIVE_DOUBLE, f.values.data());
          !s)
        return s.error();
  if (!options.comment.empty())
    if (Status s = write_string_attribute(path, series->file, "note", options.comment); !s)
      return s.error();

  series->frames = H5Gcreate2(series->file, "frames", H5P_DEFAULT, H5P_DEFAULT, H5P_DEFAULT);
  if (series->frames < 0) return h5_error(path, "create group /frames");
  if (H5Fflush(series->file, H5F_SCOPE_GLOBAL) < 0) return h5_error(path, "flush the file");
  return series;
}

Status h5_write_frame(H5Series& series, const std::string& group, double time,
                      const std::vector<VtkField>& point_data,
                      const std::vector<VtkField>& cell_data) {
  const std::string& path = series.path;
  if (series.file < 0) return make_error("%s: written after close", path.c_str());
  Handle g(H5Gcreate2(series.frames, group.c_str(), H5P_DEFAULT, H5P_DEFAULT, H5P_DEFAULT),
           H5Gclose);
  if (!g.ok()) return h5_error(path, "create group /frames/" + group);
  if (Status s = write_attribute(path, g.get(), "time_s", H5T_IEEE_F64LE, H5T_NATIVE_DOUBLE, &time);
      !s)
    return s;
  for (const std::vector<VtkField>* fields : {&point_data, &cell_data})
    for (const VtkField& f : *fields) {
      const auto cols = static_cast<hsize_t>(f.components);
      if (Status s = write_dataset(path, g.get(), f.name, H5T_IEEE_F64LE, H5T_NATIVE_DOUBLE,
                                   f.values.data(), f.values.size() / cols, cols);
          !s)
        return s;
    }
  // On disk after every frame: a run stopped later leaves a readable file up to here.
  if (H5Fflush(series.file, H5F_SCOPE_GLOBAL) < 0) return h5_error(path, "flush the file");
  return Status::ok_status();
}

Status h5_close(H5Series& series) {
  if (series.file < 0) return Status::ok_status();
  bool ok = true;
  if (series.frames >= 0) ok = H5Gclose(series.frames) >= 0;
  ok = H5Fclose(series.file) >= 0 && ok;
  series.frames = series.file = H5I_INVALID_HID;
  return ok ? Status::ok_status() : Status(h5_error(series.path, "close the file"));
}

}  // namespace zona::xdmf_detail
