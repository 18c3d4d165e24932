// The headless renderer: offscreen target, readback, PNG, frame sequences (renderer.h).
#include "render/renderer.h"

#include <stb_image_write.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <filesystem>

#include "render/draw.h"

namespace zona {

using namespace render;

struct Renderer::Impl {
  Context context;
  OverlayState overlay;
  Pipelines pipelines;
  Attachments attachments;
  FrameResources frame;
  CpuFrame cpu;
  Image target;     // single-sample RGBA8 sRGB, resolved into, copied out
  Buffer readback;  // host copy of the target
  SharedSurfaceBuffers shared;  // CUDA interop (create_shared_surface)
  int width = 0, height = 0;
  bool rendered = false;

  ~Impl() {
    if (context.device) vkDeviceWaitIdle(context.device);
    destroy_buffer(context, &shared.indices);
    destroy_buffer(context, &shared.vertices);
    destroy_buffer(context, &readback);
    destroy_image(context, &target);
    destroy_frame_resources(context, &frame);
    destroy_attachments(context, &attachments);
    destroy_pipelines(context, &pipelines);
    destroy_overlay(&overlay);
    destroy_context(&context);
  }
};

Renderer::Renderer() = default;
Renderer::Renderer(Renderer&&) noexcept = default;
Renderer& Renderer::operator=(Renderer&&) noexcept = default;
Renderer::~Renderer() = default;

int Renderer::width() const {
  return impl_ ? impl_->width : 0;
}
int Renderer::height() const {
  return impl_ ? impl_->height : 0;
}
int Renderer::samples() const {
  return impl_ ? static_cast<int>(impl_->pipelines.samples) : 0;
}
std::string Renderer::device_name() const {
  return impl_ ? impl_->context.properties.deviceName : "";
}

ValidationReport Renderer::validation() const {
  ValidationReport report;
  if (!impl_ || !impl_->context.log) return report;
  ValidationLog& log = *impl_->context.log;
  report.enabled = true;
  report.errors = log.errors.load();
  report.warnings = log.warnings.load();
  std::lock_guard<std::mutex> lock(log.mutex);
  report.messages = log.messages;
  return report;
}

Result<Renderer> create_headless_renderer(int width, int height, const RendererOptions& options) {
  if (width < 16 || height < 16 || width > 16384 || height > 16384)
    return make_error("renderer: image size %dx%d outside 16..16384", width, height);
  Renderer renderer;
  renderer.impl_ = std::make_unique<Renderer::Impl>();
  Renderer::Impl& r = *renderer.impl_;
  r.width = width;
  r.height = height;
  ContextOptions context_options;
  context_options.validation = options.validation;
  context_options.device_name = options.device_name;
  context_options.external_memory = options.external_memory;
  if (Status s = create_instance(context_options, &r.context); !s.ok()) return s.error();
  if (Status s = create_device(context_options, VK_NULL_HANDLE, &r.context); !s.ok())
    return s.error();
  // Text about 1/40 of the image height, at least 13 px.
  const float font = options.font_pixels > 0
                         ? options.font_pixels
                         : std::max(13.0f, std::round(static_cast<float>(height) / 40.0f));
  if (Status s = create_overlay(options.font_path, font, &r.overlay); !s.ok()) return s.error();
  const VkFormat format = VK_FORMAT_R8G8B8A8_SRGB;
  if (Status s = create_pipelines(r.context, format, pick_samples(r.context, options.samples),
                                  r.overlay, &r.pipelines);
      !s.ok())
    return s.error();
  const VkExtent2D extent{static_cast<uint32_t>(width), static_cast<uint32_t>(height)};
  if (Status s = create_attachments(r.context, r.pipelines, extent, &r.attachments); !s.ok())
    return s.error();
  if (Status s = create_image(r.context, extent.width, extent.height, format,
                              VK_IMAGE_USAGE_COLOR_ATTACHMENT_BIT | VK_IMAGE_USAGE_TRANSFER_SRC_BIT,
                              VK_SAMPLE_COUNT_1_BIT, VK_IMAGE_ASPECT_COLOR_BIT, &r.target);
      !s.ok())
    return s.error();
  if (Status s = create_buffer(r.context, static_cast<VkDeviceSize>(width) * height * 4,
                               VK_BUFFER_USAGE_TRANSFER_DST_BIT, MemoryPlace::kHost, &r.readback);
      !s.ok())
    return s.error();
  if (Status s = create_frame_resources(r.context, &r.frame); !s.ok()) return s.error();
  return renderer;
}

Status Renderer::render(const RenderFrame& frame) {
  if (!impl_) return make_error("renderer: not created");
  Impl& r = *impl_;
  const Context& ctx = r.context;
  ZONA_VK_TRY(vkWaitForFences(ctx.device, 1, &r.frame.fence, VK_TRUE, UINT64_MAX));
  const VkExtent2D extent = r.attachments.extent;
  if (Status s = prepare_frame(ctx, &r.overlay, frame, extent, &r.cpu, &r.frame); !s.ok()) return s;
  ZONA_VK_TRY(vkResetFences(ctx.device, 1, &r.frame.fence));
  VkCommandBuffer cmd = r.frame.cmd;
  ZONA_VK_TRY(vkResetCommandBuffer(cmd, 0));
  VkCommandBufferBeginInfo begin{VK_STRUCTURE_TYPE_COMMAND_BUFFER_BEGIN_INFO};
  begin.flags = VK_COMMAND_BUFFER_USAGE_ONE_TIME_SUBMIT_BIT;
  ZONA_VK_TRY(vkBeginCommandBuffer(cmd, &begin));
  image_barrier(cmd, r.target.image, VK_IMAGE_ASPECT_COLOR_BIT, VK_IMAGE_LAYOUT_UNDEFINED,
                VK_IMAGE_LAYOUT_COLOR_ATTACHMENT_OPTIMAL, VK_PIPELINE_STAGE_2_COPY_BIT, 0,
                VK_PIPELINE_STAGE_2_COLOR_ATTACHMENT_OUTPUT_BIT,
                VK_ACCESS_2_COLOR_ATTACHMENT_WRITE_BIT);
  record_frame(cmd, r.pipelines, r.attachments, r.cpu, r.frame, r.target.view);
  image_barrier(cmd, r.target.image, VK_IMAGE_ASPECT_COLOR_BIT,
                VK_IMAGE_LAYOUT_COLOR_ATTACHMENT_OPTIMAL, VK_IMAGE_LAYOUT_TRANSFER_SRC_OPTIMAL,
                VK_PIPELINE_STAGE_2_COLOR_ATTACHMENT_OUTPUT_BIT,
                VK_ACCESS_2_COLOR_ATTACHMENT_WRITE_BIT, VK_PIPELINE_STAGE_2_COPY_BIT,
                VK_ACCESS_2_TRANSFER_READ_BIT);
  VkBufferImageCopy region{};
  region.imageSubresource = {VK_IMAGE_ASPECT_COLOR_BIT, 0, 0, 1};
  region.imageExtent = {extent.width, extent.height, 1};
  vkCmdCopyImageToBuffer(cmd, r.target.image, VK_IMAGE_LAYOUT_TRANSFER_SRC_OPTIMAL,
                         r.readback.buffer, 1, &region);
  // Make the copy visible to the host's read after the fence.
  VkMemoryBarrier2 host{VK_STRUCTURE_TYPE_MEMORY_BARRIER_2};
  host.srcStageMask = VK_PIPELINE_STAGE_2_COPY_BIT;
  host.srcAccessMask = VK_ACCESS_2_TRANSFER_WRITE_BIT;
  host.dstStageMask = VK_PIPELINE_STAGE_2_HOST_BIT;
  host.dstAccessMask = VK_ACCESS_2_HOST_READ_BIT;
  VkDependencyInfo dep{VK_STRUCTURE_TYPE_DEPENDENCY_INFO};
  dep.memoryBarrierCount = 1;
  dep.pMemoryBarriers = &host;
  vkCmdPipelineBarrier2(cmd, &dep);
  ZONA_VK_TRY(vkEndCommandBuffer(cmd));
  VkSubmitInfo submit{VK_STRUCTURE_TYPE_SUBMIT_INFO};
  submit.commandBufferCount = 1;
  submit.pCommandBuffers = &cmd;
  ZONA_VK_TRY(vkQueueSubmit(ctx.queue, 1, &submit, r.frame.fence));
  ZONA_VK_TRY(vkWaitForFences(ctx.device, 1, &r.frame.fence, VK_TRUE, UINT64_MAX));
  r.rendered = true;
  return {};
}

Status Renderer::read_pixels(PixelImage* image) const {
  if (!impl_ || !impl_->rendered) return make_error("renderer: nothing rendered yet");
  image->width = impl_->width;
  image->height = impl_->height;
  const size_t bytes = static_cast<size_t>(image->width) * image->height * 4;
  image->rgba.resize(bytes);
  std::memcpy(image->rgba.data(), impl_->readback.mapped, bytes);
  return {};
}

Status Renderer::render_to_png(const RenderFrame& frame, const std::string& path) {
  if (Status s = render(frame); !s.ok()) return s;
  PixelImage image;
  if (Status s = read_pixels(&image); !s.ok()) return s;
  return write_png(path, image);
}

void camera_render_space(const OrbitCamera& camera, Vec3d* origin, double* scale) {
  const RenderSpace space = camera_matrices(camera, 1.0).space;
  *origin = space.origin;
  *scale = space.scale;
}

Result<SharedSurface> Renderer::create_shared_surface(std::span<const Triangle> triangles,
                                                      size_t vertex_count) {
  if (!impl_) return make_error("renderer: not created");
  Impl& r = *impl_;
  SharedSurface out;
  // The copy path's compaction (first use order), so both paths number vertices alike.
  std::vector<int32_t> compact(vertex_count, -1);
  out.indices.reserve(3 * triangles.size());
  for (size_t t = 0; t < triangles.size(); ++t)
    for (int32_t v : triangles[t]) {
      if (v < 0 || static_cast<size_t>(v) >= vertex_count)
        return make_error("renderer: shared surface triangle %zu has vertex %d, vertex count %zu",
                          t, v, vertex_count);
      if (compact[static_cast<size_t>(v)] < 0) {
        compact[static_cast<size_t>(v)] = static_cast<int32_t>(out.mesh_vertex.size());
        out.mesh_vertex.push_back(v);
      }
      out.indices.push_back(static_cast<uint32_t>(compact[static_cast<size_t>(v)]));
    }
  if (out.indices.empty()) return make_error("renderer: shared surface without triangles");
  if (!r.context.external_memory)
    return make_error(
        "renderer: external memory not enabled (RendererOptions::external_memory, "
        "or the device lacks VK_KHR_external_memory_fd)");
  if (!vkGetMemoryFdKHR) return make_error("renderer: vkGetMemoryFdKHR not available");

  if (r.frame.fence) ZONA_VK_TRY(vkWaitForFences(r.context.device, 1, &r.frame.fence, VK_TRUE,
                                                 UINT64_MAX));
  destroy_buffer(r.context, &r.shared.vertices);
  destroy_buffer(r.context, &r.shared.indices);
  r.frame.shared = nullptr;
  const VkDeviceSize stream = out.mesh_vertex.size() * sizeof(gpu::vec4);
  if (Status s = create_buffer(r.context, 2 * stream, VK_BUFFER_USAGE_VERTEX_BUFFER_BIT,
                               MemoryPlace::kDevice, &r.shared.vertices, true);
      !s.ok())
    return s.error();
  const VkDeviceSize index_bytes = out.indices.size() * sizeof(uint32_t);
  if (Status s = create_buffer(r.context, index_bytes, VK_BUFFER_USAGE_INDEX_BUFFER_BIT,
                               MemoryPlace::kHost, &r.shared.indices);
      !s.ok())
    return s.error();
  std::memcpy(r.shared.indices.mapped, out.indices.data(), index_bytes);
  r.shared.positions_offset = 0;
  r.shared.normals_offset = stream;
  r.shared.index_count = static_cast<uint32_t>(out.indices.size());

  VkMemoryGetFdInfoKHR info{VK_STRUCTURE_TYPE_MEMORY_GET_FD_INFO_KHR};
  info.memory = r.shared.vertices.memory;
  info.handleType = VK_EXTERNAL_MEMORY_HANDLE_TYPE_OPAQUE_FD_BIT;
  ZONA_VK_TRY(vkGetMemoryFdKHR(r.context.device, &info, &out.fd));
  VkMemoryRequirements req;
  vkGetBufferMemoryRequirements(r.context.device, r.shared.vertices.buffer, &req);
  out.bytes = req.size;
  out.positions_offset = r.shared.positions_offset;
  out.normals_offset = r.shared.normals_offset;
  std::memcpy(out.device_uuid.data(), r.context.device_uuid, out.device_uuid.size());
  r.frame.shared = &r.shared;
  return out;
}

Status write_png(const std::string& path, const PixelImage& image) {
  if (image.width <= 0 || image.height <= 0 ||
      image.rgba.size() != static_cast<size_t>(image.width) * image.height * 4)
    return make_error("%s: image is empty or its pixel array has the wrong size", path.c_str());
  std::vector<uint8_t> rgb(static_cast<size_t>(image.width) * image.height * 3);
  for (size_t i = 0, n = rgb.size() / 3; i < n; ++i)
    std::memcpy(&rgb[3 * i], &image.rgba[4 * i], 3);
  if (!stbi_write_png(path.c_str(), image.width, image.height, 3, rgb.data(), image.width * 3))
    return make_error("%s: cannot write the PNG file", path.c_str());
  return {};
}

FrameSequence::FrameSequence(Renderer* renderer, std::string directory, std::string prefix)
    : renderer_(renderer), directory_(std::move(directory)), prefix_(std::move(prefix)) {}

Status FrameSequence::write(const RenderFrame& frame, std::string* path) {
  std::error_code ec;
  std::filesystem::create_directories(directory_, ec);
  if (ec)
    return make_error("%s: cannot create the folder: %s", directory_.c_str(), ec.message().c_str());
  char name[64];
  std::snprintf(name, sizeof(name), "%05d.png", count_);
  const std::string file = (std::filesystem::path(directory_) / (prefix_ + name)).string();
  if (Status s = renderer_->render_to_png(frame, file); !s.ok()) return s;
  ++count_;
  if (path) *path = file;
  return {};
}

}  // namespace zona
