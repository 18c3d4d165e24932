// Buffers, images, barriers and one-shot submission (resources.h).
#include "render/resources.h"

namespace zona::render {

Status create_buffer(const Context& context, VkDeviceSize size, VkBufferUsageFlags usage,
                     MemoryPlace place, Buffer* buffer, bool exportable) {
  if (exportable && !context.external_memory)
    return make_error("exportable buffer requested but VK_KHR_external_memory_fd is not enabled");
  VkExternalMemoryBufferCreateInfo external{VK_STRUCTURE_TYPE_EXTERNAL_MEMORY_BUFFER_CREATE_INFO};
  external.handleTypes = VK_EXTERNAL_MEMORY_HANDLE_TYPE_OPAQUE_FD_BIT;
  VkBufferCreateInfo info{VK_STRUCTURE_TYPE_BUFFER_CREATE_INFO};
  info.pNext = exportable ? &external : nullptr;
  info.size = size;
  info.usage = usage;
  info.sharingMode = VK_SHARING_MODE_EXCLUSIVE;
  ZONA_VK_TRY(vkCreateBuffer(context.device, &info, nullptr, &buffer->buffer));
  VkMemoryRequirements req;
  vkGetBufferMemoryRequirements(context.device, buffer->buffer, &req);
  const VkMemoryPropertyFlags props =
      place == MemoryPlace::kHost
          ? VK_MEMORY_PROPERTY_HOST_VISIBLE_BIT | VK_MEMORY_PROPERTY_HOST_COHERENT_BIT
          : VK_MEMORY_PROPERTY_DEVICE_LOCAL_BIT;
  const int type = find_memory_type(context, req.memoryTypeBits, props);
  if (type < 0)
    return make_error("no Vulkan memory type for a %llu-byte buffer",
                      static_cast<unsigned long long>(size));
  // Exported memory is a dedicated allocation: CUDA imports it with cudaExternalMemoryDedicated,
  // which must match how it was allocated.
  VkMemoryDedicatedAllocateInfo dedicated{VK_STRUCTURE_TYPE_MEMORY_DEDICATED_ALLOCATE_INFO};
  dedicated.buffer = buffer->buffer;
  VkExportMemoryAllocateInfo export_info{VK_STRUCTURE_TYPE_EXPORT_MEMORY_ALLOCATE_INFO, &dedicated};
  export_info.handleTypes = VK_EXTERNAL_MEMORY_HANDLE_TYPE_OPAQUE_FD_BIT;
  VkMemoryAllocateInfo alloc{VK_STRUCTURE_TYPE_MEMORY_ALLOCATE_INFO};
  alloc.pNext = exportable ? &export_info : nullptr;
  alloc.allocationSize = req.size;
  alloc.memoryTypeIndex = static_cast<uint32_t>(type);
  ZONA_VK_TRY(vkAllocateMemory(context.device, &alloc, nullptr, &buffer->memory));
  ZONA_VK_TRY(vkBindBufferMemory(context.device, buffer->buffer, buffer->memory, 0));
  if (place == MemoryPlace::kHost)
    ZONA_VK_TRY(vkMapMemory(context.device, buffer->memory, 0, VK_WHOLE_SIZE, 0, &buffer->mapped));
  buffer->size = size;
  buffer->exportable = exportable;
  return {};
}

void destroy_buffer(const Context& context, Buffer* buffer) {
  if (buffer->buffer) vkDestroyBuffer(context.device, buffer->buffer, nullptr);
  // Freeing mapped memory unmaps it implicitly.
  if (buffer->memory) vkFreeMemory(context.device, buffer->memory, nullptr);
  *buffer = Buffer{};
}

Status create_image(const Context& context, uint32_t width, uint32_t height, VkFormat format,
                    VkImageUsageFlags usage, VkSampleCountFlagBits samples,
                    VkImageAspectFlags aspect, Image* image) {
  VkImageCreateInfo info{VK_STRUCTURE_TYPE_IMAGE_CREATE_INFO};
  info.imageType = VK_IMAGE_TYPE_2D;
  info.format = format;
  info.extent = {width, height, 1};
  info.mipLevels = 1;
  info.arrayLayers = 1;
  info.samples = samples;
  info.tiling = VK_IMAGE_TILING_OPTIMAL;
  info.usage = usage;
  info.sharingMode = VK_SHARING_MODE_EXCLUSIVE;
  info.initialLayout = VK_IMAGE_LAYOUT_UNDEFINED;
  ZONA_VK_TRY(vkCreateImage(context.device, &info, nullptr, &image->image));
  VkMemoryRequirements req;
  vkGetImageMemoryRequirements(context.device, image->image, &req);
  const int type =
      find_memory_type(context, req.memoryTypeBits, VK_MEMORY_PROPERTY_DEVICE_LOCAL_BIT);
  if (type < 0) return make_error("no device-local Vulkan memory for a %ux%u image", width, height);
  VkMemoryAllocateInfo alloc{VK_STRUCTURE_TYPE_MEMORY_ALLOCATE_INFO};
  alloc.allocationSize = req.size;
  alloc.memoryTypeIndex = static_cast<uint32_t>(type);
  ZONA_VK_TRY(vkAllocateMemory(context.device, &alloc, nullptr, &image->memory));
  ZONA_VK_TRY(vkBindImageMemory(context.device, image->image, image->memory, 0));
  VkImageViewCreateInfo view{VK_STRUCTURE_TYPE_IMAGE_VIEW_CREATE_INFO};
  view.image = image->image;
  view.viewType = VK_IMAGE_VIEW_TYPE_2D;
  view.format = format;
  view.subresourceRange = {aspect, 0, 1, 0, 1};
  ZONA_VK_TRY(vkCreateImageView(context.device, &view, nullptr, &image->view));
  image->format = format;
  image->extent = {width, height};
  return {};
}

void destroy_image(const Context& context, Image* image) {
  if (image->view) vkDestroyImageView(context.device, image->view, nullptr);
  if (image->image) vkDestroyImage(context.device, image->image, nullptr);
  if (image->memory) vkFreeMemory(context.device, image->memory, nullptr);
  *image = Image{};
}

void image_barrier(VkCommandBuffer cmd, VkImage image, VkImageAspectFlags aspect,
                   VkImageLayout from, VkImageLayout to, VkPipelineStageFlags2 src_stage,
                   VkAccessFlags2 src_access, VkPipelineStageFlags2 dst_stage,
                   VkAccessFlags2 dst_access) {
  VkImageMemoryBarrier2 barrier{VK_STRUCTURE_TYPE_IMAGE_MEMORY_BARRIER_2};
  barrier.srcStageMask = src_stage;
  barrier.srcAccessMask = src_access;
  barrier.dstStageMask = dst_stage;
  barrier.dstAccessMask = dst_access;
  barrier.oldLayout = from;
  barrier.newLayout = to;
  barrier.srcQueueFamilyIndex = VK_QUEUE_FAMILY_IGNORED;
  barrier.dstQueueFamilyIndex = VK_QUEUE_FAMILY_IGNORED;
  barrier.image = image;
  barrier.subresourceRange = {aspect, 0, 1, 0, 1};
  VkDependencyInfo dep{VK_STRUCTURE_TYPE_DEPENDENCY_INFO};
  dep.imageMemoryBarrierCount = 1;
  dep.pImageMemoryBarriers = &barrier;
  vkCmdPipelineBarrier2(cmd, &dep);
}

Status submit_and_wait(const Context& context, const std::function<void(VkCommandBuffer)>& record) {
  VkCommandBufferAllocateInfo alloc{VK_STRUCTURE_TYPE_COMMAND_BUFFER_ALLOCATE_INFO};
  alloc.commandPool = context.command_pool;
  alloc.level = VK_COMMAND_BUFFER_LEVEL_PRIMARY;
  alloc.commandBufferCount = 1;
  VkCommandBuffer cmd = VK_NULL_HANDLE;
  ZONA_VK_TRY(vkAllocateCommandBuffers(context.device, &alloc, &cmd));
  VkCommandBufferBeginInfo begin{VK_STRUCTURE_TYPE_COMMAND_BUFFER_BEGIN_INFO};
  begin.flags = VK_COMMAND_BUFFER_USAGE_ONE_TIME_SUBMIT_BIT;
  VkResult r = vkBeginCommandBuffer(cmd, &begin);
  if (r == VK_SUCCESS) {
    record(cmd);
    r = vkEndCommandBuffer(cmd);
  }
  if (r == VK_SUCCESS) {
    VkSubmitInfo submit{VK_STRUCTURE_TYPE_SUBMIT_INFO};
    submit.commandBufferCount = 1;
    submit.pCommandBuffers = &cmd;
    r = vkQueueSubmit(context.queue, 1, &submit, VK_NULL_HANDLE);
    if (r == VK_SUCCESS) r = vkQueueWaitIdle(context.queue);
  }
  vkFreeCommandBuffers(context.device, context.command_pool, 1, &cmd);
  ZONA_VK_TRY(r);
  return {};
}

Status create_shader_module(const Context& context, const uint32_t* words, size_t bytes,
                            VkShaderModule* module) {
  VkShaderModuleCreateInfo info{VK_STRUCTURE_TYPE_SHADER_MODULE_CREATE_INFO};
  info.codeSize = bytes;
  info.pCode = words;
  ZONA_VK_TRY(vkCreateShaderModule(context.device, &info, nullptr, module));
  return {};
}

}  // namespace zona::render
