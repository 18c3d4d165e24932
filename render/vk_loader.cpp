// Run-time loading of libvulkan.so.1 and the global Vulkan function pointers (vk_loader.h).
#include "render/vk_loader.h"

#include <dlfcn.h>

#include <mutex>
#include <string>

#define ZONA_VK_DEFINE(name) PFN_##name name = nullptr;
ZONA_VK_DEFINE(vkGetInstanceProcAddr)
ZONA_VK_GLOBAL_FUNCTIONS(ZONA_VK_DEFINE)
ZONA_VK_INSTANCE_FUNCTIONS(ZONA_VK_DEFINE)
#undef ZONA_VK_DEFINE

namespace zona::render {

Status load_vulkan_loader() {
  // The library stays open for the life of the process: drivers keep threads and state in it.
  static std::once_flag once;
  static std::string error;
  std::call_once(once, [] {
    void* library = dlopen("libvulkan.so.1", RTLD_NOW | RTLD_LOCAL);
    if (!library) library = dlopen("libvulkan.so", RTLD_NOW | RTLD_LOCAL);
    if (!library) {
      const char* why = dlerror();
      error = std::string("no Vulkan loader: cannot open libvulkan.so.1 (") +
              (why ? why : "unknown") + "); install libvulkan1 and a driver (mesa-vulkan-drivers)";
      return;
    }
    vkGetInstanceProcAddr =
        reinterpret_cast<PFN_vkGetInstanceProcAddr>(dlsym(library, "vkGetInstanceProcAddr"));
    if (!vkGetInstanceProcAddr) {
      error = "libvulkan.so.1 has no vkGetInstanceProcAddr";
      return;
    }
#define ZONA_VK_LOAD_GLOBAL(name) \
  name = reinterpret_cast<PFN_##name>(vkGetInstanceProcAddr(VK_NULL_HANDLE, #name));
    ZONA_VK_GLOBAL_FUNCTIONS(ZONA_VK_LOAD_GLOBAL)
#undef ZONA_VK_LOAD_GLOBAL
    if (!vkCreateInstance) error = "the Vulkan loader does not provide vkCreateInstance";
  });
  if (!error.empty()) return Error{error};
  return {};
}

void load_instance_functions(VkInstance instance) {
#define ZONA_VK_LOAD_INSTANCE(name) \
  name = reinterpret_cast<PFN_##name>(vkGetInstanceProcAddr(instance, #name));
  ZONA_VK_INSTANCE_FUNCTIONS(ZONA_VK_LOAD_INSTANCE)
#undef ZONA_VK_LOAD_INSTANCE
}

const char* vk_result_name(VkResult result) {
  switch (result) {
#define ZONA_VK_RESULT(r) \
  case r:                 \
    return #r;
    ZONA_VK_RESULT(VK_SUCCESS)
    ZONA_VK_RESULT(VK_NOT_READY)
    ZONA_VK_RESULT(VK_TIMEOUT)
    ZONA_VK_RESULT(VK_INCOMPLETE)
    ZONA_VK_RESULT(VK_SUBOPTIMAL_KHR)
    ZONA_VK_RESULT(VK_ERROR_OUT_OF_HOST_MEMORY)
    ZONA_VK_RESULT(VK_ERROR_OUT_OF_DEVICE_MEMORY)
    ZONA_VK_RESULT(VK_ERROR_INITIALIZATION_FAILED)
    ZONA_VK_RESULT(VK_ERROR_DEVICE_LOST)
    ZONA_VK_RESULT(VK_ERROR_MEMORY_MAP_FAILED)
    ZONA_VK_RESULT(VK_ERROR_LAYER_NOT_PRESENT)
    ZONA_VK_RESULT(VK_ERROR_EXTENSION_NOT_PRESENT)
    ZONA_VK_RESULT(VK_ERROR_FEATURE_NOT_PRESENT)
    ZONA_VK_RESULT(VK_ERROR_INCOMPATIBLE_DRIVER)
    ZONA_VK_RESULT(VK_ERROR_TOO_MANY_OBJECTS)
    ZONA_VK_RESULT(VK_ERROR_FORMAT_NOT_SUPPORTED)
    ZONA_VK_RESULT(VK_ERROR_SURFACE_LOST_KHR)
    ZONA_VK_RESULT(VK_ERROR_NATIVE_WINDOW_IN_USE_KHR)
    ZONA_VK_RESULT(VK_ERROR_OUT_OF_DATE_KHR)
    ZONA_VK_RESULT(VK_ERROR_INVALID_EXTERNAL_HANDLE)
#undef ZONA_VK_RESULT
    default:
      return "VkResult (unnamed)";
  }
}

}  // namespace zona::render
