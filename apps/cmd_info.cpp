// `zona info`: version, build options, compiled backends and devices found.
#include <cstdio>

#include <nlohmann/json.hpp>

#include "apps/commands.h"
#include "kernels/backend_info.h"

namespace zona::cli {

void add_info_command(CLI::App& app) {
  auto* cmd = app.add_subcommand("info", "Version, build options, compiled backends, devices");
  auto json = std::make_shared<bool>(false);
  cmd->add_flag("--json", *json, "Print one JSON object");
  cmd->callback([json] {
    const BuildInfo info = build_info();
    nlohmann::json j;
    j["version"] = info.version;
    j["build_type"] = info.build_type;
    j["compiler"] = info.compiler;
    j["backends_compiled"] = info.backends_compiled;
    j["renderer_compiled"] = info.renderer_compiled;
    nlohmann::json devices = nlohmann::json::array();
    for (const DeviceInfo& d : info.devices)
      devices.push_back({{"backend", d.backend},
                         {"name", d.name},
                         {"memory_bytes", d.memory_bytes},
                         {"compute_capability", d.compute_capability}});
    j["devices"] = devices;
    j["device_notice"] = info.device_notice;
    if (*json) {
      std::printf("%s\n", j.dump(2).c_str());
      return;
    }
    std::printf("zona %s (%s, %s)\n", info.version.c_str(), info.build_type.c_str(),
                info.compiler.c_str());
    std::printf("backends compiled: ");
    for (size_t i = 0; i < info.backends_compiled.size(); ++i)
      std::printf("%s%s", i ? ", " : "", info.backends_compiled[i].c_str());
    std::printf("\nrenderer: %s\n", info.renderer_compiled ? "vulkan" : "none");
    for (const DeviceInfo& d : info.devices)
      std::printf("device: %s %s (sm_%s, %.1f GiB)\n", d.backend.c_str(), d.name.c_str(),
                  d.compute_capability.c_str(),
                  static_cast<double>(d.memory_bytes) / (1024.0 * 1024.0 * 1024.0));
    if (!info.device_notice.empty()) std::printf("%s\n", info.device_notice.c_str());
  });
}

}  // namespace zona::cli
