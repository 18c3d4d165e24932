// Pipelines, attachments, per-frame uploads and command recording (draw.h).
#include "render/draw.h"

#include <imgui.h>

#include <algorithm>
#include <cmath>
#include <cstring>

namespace zona::render {
namespace {

// SPIR-V compiled by glslc at build time (render/CMakeLists.txt), as C initialiser lists.
const uint32_t kSurfaceVert[] =
#include "surface.vert.inc"
    ;
const uint32_t kSurfaceFrag[] =
#include "surface.frag.inc"
    ;
const uint32_t kOverlayVert[] =
#include "overlay.vert.inc"
    ;
const uint32_t kOverlayFrag[] =
#include "overlay.frag.inc"
    ;

enum class Blend { kOpaque, kAlpha };

struct PipelineDesc {
  const uint32_t* vert;
  size_t vert_bytes;
  const uint32_t* frag;
  size_t frag_bytes;
  VkPipelineLayout layout;
  bool overlay;  // ImGui vertex layout, no depth
  Blend blend;
  bool depth_write;
};

Status create_pipeline(const Context& context, const Pipelines& p, const PipelineDesc& d,
                       VkPipeline* pipeline) {
  VkShaderModule vert = VK_NULL_HANDLE, frag = VK_NULL_HANDLE;
  if (Status s = create_shader_module(context, d.vert, d.vert_bytes, &vert); !s.ok()) return s;
  if (Status s = create_shader_module(context, d.frag, d.frag_bytes, &frag); !s.ok()) {
    vkDestroyShaderModule(context.device, vert, nullptr);
    return s;
  }
  VkPipelineShaderStageCreateInfo stages[2] = {
      {VK_STRUCTURE_TYPE_PIPELINE_SHADER_STAGE_CREATE_INFO, nullptr, 0, VK_SHADER_STAGE_VERTEX_BIT,
       vert, "main", nullptr},
      {VK_STRUCTURE_TYPE_PIPELINE_SHADER_STAGE_CREATE_INFO, nullptr, 0,
       VK_SHADER_STAGE_FRAGMENT_BIT, frag, "main", nullptr}};

  // Vertex layouts: the 3D pass reads positions and normals from two buffers (shared.h);
  // the overlay reads ImGui's interleaved ImDrawVert.
  VkVertexInputBindingDescription bindings[2];
  VkVertexInputAttributeDescription attributes[3];
  VkPipelineVertexInputStateCreateInfo input{
      VK_STRUCTURE_TYPE_PIPELINE_VERTEX_INPUT_STATE_CREATE_INFO};
  if (d.overlay) {
    bindings[0] = {0, sizeof(ImDrawVert), VK_VERTEX_INPUT_RATE_VERTEX};
    attributes[0] = {0, 0, VK_FORMAT_R32G32_SFLOAT, offsetof(ImDrawVert, pos)};
    attributes[1] = {1, 0, VK_FORMAT_R32G32_SFLOAT, offsetof(ImDrawVert, uv)};
    attributes[2] = {2, 0, VK_FORMAT_R8G8B8A8_UNORM, offsetof(ImDrawVert, col)};
    input.vertexBindingDescriptionCount = 1;
    input.vertexAttributeDescriptionCount = 3;
  } else {
    bindings[0] = {0, sizeof(gpu::vec4), VK_VERTEX_INPUT_RATE_VERTEX};
    bindings[1] = {1, sizeof(gpu::vec4), VK_VERTEX_INPUT_RATE_VERTEX};
    attributes[0] = {gpu::kAttribPosition, 0, VK_FORMAT_R32G32B32A32_SFLOAT, 0};
    attributes[1] = {gpu::kAttribNormal, 1, VK_FORMAT_R32G32B32A32_SFLOAT, 0};
    input.vertexBindingDescriptionCount = 2;
    input.vertexAttributeDescriptionCount = 2;
  }
  input.pVertexBindingDescriptions = bindings;
  input.pVertexAttributeDescriptions = attributes;

  VkPipelineInputAssemblyStateCreateInfo assembly{
      VK_STRUCTURE_TYPE_PIPELINE_INPUT_ASSEMBLY_STATE_CREATE_INFO};
  assembly.topology = VK_PRIMITIVE_TOPOLOGY_TRIANGLE_LIST;
  VkPipelineViewportStateCreateInfo viewport{VK_STRUCTURE_TYPE_PIPELINE_VIEWPORT_STATE_CREATE_INFO};
  viewport.viewportCount = 1;
  viewport.scissorCount = 1;
  VkPipelineRasterizationStateCreateInfo raster{
      VK_STRUCTURE_TYPE_PIPELINE_RASTERIZATION_STATE_CREATE_INFO};
  raster.polygonMode = VK_POLYGON_MODE_FILL;
  raster.cullMode = VK_CULL_MODE_NONE;  // two-sided: tubes are seen from inside, folds happen
  raster.frontFace = VK_FRONT_FACE_COUNTER_CLOCKWISE;
  raster.lineWidth = 1.0f;
  VkPipelineMultisampleStateCreateInfo multisample{
      VK_STRUCTURE_TYPE_PIPELINE_MULTISAMPLE_STATE_CREATE_INFO};
  multisample.rasterizationSamples = p.samples;
  VkPipelineDepthStencilStateCreateInfo depth{
      VK_STRUCTURE_TYPE_PIPELINE_DEPTH_STENCIL_STATE_CREATE_INFO};
  depth.depthTestEnable = d.overlay ? VK_FALSE : VK_TRUE;
  depth.depthWriteEnable = d.depth_write ? VK_TRUE : VK_FALSE;
  depth.depthCompareOp = VK_COMPARE_OP_LESS_OR_EQUAL;
  VkPipelineColorBlendAttachmentState blend{};
  blend.colorWriteMask = VK_COLOR_COMPONENT_R_BIT | VK_COLOR_COMPONENT_G_BIT |
                         VK_COLOR_COMPONENT_B_BIT | VK_COLOR_COMPONENT_A_BIT;
  if (d.blend == Blend::kAlpha) {
    blend.blendEnable = VK_TRUE;
    blend.srcColorBlendFactor = VK_BLEND_FACTOR_SRC_ALPHA;
    blend.dstColorBlendFactor = VK_BLEND_FACTOR_ONE_MINUS_SRC_ALPHA;
    blend.colorBlendOp = VK_BLEND_OP_ADD;
    blend.srcAlphaBlendFactor = VK_BLEND_FACTOR_ONE;
    blend.dstAlphaBlendFactor = VK_BLEND_FACTOR_ONE_MINUS_SRC_ALPHA;
    blend.alphaBlendOp = VK_BLEND_OP_ADD;
  }
  VkPipelineColorBlendStateCreateInfo color_blend{
      VK_STRUCTURE_TYPE_PIPELINE_COLOR_BLEND_STATE_CREATE_INFO};
  color_blend.attachmentCount = 1;
  color_blend.pAttachments = &blend;
  const VkDynamicState dynamic_states[] = {VK_DYNAMIC_STATE_VIEWPORT, VK_DYNAMIC_STATE_SCISSOR};
  VkPipelineDynamicStateCreateInfo dynamic{VK_STRUCTURE_TYPE_PIPELINE_DYNAMIC_STATE_CREATE_INFO};
  dynamic.dynamicStateCount = 2;
  dynamic.pDynamicStates = dynamic_states;
  VkPipelineRenderingCreateInfo rendering{VK_STRUCTURE_TYPE_PIPELINE_RENDERING_CREATE_INFO};
  rendering.colorAttachmentCount = 1;
  rendering.pColorAttachmentFormats = &p.color_format;
  rendering.depthAttachmentFormat = p.depth_format;

  VkGraphicsPipelineCreateInfo info{VK_STRUCTURE_TYPE_GRAPHICS_PIPELINE_CREATE_INFO};
  info.pNext = &rendering;
  info.stageCount = 2;
  info.pStages = stages;
  info.pVertexInputState = &input;
  info.pInputAssemblyState = &assembly;
  info.pViewportState = &viewport;
  info.pRasterizationState = &raster;
  info.pMultisampleState = &multisample;
  info.pDepthStencilState = &depth;
  info.pColorBlendState = &color_blend;
  info.pDynamicState = &dynamic;
  info.layout = d.layout;
  const VkResult r =
      vkCreateGraphicsPipelines(context.device, VK_NULL_HANDLE, 1, &info, nullptr, pipeline);
  vkDestroyShaderModule(context.device, vert, nullptr);
  vkDestroyShaderModule(context.device, frag, nullptr);
  ZONA_VK_TRY(r);
  return {};
}

Status upload_font(const Context& context, const OverlayState& overlay, Pipelines* p) {
  const VkExtent2D size{static_cast<uint32_t>(overlay.font_width),
                        static_cast<uint32_t>(overlay.font_height)};
  // The atlas holds coverage in alpha and white in rgb: a UNORM format keeps it linear.
  if (Status s = create_image(context, size.width, size.height, VK_FORMAT_R8G8B8A8_UNORM,
                              VK_IMAGE_USAGE_SAMPLED_BIT | VK_IMAGE_USAGE_TRANSFER_DST_BIT,
                              VK_SAMPLE_COUNT_1_BIT, VK_IMAGE_ASPECT_COLOR_BIT, &p->font);
      !s.ok())
    return s;
  Buffer staging;
  if (Status s = create_buffer(context, overlay.font_pixels.size(),
                               VK_BUFFER_USAGE_TRANSFER_SRC_BIT, MemoryPlace::kHost, &staging);
      !s.ok())
    return s;
  std::memcpy(staging.mapped, overlay.font_pixels.data(), overlay.font_pixels.size());
  const Status s = submit_and_wait(context, [&](VkCommandBuffer cmd) {
    image_barrier(cmd, p->font.image, VK_IMAGE_ASPECT_COLOR_BIT, VK_IMAGE_LAYOUT_UNDEFINED,
                  VK_IMAGE_LAYOUT_TRANSFER_DST_OPTIMAL, VK_PIPELINE_STAGE_2_NONE, 0,
                  VK_PIPELINE_STAGE_2_COPY_BIT, VK_ACCESS_2_TRANSFER_WRITE_BIT);
    VkBufferImageCopy region{};
    region.imageSubresource = {VK_IMAGE_ASPECT_COLOR_BIT, 0, 0, 1};
    region.imageExtent = {size.width, size.height, 1};
    vkCmdCopyBufferToImage(cmd, staging.buffer, p->font.image, VK_IMAGE_LAYOUT_TRANSFER_DST_OPTIMAL,
                           1, &region);
    image_barrier(cmd, p->font.image, VK_IMAGE_ASPECT_COLOR_BIT,
                  VK_IMAGE_LAYOUT_TRANSFER_DST_OPTIMAL, VK_IMAGE_LAYOUT_SHADER_READ_ONLY_OPTIMAL,
                  VK_PIPELINE_STAGE_2_COPY_BIT, VK_ACCESS_2_TRANSFER_WRITE_BIT,
                  VK_PIPELINE_STAGE_2_FRAGMENT_SHADER_BIT, VK_ACCESS_2_SHADER_SAMPLED_READ_BIT);
  });
  destroy_buffer(context, &staging);
  return s;
}

// Grows a host buffer to hold `bytes` (doubling, so a growing mesh reallocates rarely).
Status ensure_buffer(const Context& context, Buffer* buffer, VkDeviceSize bytes,
                     VkBufferUsageFlags usage) {
  bytes = std::max<VkDeviceSize>(bytes, 256);
  if (buffer->size >= bytes) return {};
  const VkDeviceSize size = std::max(bytes, 2 * buffer->size);
  destroy_buffer(context, buffer);
  return create_buffer(context, size, usage, MemoryPlace::kHost, buffer);
}

template <class T>
Status upload(const Context& context, Buffer* buffer, const std::vector<T>& data,
              VkBufferUsageFlags usage) {
  const VkDeviceSize bytes = data.size() * sizeof(T);
  if (Status s = ensure_buffer(context, buffer, bytes, usage); !s.ok()) return s;
  if (bytes) std::memcpy(buffer->mapped, data.data(), bytes);
  return {};
}

gpu::vec3 srgb_to_linear(Vec3f c) {
  return {std::pow(c.x, 2.2f), std::pow(c.y, 2.2f), std::pow(c.z, 2.2f)};
}

}  // namespace

VkSampleCountFlagBits pick_samples(const Context& context, int wanted) {
  const VkSampleCountFlags supported = context.properties.limits.framebufferColorSampleCounts &
                                       context.properties.limits.framebufferDepthSampleCounts;
  for (int s = 8; s > 1; s /= 2)
    if (s <= wanted && (supported & static_cast<VkSampleCountFlags>(s)))
      return static_cast<VkSampleCountFlagBits>(s);
  return VK_SAMPLE_COUNT_1_BIT;
}

Status create_pipelines(const Context& context, VkFormat color_format,
                        VkSampleCountFlagBits samples, const OverlayState& overlay, Pipelines* p) {
  p->color_format = color_format;
  p->samples = samples;
  VkPushConstantRange mesh_push{VK_SHADER_STAGE_VERTEX_BIT | VK_SHADER_STAGE_FRAGMENT_BIT, 0,
                                sizeof(gpu::DrawConstants)};
  VkPipelineLayoutCreateInfo mesh_layout{VK_STRUCTURE_TYPE_PIPELINE_LAYOUT_CREATE_INFO};
  mesh_layout.pushConstantRangeCount = 1;
  mesh_layout.pPushConstantRanges = &mesh_push;
  ZONA_VK_TRY(vkCreatePipelineLayout(context.device, &mesh_layout, nullptr, &p->mesh_layout));

  // Overlay: one combined image sampler (the font atlas), allocated once.
  VkSamplerCreateInfo sampler{VK_STRUCTURE_TYPE_SAMPLER_CREATE_INFO};
  sampler.magFilter = VK_FILTER_LINEAR;
  sampler.minFilter = VK_FILTER_LINEAR;
  sampler.addressModeU = sampler.addressModeV = sampler.addressModeW =
      VK_SAMPLER_ADDRESS_MODE_CLAMP_TO_EDGE;
  sampler.maxLod = 1.0f;
  ZONA_VK_TRY(vkCreateSampler(context.device, &sampler, nullptr, &p->sampler));
  VkDescriptorSetLayoutBinding binding{0, VK_DESCRIPTOR_TYPE_COMBINED_IMAGE_SAMPLER, 1,
                                       VK_SHADER_STAGE_FRAGMENT_BIT, nullptr};
  VkDescriptorSetLayoutCreateInfo set_layout{VK_STRUCTURE_TYPE_DESCRIPTOR_SET_LAYOUT_CREATE_INFO};
  set_layout.bindingCount = 1;
  set_layout.pBindings = &binding;
  ZONA_VK_TRY(
      vkCreateDescriptorSetLayout(context.device, &set_layout, nullptr, &p->font_set_layout));
  VkDescriptorPoolSize pool_size{VK_DESCRIPTOR_TYPE_COMBINED_IMAGE_SAMPLER, 1};
  VkDescriptorPoolCreateInfo pool{VK_STRUCTURE_TYPE_DESCRIPTOR_POOL_CREATE_INFO};
  pool.maxSets = 1;
  pool.poolSizeCount = 1;
  pool.pPoolSizes = &pool_size;
  ZONA_VK_TRY(vkCreateDescriptorPool(context.device, &pool, nullptr, &p->descriptor_pool));
  VkDescriptorSetAllocateInfo alloc{VK_STRUCTURE_TYPE_DESCRIPTOR_SET_ALLOCATE_INFO};
  alloc.descriptorPool = p->descriptor_pool;
  alloc.descriptorSetCount = 1;
  alloc.pSetLayouts = &p->font_set_layout;
  ZONA_VK_TRY(vkAllocateDescriptorSets(context.device, &alloc, &p->font_set));
  if (Status s = upload_font(context, overlay, p); !s.ok()) return s;
  VkDescriptorImageInfo image{p->sampler, p->font.view, VK_IMAGE_LAYOUT_SHADER_READ_ONLY_OPTIMAL};
  VkWriteDescriptorSet write{VK_STRUCTURE_TYPE_WRITE_DESCRIPTOR_SET};
  write.dstSet = p->font_set;
  write.descriptorCount = 1;
  write.descriptorType = VK_DESCRIPTOR_TYPE_COMBINED_IMAGE_SAMPLER;
  write.pImageInfo = &image;
  vkUpdateDescriptorSets(context.device, 1, &write, 0, nullptr);
  VkPushConstantRange overlay_push{VK_SHADER_STAGE_VERTEX_BIT, 0, sizeof(gpu::OverlayConstants)};
  VkPipelineLayoutCreateInfo overlay_layout{VK_STRUCTURE_TYPE_PIPELINE_LAYOUT_CREATE_INFO};
  overlay_layout.setLayoutCount = 1;
  overlay_layout.pSetLayouts = &p->font_set_layout;
  overlay_layout.pushConstantRangeCount = 1;
  overlay_layout.pPushConstantRanges = &overlay_push;
  ZONA_VK_TRY(vkCreatePipelineLayout(context.device, &overlay_layout, nullptr, &p->overlay_layout));

  const PipelineDesc surface{
      kSurfaceVert, sizeof(kSurfaceVert), kSurfaceFrag, sizeof(kSurfaceFrag), p->mesh_layout,
      false,        Blend::kOpaque,       true};
  PipelineDesc glass = surface;
  glass.blend = Blend::kAlpha;
  glass.depth_write = false;
  const PipelineDesc overlay_desc{
      kOverlayVert, sizeof(kOverlayVert), kOverlayFrag, sizeof(kOverlayFrag), p->overlay_layout,
      true,         Blend::kAlpha,        false};
  if (Status s = create_pipeline(context, *p, surface, &p->surface); !s.ok()) return s;
  if (Status s = create_pipeline(context, *p, glass, &p->glass); !s.ok()) return s;
  return create_pipeline(context, *p, overlay_desc, &p->overlay);
}

void destroy_pipelines(const Context& context, Pipelines* p) {
  if (!context.device) return;
  for (VkPipeline pipeline : {p->surface, p->glass, p->overlay})
    if (pipeline) vkDestroyPipeline(context.device, pipeline, nullptr);
  if (p->mesh_layout) vkDestroyPipelineLayout(context.device, p->mesh_layout, nullptr);
  if (p->overlay_layout) vkDestroyPipelineLayout(context.device, p->overlay_layout, nullptr);
  if (p->descriptor_pool) vkDestroyDescriptorPool(context.device, p->descriptor_pool, nullptr);
  if (p->font_set_layout) vkDestroyDescriptorSetLayout(context.device, p->font_set_layout, nullptr);
  if (p->sampler) vkDestroySampler(context.device, p->sampler, nullptr);
  destroy_image(context, &p->font);
  *p = Pipelines{};
}

Status create_attachments(const Context& context, const Pipelines& p, VkExtent2D extent,
                          Attachments* a) {
  a->extent = extent;
  if (p.samples != VK_SAMPLE_COUNT_1_BIT) {
    if (Status s = create_image(
            context, extent.width, extent.height, p.color_format,
            VK_IMAGE_USAGE_COLOR_ATTACHMENT_BIT | VK_IMAGE_USAGE_TRANSIENT_ATTACHMENT_BIT,
            p.samples, VK_IMAGE_ASPECT_COLOR_BIT, &a->color);
        !s.ok())
      return s;
  }
  return create_image(
      context, extent.width, extent.height, p.depth_format,
      VK_IMAGE_USAGE_DEPTH_STENCIL_ATTACHMENT_BIT | VK_IMAGE_USAGE_TRANSIENT_ATTACHMENT_BIT,
      p.samples, VK_IMAGE_ASPECT_DEPTH_BIT, &a->depth);
}

void destroy_attachments(const Context& context, Attachments* a) {
  destroy_image(context, &a->color);
  destroy_image(context, &a->depth);
  a->extent = {0, 0};
}

Status create_frame_resources(const Context& context, FrameResources* f) {
  VkCommandBufferAllocateInfo alloc{VK_STRUCTURE_TYPE_COMMAND_BUFFER_ALLOCATE_INFO};
  alloc.commandPool = context.command_pool;
  alloc.level = VK_COMMAND_BUFFER_LEVEL_PRIMARY;
  alloc.commandBufferCount = 1;
  ZONA_VK_TRY(vkAllocateCommandBuffers(context.device, &alloc, &f->cmd));
  VkFenceCreateInfo fence{VK_STRUCTURE_TYPE_FENCE_CREATE_INFO};
  fence.flags = VK_FENCE_CREATE_SIGNALED_BIT;  // the first wait returns at once
  ZONA_VK_TRY(vkCreateFence(context.device, &fence, nullptr, &f->fence));
  return {};
}

void destroy_frame_resources(const Context& context, FrameResources* f) {
  if (!context.device) return;
  for (Buffer* b :
       {&f->surface_positions, &f->surface_normals, &f->surface_indices, &f->tool_positions,
        &f->tool_normals, &f->tool_indices, &f->overlay_vertices, &f->overlay_indices})
    destroy_buffer(context, b);
  if (f->fence) vkDestroyFence(context.device, f->fence, nullptr);
  if (f->cmd) vkFreeCommandBuffers(context.device, context.command_pool, 1, &f->cmd);
  *f = FrameResources{};
}

Status prepare_frame(const Context& context, OverlayState* overlay, const RenderFrame& frame,
                     VkExtent2D extent, CpuFrame* cpu, FrameResources* r) {
  const double aspect = static_cast<double>(extent.width) / std::max(1u, extent.height);
  cpu->camera = camera_matrices(frame.camera, aspect);
  cpu->shared = frame.shared_surface;
  if (cpu->shared) {
    if (!r->shared || r->shared->index_count == 0)
      return make_error(
          "render frame: shared_surface is set but the renderer has no shared surface "
          "(Renderer::create_shared_surface)");
  } else if (Status s = update_surface(frame, cpu->camera.space, &cpu->surface); !s.ok()) {
    return s;
  }
  cpu->color_map =
      frame.field != ColorField::kNone && (cpu->shared || !frame.scalar.empty());
  // The shared surface's range comes with the frame (the CUDA writer measured it).
  const bool auto_range = frame.auto_range && !cpu->shared;
  cpu->lo = auto_range ? cpu->surface.scalar_min : frame.scalar_min;
  // Stress under a point-like tip is singular: a few tetrahedra would stretch the range and
  // leave the rest of the cell one colour, so its automatic top is the 98th percentile (the
  // peak saturates red). Displacement shows its true maximum, the indentation depth.
  const double auto_hi =
      frame.field == ColorField::kStress ? cpu->surface.scalar_p98 : cpu->surface.scalar_max;
  cpu->hi = auto_range ? auto_hi : frame.scalar_max;
  // A constant field (the cell at rest) gets one legend unit of range: its colour is the
  // map's bottom and the labels stay readable.
  if (!(cpu->hi > cpu->lo)) cpu->hi = cpu->lo + field_unit(frame.field);
  cpu->cell_color = gpu::vec4(frame.cell_color.x, frame.cell_color.y, frame.cell_color.z, 1.0f);
  cpu->background = gpu::vec4(srgb_to_linear(frame.background), 1.0f);

  // Tools reach three camera distances back: out of the view for any sensible camera.
  cpu->tools.clear();
  const double tool_length = 3.0 * frame.camera.distance;
  append_needle(frame.needle, tool_length, cpu->camera.space, &cpu->tools);
  cpu->needle_indices = static_cast<uint32_t>(cpu->tools.indices.size());
  append_holding(frame.holding, tool_length, cpu->camera.space, &cpu->tools);

  constexpr VkBufferUsageFlags kVertex = VK_BUFFER_USAGE_VERTEX_BUFFER_BIT;
  constexpr VkBufferUsageFlags kIndex = VK_BUFFER_USAGE_INDEX_BUFFER_BIT;
  const MeshData& m = cpu->surface.mesh;
  if (!cpu->shared)
    for (Status s : {upload(context, &r->surface_positions, m.positions, kVertex),
                     upload(context, &r->surface_normals, m.normals, kVertex),
                     upload(context, &r->surface_indices, m.indices, kIndex)})
      if (!s.ok()) return s;
  for (Status s : {upload(context, &r->tool_positions, cpu->tools.positions, kVertex),
                   upload(context, &r->tool_normals, cpu->tools.normals, kVertex),
                   upload(context, &r->tool_indices, cpu->tools.indices, kIndex)})
    if (!s.ok()) return s;

  // Overlay: ImGui's lists concatenated into one vertex and one index buffer.
  ImDrawData* draw = build_overlay(overlay, frame, cpu->lo, cpu->hi, static_cast<int>(extent.width),
                                   static_cast<int>(extent.height));
  r->overlay = draw;
  const VkDeviceSize vbytes = static_cast<VkDeviceSize>(draw->TotalVtxCount) * sizeof(ImDrawVert);
  const VkDeviceSize ibytes = static_cast<VkDeviceSize>(draw->TotalIdxCount) * sizeof(ImDrawIdx);
  if (Status s = ensure_buffer(context, &r->overlay_vertices, vbytes, kVertex); !s.ok()) return s;
  if (Status s = ensure_buffer(context, &r->overlay_indices, ibytes, kIndex); !s.ok()) return s;
  auto* vdst = static_cast<ImDrawVert*>(r->overlay_vertices.mapped);
  auto* idst = static_cast<ImDrawIdx*>(r->overlay_indices.mapped);
  for (int i = 0; i < draw->CmdListsCount; ++i) {
    const ImDrawList* list = draw->CmdLists[i];
    std::memcpy(vdst, list->VtxBuffer.Data, list->VtxBuffer.Size * sizeof(ImDrawVert));
    std::memcpy(idst, list->IdxBuffer.Data, list->IdxBuffer.Size * sizeof(ImDrawIdx));
    vdst += list->VtxBuffer.Size;
    idst += list->IdxBuffer.Size;
  }
  return {};
}

void record_frame(VkCommandBuffer cmd, const Pipelines& p, const Attachments& a,
                  const CpuFrame& cpu, const FrameResources& r, VkImageView target) {
  const bool msaa = p.samples != VK_SAMPLE_COUNT_1_BIT;
  // Attachments are cleared every frame: their old contents are discarded (UNDEFINED).
  if (msaa)
    image_barrier(
        cmd, a.color.image, VK_IMAGE_ASPECT_COLOR_BIT, VK_IMAGE_LAYOUT_UNDEFINED,
        VK_IMAGE_LAYOUT_COLOR_ATTACHMENT_OPTIMAL, VK_PIPELINE_STAGE_2_COLOR_ATTACHMENT_OUTPUT_BIT,
        0, VK_PIPELINE_STAGE_2_COLOR_ATTACHMENT_OUTPUT_BIT, VK_ACCESS_2_COLOR_ATTACHMENT_WRITE_BIT);
  image_barrier(
      cmd, a.depth.image, VK_IMAGE_ASPECT_DEPTH_BIT, VK_IMAGE_LAYOUT_UNDEFINED,
      VK_IMAGE_LAYOUT_DEPTH_ATTACHMENT_OPTIMAL,
      VK_PIPELINE_STAGE_2_EARLY_FRAGMENT_TESTS_BIT | VK_PIPELINE_STAGE_2_LATE_FRAGMENT_TESTS_BIT,
      VK_ACCESS_2_DEPTH_STENCIL_ATTACHMENT_WRITE_BIT,
      VK_PIPELINE_STAGE_2_EARLY_FRAGMENT_TESTS_BIT | VK_PIPELINE_STAGE_2_LATE_FRAGMENT_TESTS_BIT,
      VK_ACCESS_2_DEPTH_STENCIL_ATTACHMENT_READ_BIT |
          VK_ACCESS_2_DEPTH_STENCIL_ATTACHMENT_WRITE_BIT);

  VkRenderingAttachmentInfo color{VK_STRUCTURE_TYPE_RENDERING_ATTACHMENT_INFO};
  color.imageView = msaa ? a.color.view : target;
  color.imageLayout = VK_IMAGE_LAYOUT_COLOR_ATTACHMENT_OPTIMAL;
  color.loadOp = VK_ATTACHMENT_LOAD_OP_CLEAR;
  color.storeOp = msaa ? VK_ATTACHMENT_STORE_OP_DONT_CARE : VK_ATTACHMENT_STORE_OP_STORE;
  color.clearValue.color = {{cpu.background.x, cpu.background.y, cpu.background.z, 1.0f}};
  if (msaa) {
    color.resolveMode = VK_RESOLVE_MODE_AVERAGE_BIT;
    color.resolveImageView = target;
    color.resolveImageLayout = VK_IMAGE_LAYOUT_COLOR_ATTACHMENT_OPTIMAL;
  }
  VkRenderingAttachmentInfo depth{VK_STRUCTURE_TYPE_RENDERING_ATTACHMENT_INFO};
  depth.imageView = a.depth.view;
  depth.imageLayout = VK_IMAGE_LAYOUT_DEPTH_ATTACHMENT_OPTIMAL;
  depth.loadOp = VK_ATTACHMENT_LOAD_OP_CLEAR;
  depth.storeOp = VK_ATTACHMENT_STORE_OP_DONT_CARE;
  depth.clearValue.depthStencil = {1.0f, 0};
  VkRenderingInfo rendering{VK_STRUCTURE_TYPE_RENDERING_INFO};
  rendering.renderArea = {{0, 0}, a.extent};
  rendering.layerCount = 1;
  rendering.colorAttachmentCount = 1;
  rendering.pColorAttachments = &color;
  rendering.pDepthAttachment = &depth;
  vkCmdBeginRendering(cmd, &rendering);

  const VkViewport viewport{
      0, 0, static_cast<float>(a.extent.width), static_cast<float>(a.extent.height), 0, 1};
  const VkRect2D full{{0, 0}, a.extent};
  vkCmdSetViewport(cmd, 0, 1, &viewport);
  vkCmdSetScissor(cmd, 0, 1, &full);
  const VkDeviceSize zero = 0;

  gpu::DrawConstants draw{};
  draw.view_proj = cpu.camera.view_proj;
  draw.eye = gpu::vec4(cpu.camera.eye, 0.0f);
  draw.range = gpu::vec4(static_cast<float>(cpu.lo), static_cast<float>(1.0 / (cpu.hi - cpu.lo)),
                         cpu.color_map ? 1.0f : 0.0f, 0.35f);
  constexpr VkShaderStageFlags kStages = VK_SHADER_STAGE_VERTEX_BIT | VK_SHADER_STAGE_FRAGMENT_BIT;

  // Cell surface, opaque: from this frame's uploads, or from the memory CUDA wrote.
  const auto index_count = cpu.shared ? r.shared->index_count
                                      : static_cast<uint32_t>(cpu.surface.mesh.indices.size());
  if (index_count) {
    draw.color = cpu.cell_color;
    draw.eye.w = static_cast<float>(cpu.color_map ? gpu::kShadeColorMap : gpu::kShadeFlat);
    vkCmdBindPipeline(cmd, VK_PIPELINE_BIND_POINT_GRAPHICS, p.surface);
    vkCmdPushConstants(cmd, p.mesh_layout, kStages, 0, sizeof(draw), &draw);
    if (cpu.shared) {
      const VkBuffer vb[2] = {r.shared->vertices.buffer, r.shared->vertices.buffer};
      const VkDeviceSize offsets[2] = {r.shared->positions_offset, r.shared->normals_offset};
      vkCmdBindVertexBuffers(cmd, 0, 2, vb, offsets);
      vkCmdBindIndexBuffer(cmd, r.shared->indices.buffer, 0, VK_INDEX_TYPE_UINT32);
    } else {
      const VkBuffer vb[2] = {r.surface_positions.buffer, r.surface_normals.buffer};
      const VkDeviceSize offsets[2] = {0, 0};
      vkCmdBindVertexBuffers(cmd, 0, 2, vb, offsets);
      vkCmdBindIndexBuffer(cmd, r.surface_indices.buffer, 0, VK_INDEX_TYPE_UINT32);
    }
    vkCmdDrawIndexed(cmd, index_count, 1, 0, 0, 0);
  }

  // Pipettes, glass after the opaque cell so that the cell shows through them.
  const auto tool_count = static_cast<uint32_t>(cpu.tools.indices.size());
  if (tool_count) {
    vkCmdBindPipeline(cmd, VK_PIPELINE_BIND_POINT_GRAPHICS, p.glass);
    const VkBuffer vb[2] = {r.tool_positions.buffer, r.tool_normals.buffer};
    const VkDeviceSize offsets[2] = {0, 0};
    vkCmdBindVertexBuffers(cmd, 0, 2, vb, offsets);
    vkCmdBindIndexBuffer(cmd, r.tool_indices.buffer, 0, VK_INDEX_TYPE_UINT32);
    draw.eye.w = static_cast<float>(gpu::kShadeGlass);
    // Needle a little more opaque than the holding pipette: it is the tool the eye follows.
    if (cpu.needle_indices) {
      draw.color = gpu::vec4(0.78f, 0.86f, 0.93f, 0.35f);
      vkCmdPushConstants(cmd, p.mesh_layout, kStages, 0, sizeof(draw), &draw);
      vkCmdDrawIndexed(cmd, cpu.needle_indices, 1, 0, 0, 0);
    }
    if (tool_count > cpu.needle_indices) {
      draw.color = gpu::vec4(0.74f, 0.82f, 0.90f, 0.30f);
      vkCmdPushConstants(cmd, p.mesh_layout, kStages, 0, sizeof(draw), &draw);
      vkCmdDrawIndexed(cmd, tool_count - cpu.needle_indices, 1, cpu.needle_indices, 0, 0);
    }
  }

  // Overlay.
  const ImDrawData* o = r.overlay;
  if (o && o->TotalIdxCount > 0) {
    vkCmdBindPipeline(cmd, VK_PIPELINE_BIND_POINT_GRAPHICS, p.overlay);
    vkCmdBindDescriptorSets(cmd, VK_PIPELINE_BIND_POINT_GRAPHICS, p.overlay_layout, 0, 1,
                            &p.font_set, 0, nullptr);
    vkCmdBindVertexBuffers(cmd, 0, 1, &r.overlay_vertices.buffer, &zero);
    vkCmdBindIndexBuffer(cmd, r.overlay_indices.buffer, 0,
                         sizeof(ImDrawIdx) == 2 ? VK_INDEX_TYPE_UINT16 : VK_INDEX_TYPE_UINT32);
    gpu::OverlayConstants oc;
    oc.scale = gpu::vec2(2.0f / o->DisplaySize.x, 2.0f / o->DisplaySize.y);
    oc.translate =
        gpu::vec2(-1.0f - o->DisplayPos.x * oc.scale.x, -1.0f - o->DisplayPos.y * oc.scale.y);
    vkCmdPushConstants(cmd, p.overlay_layout, VK_SHADER_STAGE_VERTEX_BIT, 0, sizeof(oc), &oc);
    uint32_t vertex_base = 0, index_base = 0;
    for (int i = 0; i < o->CmdListsCount; ++i) {
      const ImDrawList* list = o->CmdLists[i];
      for (const ImDrawCmd& c : list->CmdBuffer) {
        if (c.UserCallback) continue;  // zona adds none
        const float x0 = std::max(c.ClipRect.x - o->DisplayPos.x, 0.0f);
        const float y0 = std::max(c.ClipRect.y - o->DisplayPos.y, 0.0f);
        const float x1 =
            std::min(c.ClipRect.z - o->DisplayPos.x, static_cast<float>(a.extent.width));
        const float y1 =
            std::min(c.ClipRect.w - o->DisplayPos.y, static_cast<float>(a.extent.height));
        if (x1 <= x0 || y1 <= y0) continue;
        const VkRect2D scissor{{static_cast<int32_t>(x0), static_cast<int32_t>(y0)},
                               {static_cast<uint32_t>(x1 - x0), static_cast<uint32_t>(y1 - y0)}};
        vkCmdSetScissor(cmd, 0, 1, &scissor);
        vkCmdDrawIndexed(cmd, c.ElemCount, 1, index_base + c.IdxOffset,
                         static_cast<int32_t>(vertex_base + c.VtxOffset), 0);
      }
      vertex_base += static_cast<uint32_t>(list->VtxBuffer.Size);
      index_base += static_cast<uint32_t>(list->IdxBuffer.Size);
    }
  }
  vkCmdEndRendering(cmd);
}

}  // namespace zona::render
