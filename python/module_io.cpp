// zona.read_vtu's C++ half: a .vtu of zona's with every point, cell and field array, through the
// engine's reader (engine/mesh/mesh_io_vtu_read.cpp, read_vtu). Arrays are handed over, not
// copied.
#include <memory>
#include <string>

#include <nanobind/stl/string.h>

#include "engine/mesh/mesh_io.h"
#include "python/module.h"

namespace zona::py {
namespace {

nb::dict read_vtu_dict(const std::string& path) {
  auto file = std::make_shared<VtuFile>(take(read_vtu(path)));
  const size_t np = file->points.size(), nc = file->tets.size();
  nb::dict d;
  d["points"] = positions_view(file->points, file);
  d["tets"] = array_view(reinterpret_cast<const int32_t*>(file->tets.data()), {nc, 4}, file);
  nb::dict regions;
  for (const Region& r : file->regions) regions[r.name.c_str()] = r.tag;
  d["regions"] = regions;
  // Point and cell arrays shaped per tuple: (count), (count x c), tensors (count x 3 x 3).
  auto arrays = [&](const std::vector<VtkField>& fields, size_t count) {
    nb::dict out;
    for (const VtkField& f : fields) {
      std::vector<size_t> shape{count};
      if (f.components == 9) shape = {count, 3, 3};
      else if (f.components > 1) shape = {count, static_cast<size_t>(f.components)};
      out[f.name.c_str()] = array_view(f.values.data(), shape, file);
    }
    return out;
  };
  d["point_data"] = arrays(file->point_data, np);
  d["cell_data"] = arrays(file->cell_data, nc);
  nb::dict field;
  for (const VtkField& f : file->field_data)
    field[f.name.c_str()] = array_view(f.values.data(), {f.values.size()}, file);
  d["field_data"] = field;
  return d;
}

}  // namespace

void add_io(nb::module_& m) {
  m.def("read_vtu", &read_vtu_dict, nb::arg("path"),
        "A .vtu with all its arrays (points as written, tets, point/cell/field data).");
}

}  // namespace zona::py
