// libFuzzer target: the TetGen reader. The input is the .node text, a NUL byte, then the .ele
// text; without a NUL it is a .node alone (positions only, as `zona forces` reads it).
#include <cstddef>
#include <cstdint>
#include <string_view>

#include "engine/mesh/mesh_io.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::string_view text(reinterpret_cast<const char*>(data), size);
  const size_t split = text.find('\0');
  if (split == std::string_view::npos) {
    const auto points = zona::read_tetgen_node_from_memory(text, "fuzz.node");
    if (!points.ok() && points.error().message.find('\n') != std::string::npos) __builtin_trap();
    return 0;
  }
  std::vector<std::string> warnings;
  const auto mesh = zona::read_tetgen_from_memory(text.substr(0, split), text.substr(split + 1),
                                                  "fuzz.node", "fuzz.ele", {}, &warnings);
  if (!mesh.ok() && mesh.error().message.find('\n') != std::string::npos) __builtin_trap();
  return 0;
}
