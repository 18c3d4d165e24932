// Names of backends and assembly strategies, and their parsers (`--backend`, `--assembly`).
#include "engine/sim/backend.h"

#include <string>

namespace zona {

Result<BackendKind> parse_backend_kind(std::string_view text) {
  if (text == "auto") return BackendKind::kAuto;
  if (text == "cpu") return BackendKind::kCpu;
  if (text == "cuda") return BackendKind::kCuda;
  return make_error("backend '%s' is unknown: use auto, cpu or cuda", std::string(text).c_str());
}

const char* backend_kind_name(BackendKind kind) {
  switch (kind) {
    case BackendKind::kAuto:
      return "auto";
    case BackendKind::kCpu:
      return "cpu";
    case BackendKind::kCuda:
      return "cuda";
  }
  return "?";
}

const char* assembly_name(Assembly assembly) {
  switch (assembly) {
    case Assembly::kScatterAtomic:
      return "atomic";
    case Assembly::kScatterFixed:
      return "fixed_point";
    case Assembly::kGatherRecompute:
      return "gather_recompute";
    case Assembly::kGatherStored:
      return "gather_stored";
  }
  return "?";
}

Result<Assembly> parse_assembly(std::string_view text) {
  if (text == "atomic") return Assembly::kScatterAtomic;
  if (text == "fixed_point") return Assembly::kScatterFixed;
  if (text == "gather_recompute") return Assembly::kGatherRecompute;
  if (text == "gather_stored") return Assembly::kGatherStored;
  return make_error(
      "assembly '%s' is unknown: use atomic, fixed_point, gather_recompute or "
      "gather_stored",
      std::string(text).c_str());
}

Result<JobRunner*> Backend::start_job(const JobSetup&) {
  return make_error("%s backend: the device-resident injection step is not supported", name());
}

Status Backend::set_external_forces(std::span<const Vec3d>) {
  return make_error("%s backend: set_external_forces is not supported", name());
}

}  // namespace zona
