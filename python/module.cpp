// The extension `zona._zona` (nanobind): scenes, the cell mesher, elastic forces and the mesh
// readers here; the run in module_run.cpp, the VTU reader in module_io.cpp. The package's
// Python files (python/zona/) give them their user-facing signatures (docs/python.md).
#include <filesystem>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include <nanobind/stl/string.h>
#include <nanobind/stl/vector.h>
#include <nlohmann/json.hpp>

#include "engine/core/units.h"
#include "engine/mesh/xdmf_writer.h"
#include "engine/fem/model.h"
#include "engine/fem/state.h"
#include "engine/mesh/mesh_generate.h"
#include "engine/mesh/mesh_io.h"
#include "engine/scene/scene.h"
#include "engine/scene/scene_mesh.h"
#include "engine/sim/recorder.h"
#include "kernels/backend_factory.h"
#include "python/module.h"

namespace zona::py {

std::vector<Vec3d> to_positions(nb::handle array, const char* what) {
  using Positions = nb::ndarray<const double, nb::shape<-1, 3>, nb::c_contig, nb::device::cpu>;
  Positions p;
  if (!nb::try_cast(array, p))
    throw ZonaError(std::string(what) + ": expected an (n x 3) float64 array of positions [m]");
  std::vector<Vec3d> out(p.shape(0));
  for (size_t i = 0; i < out.size(); ++i) out[i] = Vec3d{p(i, 0), p(i, 1), p(i, 2)};
  return out;
}

namespace {

namespace fs = std::filesystem;

// A scene argument as every command resolves it (apps/main.cpp, find_scene_file): a path as
// given, else ./scenes, $ZONA_SCENES_DIR, the source tree's scenes; absolute.
std::string scene_file(const std::string& name) {
  const std::string path =
      take(find_scene(name, scene_search_dirs("", std::string(ZONA_SOURCE_DIR) + "/scenes")));
  std::error_code ec;
  const fs::path absolute = fs::absolute(path, ec);
  return ec ? path : absolute.lexically_normal().string();
}

// A mesh as a dict of arrays: points [m] (n x 3), tets (m x 4), region (m), regions {name: tag}.
nb::dict mesh_dict(Mesh&& mesh) {
  auto hold = std::make_shared<Mesh>(std::move(mesh));
  nb::dict d;
  d["points"] = positions_view(hold->rest_positions, hold);
  d["tets"] = array_view(reinterpret_cast<const int32_t*>(hold->tets.data()), {hold->tet_count(), 4},
                         hold);
  d["region"] = array_view(hold->tet_region.data(), {hold->tet_count()}, hold);
  nb::dict regions;
  for (const Region& r : hold->regions) regions[r.name.c_str()] = r.tag;
  d["regions"] = regions;
  return d;
}

// A mesh from arrays, checked as a file mesh is (validate_mesh).
Mesh mesh_from(nb::handle points, nb::handle tets, nb::handle region, const char* what) {
  using Tets = nb::ndarray<const int32_t, nb::shape<-1, 4>, nb::c_contig, nb::device::cpu>;
  using Tags = nb::ndarray<const int32_t, nb::ndim<1>, nb::c_contig, nb::device::cpu>;
  Mesh mesh;
  mesh.rest_positions = to_positions(points, what);
  Tets t;
  if (!nb::try_cast(tets, t))
    throw ZonaError(std::string(what) + ": tets: expected an (m x 4) int32 array");
  mesh.tets.resize(t.shape(0));
  for (size_t e = 0; e < mesh.tets.size(); ++e)
    for (size_t k = 0; k < 4; ++k) mesh.tets[e][k] = t(e, k);
  if (!region.is_none()) {
    Tags r;
    if (!nb::try_cast(region, r) || r.shape(0) != mesh.tets.size())
      throw ZonaError(std::string(what) + ": region: expected one int32 tag per tetrahedron");
    mesh.tet_region.assign(r.data(), r.data() + r.shape(0));
  } else {
    mesh.tet_region.assign(mesh.tets.size(), 0);
  }
  check(validate_mesh(mesh, what));
  return mesh;
}

// A length given as a number [m] or as text with a unit ("56 um").
double length_of(nb::handle value, const char* key) {
  if (nb::isinstance<nb::str>(value)) {
    Result<double> v = parse_quantity(nb::cast<std::string>(value), dim::kLength);
    if (!v.ok()) throw ZonaError(std::string(key) + ": " + v.error().message);
    return *v;
  }
  double v = 0;
  if (!nb::try_cast(value, v))
    throw ZonaError(std::string(key) + ": expected a length (metres, or text such as '56 um')");
  return v;
}

// zona mesh generate (apps/cmd_mesh.cpp): from a scene, or from a diameter and a resolution.
nb::dict generate_mesh(const std::string& scene_json, const std::string& source, nb::dict lengths,
                       nb::object refine_at, int64_t vertices, const std::string& out) {
  CellMeshSpec spec;
  if (!scene_json.empty()) {
    nlohmann::json json = nlohmann::json::parse(scene_json, nullptr, false);
    if (json.is_discarded()) throw ZonaError("scene: not valid JSON");
    const Scene scene = take(parse_scene(json, source.empty() ? "scene dict" : source));
    if (scene.mesh.source != MeshSource::kGenerate)
      throw ZonaError(scene.name + ": mesh: the scene reads a mesh file (mesh.file)");
    spec = cell_mesh_spec(scene);
  } else {
    struct Key {
      const char* name;
      double* target;
    };
    const Key keys[] = {{"diameter", &spec.diameter},
                        {"edge_length", &spec.edge_length},
                        {"refine_edge_length", &spec.refine_edge_length},
                        {"refine_radius", &spec.refine_radius},
                        {"zona_thickness", &spec.zona_thickness},
                        {"nucleus_diameter", &spec.nucleus_diameter}};
    for (const Key& k : keys)
      if (lengths.contains(k.name)) *k.target = length_of(lengths[k.name], k.name);
    if (!refine_at.is_none()) {
      std::vector<nb::object> xyz;
      if (!nb::try_cast(refine_at, xyz) || xyz.size() != 3)
        throw ZonaError("refine_at: expected three lengths x, y, z");
      spec.refine_at = Vec3d{length_of(xyz[0], "refine_at"), length_of(xyz[1], "refine_at"),
                             length_of(xyz[2], "refine_at")};
      // A point alone asks for refinement: the CLI's seed-like ratios when unset.
      if (spec.refine_edge_length <= 0 && vertices > 0) {
        spec.edge_length = spec.diameter / 8.0;
        spec.refine_edge_length = spec.diameter / 40.0;
        spec.refine_radius = spec.diameter / 5.0;
      }
    }
    if (vertices <= 0 && spec.edge_length <= 0)
      throw ZonaError("generate_mesh: give vertices or edge_length (or a scene)");
  }
  if (vertices > 0) spec.target_vertices = vertices;
  std::optional<Result<Mesh>> mesh;
  {
    nb::gil_scoped_release release;
    mesh.emplace(generate_cell_mesh(spec));
  }
  Mesh m = take(std::move(*mesh));
  if (!out.empty()) check(write_mesh(out, m));
  return mesh_dict(std::move(m));
}

// zona forces (apps/cmd_forces.cpp): -dW/du [N] of a deformed configuration, (n x 3).
nb::object elastic_forces(nb::handle points, nb::handle tets, nb::handle region, nb::handle deformed,
                          const std::string& model, const std::string& formulation, double young,
                          double poisson, const std::string& backend) {
  const Mesh mesh = mesh_from(points, tets, region, "rest mesh");
  const std::vector<Vec3d> positions = to_positions(deformed, "deformed");
  if (positions.size() != mesh.vertex_count())
    throw ZonaError("deformed: " + std::to_string(positions.size()) + " vertices, but the rest mesh has " +
                    std::to_string(mesh.vertex_count()) + " (same connectivity expected)");
  ModelDesc desc;
  desc.material.young = young;
  desc.material.poisson = poisson;
  if (model == "svk") desc.constitutive = ConstitutiveModel::kSvk;
  else if (model == "linear") desc.constitutive = ConstitutiveModel::kLinear;
  else if (model == "neohookean") desc.constitutive = ConstitutiveModel::kStableNeoHookean;
  else throw ZonaError("model: '" + model + "' is not svk, linear or neohookean");
  if (formulation == "gradient") desc.formulation = Formulation::kGradient;
  else if (formulation == "tensor_stored") desc.formulation = Formulation::kTensorStored;
  else if (formulation == "tensor_rebuilt") desc.formulation = Formulation::kTensorRebuilt;
  else throw ZonaError("formulation: '" + formulation + "' is not gradient, tensor_stored or tensor_rebuilt");
  const Model built = take(build_model(mesh, desc));
  std::unique_ptr<Backend> engine = take(make_backend(take(parse_backend_kind(backend)), BackendOptions{}));
  const State state = make_state(built, 1);
  check(engine->upload(built, state));
  std::vector<Vec3d> u(mesh.vertex_count()), f(mesh.vertex_count());
  for (size_t v = 0; v < u.size(); ++v) u[v] = positions[v] - mesh.rest_positions[v];
  {
    nb::gil_scoped_release release;
    if (Status s = engine->elastic_forces(u, f); !s) {
      nb::gil_scoped_acquire acquire;
      throw ZonaError(s.error().message);
    }
  }
  auto hold = std::make_shared<std::vector<Vec3d>>(std::move(f));
  return positions_view(*hold, hold);
}

}  // namespace

NB_MODULE(_zona, m) {
  m.doc() = "zona's engine (the package zona wraps it; docs/python.md)";
  nb::exception<ZonaError>(m, "ZonaError", PyExc_ValueError);
  m.attr("version") = ZONA_VERSION;
  m.attr("schema_version") = kOutputSchemaVersion;
  m.attr("force_csv_columns") = nb::cast(force_csv_columns());
  // Whether output.format "xdmf" can be written (a build with HDF5; engine/mesh/xdmf_writer.h).
  m.attr("xdmf_supported") = xdmf_supported();
  m.def("find_scene", &scene_file, nb::arg("name"),
        "The scene file a name or path resolves to, as every zona command resolves it.");
  m.def(
      "load_scene",
      [](const std::string& path, const std::vector<std::string>& sets) {
        return scene_to_json(take(load_scene(path, sets))).dump();
      },
      nb::arg("path"), nb::arg("sets"), "A scene file, --set overrides applied, as JSON text (SI).");
  m.def(
      "parse_scene",
      [](const std::string& text, const std::string& source, const std::vector<std::string>& sets) {
        nlohmann::json json = nlohmann::json::parse(text, nullptr, false);
        if (json.is_discarded()) throw ZonaError("scene: not valid JSON");
        return scene_to_json(take(parse_scene(json, source.empty() ? "scene dict" : source, sets)))
            .dump();
      },
      nb::arg("text"), nb::arg("source"), nb::arg("sets"),
      "Validates a scene's JSON text (overrides applied); the scene as JSON text (SI).");
  m.def("generate_mesh", &generate_mesh, nb::arg("scene_json"), nb::arg("source"),
        nb::arg("lengths"), nb::arg("refine_at").none(), nb::arg("vertices"), nb::arg("out"),
        "The cell mesher (zona mesh generate); a dict of arrays.");
  m.def("elastic_forces", &elastic_forces, nb::arg("points"), nb::arg("tets"),
        nb::arg("region").none(), nb::arg("deformed"), nb::arg("model"), nb::arg("formulation"),
        nb::arg("young"), nb::arg("poisson"), nb::arg("backend"),
        "Elastic force on each vertex [N] (zona forces), (n x 3).");
  m.def(
      "read_mesh",
      [](const std::string& path, double scale) {
        ReadMeshOptions options;
        options.scale = scale;
        return mesh_dict(take(read_mesh(path, options)));
      },
      nb::arg("path"), nb::arg("scale"), "A mesh file (.msh, .node, .vtu) as a dict of arrays.");
  m.def(
      "read_positions",
      [](const std::string& path, double scale) {
        ReadMeshOptions options;
        options.scale = scale;
        auto hold = std::make_shared<std::vector<Vec3d>>(take(read_positions(path, options)));
        return positions_view(*hold, hold);
      },
      nb::arg("path"), nb::arg("scale"),
      "Vertex positions [m] of a mesh file; a zona frame gives its deformed positions.");
  m.def(
      "write_mesh",
      [](const std::string& path, nb::handle points, nb::handle tets, nb::handle region) {
        check(write_mesh(path, mesh_from(points, tets, region, path.c_str())));
      },
      nb::arg("path"), nb::arg("points"), nb::arg("tets"), nb::arg("region").none(),
      "Writes a mesh (.msh or .vtu).");
  add_run(m);
  add_io(m);
}

}  // namespace zona::py
