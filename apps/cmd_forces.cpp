// `zona forces REST DEFORMED ...`: the elastic force on every vertex of a deformed configuration
// (minus the energy gradient, newtons), as CSV.
#include <algorithm>
#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <memory>
#include <string>
#include <vector>

#include "apps/commands.h"
#include "engine/sim/backend.h"
#include "engine/mesh/mesh_io.h"
#include "engine/fem/model.h"
#include "engine/fem/state.h"
#include "kernels/backend_factory.h"

namespace zona::cli {
namespace {

struct ForcesArgs {
  std::string rest;
  std::string deformed;
  std::string model = "svk";
  std::string formulation = "gradient";
  double young = 17.9e3;
  double poisson = 0.49;
  double scale = 1.0;
  std::string backend = "auto";
  std::string out;
};

Status run_forces(const ForcesArgs& a) {
  ReadMeshOptions read;
  read.scale = a.scale;
  Result<Mesh> mesh = read_mesh(a.rest, read);
  if (!mesh) return mesh.error();
  // The deformed file may be a bare TetGen .node: read it as points, numbered like the mesh.
  Result<std::vector<Vec3d>> deformed = read_positions(a.deformed, read);
  if (!deformed) return deformed.error();
  if (deformed->size() != mesh->vertex_count())
    return make_error("%s: %zu vertices, but %s has %zu (same connectivity expected)",
                      a.deformed.c_str(), deformed->size(), a.rest.c_str(),
                      mesh->vertex_count());

  ModelDesc desc;
  desc.material.young = a.young;
  desc.material.poisson = a.poisson;
  desc.constitutive = a.model == "linear"       ? ConstitutiveModel::kLinear
                      : a.model == "neohookean" ? ConstitutiveModel::kStableNeoHookean
                                                : ConstitutiveModel::kSvk;
  desc.formulation = a.formulation == "tensor_stored"    ? Formulation::kTensorStored
                     : a.formulation == "tensor_rebuilt" ? Formulation::kTensorRebuilt
                                                         : Formulation::kGradient;
  Result<Model> model = build_model(*mesh, desc);
  if (!model) return model.error();

  Result<BackendKind> kind = parse_backend_kind(a.backend);
  if (!kind) return kind.error();
  std::string notice;
  Result<std::unique_ptr<Backend>> backend = make_backend(*kind, BackendOptions{}, &notice);
  if (!backend) return backend.error();
  if (!notice.empty()) std::fprintf(stderr, "zona: notice: %s\n", notice.c_str());
  const State state = make_state(*model, 1);
  if (Status s = (*backend)->upload(*model, state); !s) return s;

  std::vector<Vec3d> u(mesh->vertex_count()), f(mesh->vertex_count());
  for (size_t v = 0; v < u.size(); ++v) u[v] = (*deformed)[v] - mesh->rest_positions[v];
  if (Status s = (*backend)->elastic_forces(u, f); !s) return s;

  std::FILE* file = std::fopen(a.out.c_str(), "w");
  if (!file) return make_error("%s: cannot write: %s", a.out.c_str(), std::strerror(errno));
  std::fprintf(file, "vertex,fx,fy,fz\n");
  for (size_t v = 0; v < f.size(); ++v)
    std::fprintf(file, "%zu,%.17g,%.17g,%.17g\n", v, f[v].x, f[v].y, f[v].z);
  if (std::fclose(file) != 0)
    return make_error("%s: write failed: %s", a.out.c_str(), std::strerror(errno));
  // One line on success: what was written, from what, and the largest force (a sanity check).
  double max_force = 0;
  for (const Vec3d& fv : f) max_force = std::max(max_force, norm(fv));
  std::printf("wrote %s: elastic forces on %zu vertices (%s, %s, E %.6g Pa, nu %.4g); "
              "largest |f| %.6g N\n",
              a.out.c_str(), f.size(), a.model.c_str(), a.formulation.c_str(), a.young, a.poisson,
              max_force);
  return Status::ok_status();
}

}  // namespace

void add_forces_command(CLI::App& app) {
  auto args = std::make_shared<ForcesArgs>();
  auto* cmd = app.add_subcommand(
      "forces", "Elastic force on each vertex of a deformed mesh (-dW/du, newtons) as CSV");
  cmd->add_option("REST", args->rest, "Rest mesh (.msh, TetGen .node/.ele, or .vtu)")->required();
  cmd->add_option("DEFORMED", args->deformed,
                  "Deformed positions, same vertices (a mesh, a bare TetGen .node, or a zona frame .vtu: points + displacement)")
      ->required();
  cmd->add_option("--model", args->model, "Constitutive model")
      ->check(CLI::IsMember({"svk", "linear", "neohookean"}))
      ->capture_default_str();
  cmd->add_option("--formulation", args->formulation,
                  "Evaluation: deformation gradient, or Ladjal et al.'s mass tensors")
      ->check(CLI::IsMember({"gradient", "tensor_stored", "tensor_rebuilt"}))
      ->capture_default_str();
  cmd->add_option("--young", args->young, "Young's modulus [Pa]")->capture_default_str();
  cmd->add_option("--poisson", args->poisson, "Poisson's ratio, in [0, 0.5)")
      ->capture_default_str();
  cmd->add_option("--scale", args->scale, "Metres per file unit (1e-6 for micrometres)")
      ->capture_default_str();
  cmd->add_option("--backend", args->backend, "auto, cpu or cuda")->capture_default_str();
  cmd->add_option("--out", args->out, "Output CSV: vertex,fx,fy,fz")->required();
  cmd->callback([args] {
    if (Status s = run_forces(*args); !s) fail(s.error().message);
  });
}

}  // namespace zona::cli
