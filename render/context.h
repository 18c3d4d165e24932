// The Vulkan instance, device and queue the renderer draws with, plus the validation layer's
// message counter. One plain struct, created and destroyed by free functions.
#pragma once

#include <atomic>
#include <memory>
#include <mutex>
#include <string>
#include <vector>

#include "engine/core/base.h"
#include "render/vk_loader.h"

namespace zona::render {

/// How the context is created.
struct ContextOptions {
  /// Enable VK_LAYER_KHRONOS_validation and count its messages (error if not installed).
  bool validation = false;
  /// Extra instance extensions (a window's surface extensions from GLFW).
  std::vector<std::string> instance_extensions;
  /// Enable VK_KHR_swapchain on the device (window mode).
  bool swapchain = false;
  /// Enable VK_KHR_external_memory_fd when the device has it (the CUDA interop seam).
  bool external_memory = false;
  /// Prefer the device whose name contains this; empty: $ZONA_VK_DEVICE, else the best kind
  /// (discrete > integrated > virtual > CPU).
  std::string device_name;
};

/// What the validation layer said. Written by the layer's callback (any thread).
struct ValidationLog {
  std::atomic<int> errors{0};    ///< messages of error severity (any type)
  std::atomic<int> warnings{0};  ///< validation messages of warning severity
  std::mutex mutex;
  std::vector<std::string> messages;  ///< the first kMaxMessages messages, one line each
  static constexpr size_t kMaxMessages = 32;
};

/// Instance, chosen physical device, logical device, one graphics queue and a command pool.
struct Context {
  VkInstance instance = VK_NULL_HANDLE;
  VkDebugUtilsMessengerEXT messenger = VK_NULL_HANDLE;
  VkPhysicalDevice physical_device = VK_NULL_HANDLE;
  VkPhysicalDeviceProperties properties{};
  VkPhysicalDeviceMemoryProperties memory_properties{};
  VkDevice device = VK_NULL_HANDLE;
  uint32_t queue_family = 0;
  VkQueue queue = VK_NULL_HANDLE;
  VkCommandPool command_pool = VK_NULL_HANDLE;  ///< resettable command buffers
  bool validation = false;
  bool external_memory = false;        ///< VK_KHR_external_memory_fd enabled
  uint8_t device_uuid[VK_UUID_SIZE] = {};  ///< identifies the GPU to CUDA (interop)
  std::unique_ptr<ValidationLog> log;  ///< stable address for the layer's callback
};

/// Step 1: loads the Vulkan loader and creates the instance (and the validation messenger).
/// On error the context holds what was created; destroy_context releases it.
Status create_instance(const ContextOptions& options, Context* context);

/// Step 2: picks a physical device (able to present to `surface` when it is not null) and
/// creates the device, queue and command pool. Needs Vulkan 1.3 with dynamic rendering.
Status create_device(const ContextOptions& options, VkSurfaceKHR surface, Context* context);

/// Waits for the device to be idle and destroys everything in reverse order; idempotent.
void destroy_context(Context* context);

/// Index of a memory type allowed by `type_bits` with `properties`, or -1.
int find_memory_type(const Context& context, uint32_t type_bits, VkMemoryPropertyFlags properties);

}  // namespace zona::render
