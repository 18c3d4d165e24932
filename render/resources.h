// Buffers, images and one-shot command submission over a render Context: plain structs with
// create / destroy functions, every Vulkan call checked.
#pragma once

#include <functional>

#include "engine/core/base.h"
#include "render/context.h"

namespace zona::render {

/// A buffer with its own memory; `mapped` is set for host-visible buffers (persistently mapped).
struct Buffer {
  VkBuffer buffer = VK_NULL_HANDLE;
  VkDeviceMemory memory = VK_NULL_HANDLE;
  void* mapped = nullptr;
  VkDeviceSize size = 0;
  bool exportable = false;  ///< memory allocated with an exportable opaque fd handle
};

/// How a buffer's memory is placed.
enum class MemoryPlace {
  kHost,    ///< host-visible, coherent, mapped (uploads every frame, readback)
  kDevice,  ///< device-local (not mapped)
};

/// Creates a buffer of `size` bytes. `exportable` allocates its memory with an opaque-fd export
/// (needs Context::external_memory), the seam for CUDA external memory.
Status create_buffer(const Context& context, VkDeviceSize size, VkBufferUsageFlags usage,
                     MemoryPlace place, Buffer* buffer, bool exportable = false);
void destroy_buffer(const Context& context, Buffer* buffer);

/// A 2D image with its own memory and one view.
struct Image {
  VkImage image = VK_NULL_HANDLE;
  VkDeviceMemory memory = VK_NULL_HANDLE;
  VkImageView view = VK_NULL_HANDLE;
  VkFormat format = VK_FORMAT_UNDEFINED;
  VkExtent2D extent{0, 0};
};

/// Creates a device-local 2D image and its view.
Status create_image(const Context& context, uint32_t width, uint32_t height, VkFormat format,
                    VkImageUsageFlags usage, VkSampleCountFlagBits samples,
                    VkImageAspectFlags aspect, Image* image);
void destroy_image(const Context& context, Image* image);

/// Records a layout transition of a whole image (synchronization2).
void image_barrier(VkCommandBuffer cmd, VkImage image, VkImageAspectFlags aspect,
                   VkImageLayout from, VkImageLayout to, VkPipelineStageFlags2 src_stage,
                   VkAccessFlags2 src_access, VkPipelineStageFlags2 dst_stage,
                   VkAccessFlags2 dst_access);

/// Records `record` into a temporary command buffer, submits it and waits (setup uploads).
Status submit_and_wait(const Context& context, const std::function<void(VkCommandBuffer)>& record);

/// Creates a shader module from SPIR-V words.
Status create_shader_module(const Context& context, const uint32_t* words, size_t bytes,
                            VkShaderModule* module);

}  // namespace zona::render
