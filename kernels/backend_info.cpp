// Build information for `zona info`; the device list comes from the CUDA runtime or its stub.
#include "kernels/backend_info.h"

namespace zona {

BuildInfo build_info() {
  BuildInfo info;
  info.version = ZONA_VERSION;
#if defined(NDEBUG)
  info.build_type = "release";
#else
  info.build_type = "debug";
#endif
#if defined(__clang__)
  info.compiler = "clang " __clang_version__;
#elif defined(__GNUC__)
  info.compiler = "gcc " __VERSION__;
#endif
  info.backends_compiled.push_back("cpu");
  if (cuda_compiled()) info.backends_compiled.push_back("cuda");
  info.renderer_compiled = ZONA_RENDERER_COMPILED != 0;
  info.devices = cuda_devices(&info.device_notice);
  return info;
}

}  // namespace zona
