// The drawing machinery shared by the headless renderer and the window: pipelines (cell,
// glass pipettes, overlay), per-frame upload buffers, size-dependent attachments, and the
// recording of one frame into a colour target with dynamic rendering.
#pragma once

#include "render/context.h"
#include "render/geometry.h"
#include "render/overlay.h"
#include "render/resources.h"

namespace zona::render {

/// Pipelines and the overlay's font texture, for one colour format and sample count.
struct Pipelines {
  VkFormat color_format = VK_FORMAT_UNDEFINED;
  VkFormat depth_format = VK_FORMAT_D32_SFLOAT;
  VkSampleCountFlagBits samples = VK_SAMPLE_COUNT_1_BIT;
  VkPipelineLayout mesh_layout = VK_NULL_HANDLE;
  VkPipelineLayout overlay_layout = VK_NULL_HANDLE;
  VkDescriptorSetLayout font_set_layout = VK_NULL_HANDLE;
  VkDescriptorPool descriptor_pool = VK_NULL_HANDLE;
  VkDescriptorSet font_set = VK_NULL_HANDLE;
  VkSampler sampler = VK_NULL_HANDLE;
  Image font;
  VkPipeline surface = VK_NULL_HANDLE;  ///< opaque, depth write
  VkPipeline glass = VK_NULL_HANDLE;    ///< blended, depth test without write
  VkPipeline overlay = VK_NULL_HANDLE;  ///< blended, no depth, scissored
};

/// Creates the pipelines and uploads the overlay's font atlas.
Status create_pipelines(const Context& context, VkFormat color_format,
                        VkSampleCountFlagBits samples, const OverlayState& overlay,
                        Pipelines* pipelines);
void destroy_pipelines(const Context& context, Pipelines* pipelines);

/// The largest supported sample count not above `wanted`.
VkSampleCountFlagBits pick_samples(const Context& context, int wanted);

/// MSAA colour (when samples > 1) and depth images of one size.
struct Attachments {
  Image color;  ///< multisampled colour, resolved into the target; empty when samples == 1
  Image depth;
  VkExtent2D extent{0, 0};
};
Status create_attachments(const Context& context, const Pipelines& pipelines, VkExtent2D extent,
                          Attachments* attachments);
void destroy_attachments(const Context& context, Attachments* attachments);

/// CPU geometry of a frame, reused between frames.
struct CpuFrame {
  SurfaceGeometry surface;
  MeshData tools;
  CameraMatrices camera;
  double lo = 0, hi = 1;  ///< colour range [field SI unit]
  bool color_map = false;
  gpu::vec4 cell_color{1.0f};
  gpu::vec4 background{0.0f};   ///< linear clear colour
  uint32_t needle_indices = 0;  ///< the first tool indices are the needle's
  bool shared = false;          ///< the cell comes from the shared surface (RenderFrame)
};

/// The cell surface in memory shared with CUDA: one exported device-local allocation holding
/// the positions and then the normals (vec4 each), and its triangles.
struct SharedSurfaceBuffers {
  Buffer vertices;  ///< exportable; written by CUDA, read as two vertex streams
  Buffer indices;   ///< host-visible, written once
  VkDeviceSize positions_offset = 0, normals_offset = 0;
  uint32_t index_count = 0;
};

/// Host-visible buffers and sync of one frame in flight.
struct FrameResources {
  VkCommandBuffer cmd = VK_NULL_HANDLE;
  VkFence fence = VK_NULL_HANDLE;  ///< signalled when the frame's commands are done
  Buffer surface_positions, surface_normals, surface_indices;
  Buffer tool_positions, tool_normals, tool_indices;
  Buffer overlay_vertices, overlay_indices;
  ImDrawData* overlay = nullptr;  ///< draw data uploaded for this frame
  const SharedSurfaceBuffers* shared = nullptr;  ///< the renderer's shared surface, if any
};
Status create_frame_resources(const Context& context, FrameResources* frame);
void destroy_frame_resources(const Context& context, FrameResources* frame);

/// CPU work and uploads of one frame: surface, tools, colour range, overlay. The frame's fence
/// must have been waited for (its buffers may grow).
Status prepare_frame(const Context& context, OverlayState* overlay, const RenderFrame& frame,
                     VkExtent2D extent, CpuFrame* cpu, FrameResources* resources);

/// Records the frame's drawing into `target` (a view of a single-sample image of the pipelines'
/// colour format, already in COLOR_ATTACHMENT_OPTIMAL; left in that layout).
void record_frame(VkCommandBuffer cmd, const Pipelines& pipelines, const Attachments& attachments,
                  const CpuFrame& cpu, const FrameResources& resources, VkImageView target);

}  // namespace zona::render
