// Vulkan instance, validation messenger, device selection and logical device (context.h).
#include "render/context.h"

#include <cstdlib>
#include <cstring>

namespace zona::render {
namespace {

constexpr const char* kValidationLayer = "VK_LAYER_KHRONOS_validation";

VKAPI_ATTR VkBool32 VKAPI_CALL on_validation_message(
    VkDebugUtilsMessageSeverityFlagBitsEXT severity, VkDebugUtilsMessageTypeFlagsEXT type,
    const VkDebugUtilsMessengerCallbackDataEXT* data, void* user) {
  auto* log = static_cast<ValidationLog*>(user);
  // Loader chatter (an ICD json that names a missing driver, ...) arrives as general warnings:
  // only errors of any kind and validation warnings count.
  const bool error = severity & VK_DEBUG_UTILS_MESSAGE_SEVERITY_ERROR_BIT_EXT;
  const bool warning = (severity & VK_DEBUG_UTILS_MESSAGE_SEVERITY_WARNING_BIT_EXT) &&
                       (type & VK_DEBUG_UTILS_MESSAGE_TYPE_VALIDATION_BIT_EXT);
  if (!error && !warning) return VK_FALSE;
  (error ? log->errors : log->warnings).fetch_add(1);
  std::lock_guard<std::mutex> lock(log->mutex);
  if (log->messages.size() < ValidationLog::kMaxMessages)
    log->messages.push_back(std::string(error ? "error: " : "warning: ") +
                            (data && data->pMessage ? data->pMessage : "(no message)"));
  return VK_FALSE;
}

bool has_layer(const char* name) {
  uint32_t count = 0;
  vkEnumerateInstanceLayerProperties(&count, nullptr);
  std::vector<VkLayerProperties> layers(count);
  vkEnumerateInstanceLayerProperties(&count, layers.data());
  for (const VkLayerProperties& l : layers)
    if (std::strcmp(l.layerName, name) == 0) return true;
  return false;
}

bool has_device_extension(VkPhysicalDevice device, const char* name) {
  uint32_t count = 0;
  vkEnumerateDeviceExtensionProperties(device, nullptr, &count, nullptr);
  std::vector<VkExtensionProperties> extensions(count);
  vkEnumerateDeviceExtensionProperties(device, nullptr, &count, extensions.data());
  for (const VkExtensionProperties& e : extensions)
    if (std::strcmp(e.extensionName, name) == 0) return true;
  return false;
}

// Higher is better; negative: unusable.
int device_score(VkPhysicalDevice device, VkSurfaceKHR surface, const ContextOptions& options,
                 const std::string& wanted, uint32_t* family) {
  VkPhysicalDeviceProperties props;
  vkGetPhysicalDeviceProperties(device, &props);
  if (props.apiVersion < VK_API_VERSION_1_3) return -1;
  VkPhysicalDeviceVulkan13Features f13{VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_VULKAN_1_3_FEATURES};
  VkPhysicalDeviceFeatures2 f2{VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_FEATURES_2, &f13, {}};
  vkGetPhysicalDeviceFeatures2(device, &f2);
  if (!f13.dynamicRendering || !f13.synchronization2) return -1;
  if (options.swapchain && !has_device_extension(device, VK_KHR_SWAPCHAIN_EXTENSION_NAME))
    return -1;
  uint32_t count = 0;
  vkGetPhysicalDeviceQueueFamilyProperties(device, &count, nullptr);
  std::vector<VkQueueFamilyProperties> families(count);
  vkGetPhysicalDeviceQueueFamilyProperties(device, &count, families.data());
  int found = -1;
  for (uint32_t i = 0; i < count && found < 0; ++i) {
    if (!(families[i].queueFlags & VK_QUEUE_GRAPHICS_BIT)) continue;
    VkBool32 present = VK_TRUE;
    if (surface) vkGetPhysicalDeviceSurfaceSupportKHR(device, i, surface, &present);
    if (present) found = static_cast<int>(i);
  }
  if (found < 0) return -1;
  *family = static_cast<uint32_t>(found);
  int score = 1;
  switch (props.deviceType) {
    case VK_PHYSICAL_DEVICE_TYPE_DISCRETE_GPU:
      score = 4;
      break;
    case VK_PHYSICAL_DEVICE_TYPE_INTEGRATED_GPU:
      score = 3;
      break;
    case VK_PHYSICAL_DEVICE_TYPE_VIRTUAL_GPU:
      score = 2;
      break;
    default:
      score = 1;
      break;
  }
  if (!wanted.empty() && std::strstr(props.deviceName, wanted.c_str())) score += 100;
  return score;
}

}  // namespace

Status create_instance(const ContextOptions& options, Context* context) {
  if (Status s = load_vulkan_loader(); !s.ok()) return s;
  uint32_t version = VK_API_VERSION_1_0;
  if (vkEnumerateInstanceVersion) vkEnumerateInstanceVersion(&version);
  if (version < VK_API_VERSION_1_3)
    return make_error("the Vulkan loader is version %u.%u; zona's renderer needs 1.3",
                      VK_API_VERSION_MAJOR(version), VK_API_VERSION_MINOR(version));

  std::vector<const char*> layers, extensions;
  for (const std::string& e : options.instance_extensions) extensions.push_back(e.c_str());
  if (options.validation) {
    if (!has_layer(kValidationLayer))
      return make_error("validation requested but %s is not installed (vulkan-validationlayers)",
                        kValidationLayer);
    layers.push_back(kValidationLayer);
    extensions.push_back(VK_EXT_DEBUG_UTILS_EXTENSION_NAME);
    context->log = std::make_unique<ValidationLog>();
  }

  VkApplicationInfo app{VK_STRUCTURE_TYPE_APPLICATION_INFO};
  app.pApplicationName = "zona";
  app.pEngineName = "zona";
  app.apiVersion = VK_API_VERSION_1_3;
  // The messenger info in pNext also reports problems of vkCreateInstance itself.
  VkDebugUtilsMessengerCreateInfoEXT messenger{
      VK_STRUCTURE_TYPE_DEBUG_UTILS_MESSENGER_CREATE_INFO_EXT};
  messenger.messageSeverity = VK_DEBUG_UTILS_MESSAGE_SEVERITY_WARNING_BIT_EXT |
                              VK_DEBUG_UTILS_MESSAGE_SEVERITY_ERROR_BIT_EXT;
  messenger.messageType = VK_DEBUG_UTILS_MESSAGE_TYPE_GENERAL_BIT_EXT |
                          VK_DEBUG_UTILS_MESSAGE_TYPE_VALIDATION_BIT_EXT |
                          VK_DEBUG_UTILS_MESSAGE_TYPE_PERFORMANCE_BIT_EXT;
  messenger.pfnUserCallback = on_validation_message;
  messenger.pUserData = context->log.get();
  VkInstanceCreateInfo info{VK_STRUCTURE_TYPE_INSTANCE_CREATE_INFO};
  info.pNext = options.validation ? &messenger : nullptr;
  info.pApplicationInfo = &app;
  info.enabledLayerCount = static_cast<uint32_t>(layers.size());
  info.ppEnabledLayerNames = layers.data();
  info.enabledExtensionCount = static_cast<uint32_t>(extensions.size());
  info.ppEnabledExtensionNames = extensions.data();
  const VkResult created = vkCreateInstance(&info, nullptr, &context->instance);
  // The loader answers INCOMPATIBLE_DRIVER when it found no driver at all: say so plainly.
  if (created == VK_ERROR_INCOMPATIBLE_DRIVER)
    return make_error("no Vulkan driver found by the loader (install mesa-vulkan-drivers for "
                      "lavapipe, or point VK_DRIVER_FILES at a driver's json)");
  ZONA_VK_TRY(created);
  load_instance_functions(context->instance);
  context->validation = options.validation;
  if (options.validation && vkCreateDebugUtilsMessengerEXT)
    ZONA_VK_TRY(vkCreateDebugUtilsMessengerEXT(context->instance, &messenger, nullptr,
                                               &context->messenger));
  return {};
}

Status create_device(const ContextOptions& options, VkSurfaceKHR surface, Context* context) {
  uint32_t count = 0;
  ZONA_VK_TRY(vkEnumeratePhysicalDevices(context->instance, &count, nullptr));
  if (count == 0) return make_error("no Vulkan device (install mesa-vulkan-drivers for lavapipe)");
  std::vector<VkPhysicalDevice> devices(count);
  ZONA_VK_TRY(vkEnumeratePhysicalDevices(context->instance, &count, devices.data()));
  std::string wanted = options.device_name;
  if (wanted.empty())
    if (const char* env = std::getenv("ZONA_VK_DEVICE")) wanted = env;
  int best = -1;
  for (VkPhysicalDevice d : devices) {
    uint32_t family = 0;
    const int score = device_score(d, surface, options, wanted, &family);
    if (score > best) {
      best = score;
      context->physical_device = d;
      context->queue_family = family;
    }
  }
  if (best < 0)
    return make_error("no Vulkan device with 1.3, dynamic rendering and a graphics queue%s",
                      surface ? " that can present to the window" : "");
  vkGetPhysicalDeviceProperties(context->physical_device, &context->properties);
  vkGetPhysicalDeviceMemoryProperties(context->physical_device, &context->memory_properties);
  VkPhysicalDeviceIDProperties id{VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_ID_PROPERTIES};
  VkPhysicalDeviceProperties2 properties2{VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_PROPERTIES_2, &id, {}};
  vkGetPhysicalDeviceProperties2(context->physical_device, &properties2);
  std::memcpy(context->device_uuid, id.deviceUUID, VK_UUID_SIZE);

  std::vector<const char*> extensions;
  if (options.swapchain) extensions.push_back(VK_KHR_SWAPCHAIN_EXTENSION_NAME);
  if (options.external_memory &&
      has_device_extension(context->physical_device, VK_KHR_EXTERNAL_MEMORY_FD_EXTENSION_NAME)) {
    extensions.push_back(VK_KHR_EXTERNAL_MEMORY_FD_EXTENSION_NAME);
    context->external_memory = true;
  }
  const float priority = 1.0f;
  VkDeviceQueueCreateInfo queue{VK_STRUCTURE_TYPE_DEVICE_QUEUE_CREATE_INFO};
  queue.queueFamilyIndex = context->queue_family;
  queue.queueCount = 1;
  queue.pQueuePriorities = &priority;
  VkPhysicalDeviceVulkan13Features f13{VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_VULKAN_1_3_FEATURES};
  f13.dynamicRendering = VK_TRUE;
  f13.synchronization2 = VK_TRUE;
  VkPhysicalDeviceFeatures2 features{VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_FEATURES_2, &f13, {}};
  VkDeviceCreateInfo info{VK_STRUCTURE_TYPE_DEVICE_CREATE_INFO};
  info.pNext = &features;
  info.queueCreateInfoCount = 1;
  info.pQueueCreateInfos = &queue;
  info.enabledExtensionCount = static_cast<uint32_t>(extensions.size());
  info.ppEnabledExtensionNames = extensions.data();
  ZONA_VK_TRY(vkCreateDevice(context->physical_device, &info, nullptr, &context->device));
  vkGetDeviceQueue(context->device, context->queue_family, 0, &context->queue);

  VkCommandPoolCreateInfo pool{VK_STRUCTURE_TYPE_COMMAND_POOL_CREATE_INFO};
  pool.flags = VK_COMMAND_POOL_CREATE_RESET_COMMAND_BUFFER_BIT;
  pool.queueFamilyIndex = context->queue_family;
  ZONA_VK_TRY(vkCreateCommandPool(context->device, &pool, nullptr, &context->command_pool));
  return {};
}

void destroy_context(Context* context) {
  if (context->device) {
    vkDeviceWaitIdle(context->device);
    if (context->command_pool)
      vkDestroyCommandPool(context->device, context->command_pool, nullptr);
    vkDestroyDevice(context->device, nullptr);
  }
  if (context->messenger)
    vkDestroyDebugUtilsMessengerEXT(context->instance, context->messenger, nullptr);
  if (context->instance) vkDestroyInstance(context->instance, nullptr);
  context->command_pool = VK_NULL_HANDLE;
  context->device = VK_NULL_HANDLE;
  context->messenger = VK_NULL_HANDLE;
  context->instance = VK_NULL_HANDLE;
  context->physical_device = VK_NULL_HANDLE;
}

int find_memory_type(const Context& context, uint32_t type_bits, VkMemoryPropertyFlags properties) {
  const VkPhysicalDeviceMemoryProperties& m = context.memory_properties;
  for (uint32_t i = 0; i < m.memoryTypeCount; ++i)
    if ((type_bits & (1u << i)) && (m.memoryTypes[i].propertyFlags & properties) == properties)
      return static_cast<int>(i);
  return -1;
}

}  // namespace zona::render
