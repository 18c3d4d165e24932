// `zona mesh ...`: placeholder registration until mesh I/O and the generator land.
#include "apps/commands.h"

namespace zona::cli {
void add_mesh_commands(CLI::App& app) { (void)app; }
}  // namespace zona::cli
