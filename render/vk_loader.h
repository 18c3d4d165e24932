// Run-time loading of the Vulkan loader (libvulkan.so.1): every Vulkan entry point zona uses,
// as a global function pointer named like the function (the volk pattern), filled by dlopen +
// vkGetInstanceProcAddr. Include this header instead of <vulkan/vulkan.h> in render/.
//
// Why not link libvulkan: a binary linked to it does not start where the loader is missing (CI
// without Mesa, the GPU machine before its loader is unpacked). Opened at run time, a missing
// loader is an error value from create_headless_renderer and tests can skip.
#pragma once

#ifndef VK_NO_PROTOTYPES
#define VK_NO_PROTOTYPES
#endif
#include <vulkan/vulkan.h>

#include "engine/core/base.h"

// Functions callable before an instance exists.
#define ZONA_VK_GLOBAL_FUNCTIONS(X)         \
  X(vkCreateInstance)                       \
  X(vkEnumerateInstanceLayerProperties)     \
  X(vkEnumerateInstanceExtensionProperties) \
  X(vkEnumerateInstanceVersion)

// Instance and device functions (device functions are fetched through the instance: one
// dispatch more per call, negligible for a renderer issuing a few hundred calls a frame).
#define ZONA_VK_INSTANCE_FUNCTIONS(X)          \
  X(vkDestroyInstance)                         \
  X(vkEnumeratePhysicalDevices)                \
  X(vkGetPhysicalDeviceProperties)             \
  X(vkGetPhysicalDeviceProperties2)            \
  X(vkGetPhysicalDeviceFeatures2)              \
  X(vkGetPhysicalDeviceQueueFamilyProperties)  \
  X(vkGetPhysicalDeviceMemoryProperties)       \
  X(vkGetPhysicalDeviceFormatProperties)       \
  X(vkEnumerateDeviceExtensionProperties)      \
  X(vkCreateDevice)                            \
  X(vkCreateDebugUtilsMessengerEXT)            \
  X(vkDestroyDebugUtilsMessengerEXT)           \
  X(vkDestroySurfaceKHR)                       \
  X(vkGetPhysicalDeviceSurfaceSupportKHR)      \
  X(vkGetPhysicalDeviceSurfaceCapabilitiesKHR) \
  X(vkGetPhysicalDeviceSurfaceFormatsKHR)      \
  X(vkGetPhysicalDeviceSurfacePresentModesKHR) \
  X(vkDestroyDevice)                           \
  X(vkGetDeviceQueue)                          \
  X(vkDeviceWaitIdle)                          \
  X(vkCreateCommandPool)                       \
  X(vkDestroyCommandPool)                      \
  X(vkAllocateCommandBuffers)                  \
  X(vkFreeCommandBuffers)                      \
  X(vkBeginCommandBuffer)                      \
  X(vkEndCommandBuffer)                        \
  X(vkResetCommandBuffer)                      \
  X(vkQueueSubmit)                             \
  X(vkQueueWaitIdle)                           \
  X(vkCreateFence)                             \
  X(vkDestroyFence)                            \
  X(vkWaitForFences)                           \
  X(vkResetFences)                             \
  X(vkCreateSemaphore)                         \
  X(vkDestroySemaphore)                        \
  X(vkCreateBuffer)                            \
  X(vkDestroyBuffer)                           \
  X(vkGetBufferMemoryRequirements)             \
  X(vkAllocateMemory)                          \
  X(vkFreeMemory)                              \
  X(vkBindBufferMemory)                        \
  X(vkMapMemory)                               \
  X(vkUnmapMemory)                             \
  X(vkCreateImage)                             \
  X(vkDestroyImage)                            \
  X(vkGetImageMemoryRequirements)              \
  X(vkBindImageMemory)                         \
  X(vkCreateImageView)                         \
  X(vkDestroyImageView)                        \
  X(vkCreateSampler)                           \
  X(vkDestroySampler)                          \
  X(vkCreateShaderModule)                      \
  X(vkDestroyShaderModule)                     \
  X(vkCreatePipelineLayout)                    \
  X(vkDestroyPipelineLayout)                   \
  X(vkCreateGraphicsPipelines)                 \
  X(vkDestroyPipeline)                         \
  X(vkCreateDescriptorSetLayout)               \
  X(vkDestroyDescriptorSetLayout)              \
  X(vkCreateDescriptorPool)                    \
  X(vkDestroyDescriptorPool)                   \
  X(vkAllocateDescriptorSets)                  \
  X(vkUpdateDescriptorSets)                    \
  X(vkCmdPipelineBarrier2)                     \
  X(vkCmdBeginRendering)                       \
  X(vkCmdEndRendering)                         \
  X(vkCmdBindPipeline)                         \
  X(vkCmdBindVertexBuffers)                    \
  X(vkCmdBindIndexBuffer)                      \
  X(vkCmdBindDescriptorSets)                   \
  X(vkCmdPushConstants)                        \
  X(vkCmdSetViewport)                          \
  X(vkCmdSetScissor)                           \
  X(vkCmdDraw)                                 \
  X(vkCmdDrawIndexed)                          \
  X(vkCmdCopyImageToBuffer)                    \
  X(vkCmdCopyBufferToImage)                    \
  X(vkCreateSwapchainKHR)                      \
  X(vkDestroySwapchainKHR)                     \
  X(vkGetSwapchainImagesKHR)                   \
  X(vkAcquireNextImageKHR)                     \
  X(vkQueuePresentKHR)                         \
  X(vkGetMemoryFdKHR)

#define ZONA_VK_DECLARE(name) extern PFN_##name name;
ZONA_VK_DECLARE(vkGetInstanceProcAddr)
ZONA_VK_GLOBAL_FUNCTIONS(ZONA_VK_DECLARE)
ZONA_VK_INSTANCE_FUNCTIONS(ZONA_VK_DECLARE)
#undef ZONA_VK_DECLARE

namespace zona::render {

/// Opens libvulkan.so.1 (once per process; later calls return the first outcome) and fills the
/// global functions. Error: the loader library is missing or lacks vkGetInstanceProcAddr.
Status load_vulkan_loader();

/// Fills the instance and device functions for `instance` (extension functions the instance
/// or device does not offer stay null).
void load_instance_functions(VkInstance instance);

/// The name of a VkResult ("VK_ERROR_DEVICE_LOST"), for one-line error messages.
const char* vk_result_name(VkResult result);

}  // namespace zona::render

/// Checks a Vulkan call in a function returning Status or Result: on failure returns an Error
/// naming the call, the result and the source line.
#define ZONA_VK_TRY(call)                                                          \
  do {                                                                             \
    const VkResult zona_vk_result_ = (call);                                       \
    if (zona_vk_result_ != VK_SUCCESS)                                             \
      return ::zona::make_error("%s:%d: %s failed: %s", __FILE__, __LINE__, #call, \
                                ::zona::render::vk_result_name(zona_vk_result_));  \
  } while (0)
