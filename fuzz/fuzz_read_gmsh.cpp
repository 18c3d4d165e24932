// libFuzzer target: the Gmsh .msh reader on arbitrary bytes must return a value or an Error,
// never crash, hang, leak or allocate without bound.
#include <cstddef>
#include <cstdint>
#include <string_view>

#include "engine/mesh/mesh_io.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::string_view text(reinterpret_cast<const char*>(data), size);
  std::vector<std::string> warnings;
  const zona::Result<zona::Mesh> mesh = zona::read_gmsh_from_memory(text, "fuzz.msh", {}, &warnings);
  if (!mesh.ok() && mesh.error().message.find('\n') != std::string::npos) __builtin_trap();
  return 0;
}
