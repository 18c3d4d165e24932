// The headless renderer: draws a RenderFrame (render/frame.h) into an offscreen image with
// Vulkan and reads it back or writes a PNG. Works on any Vulkan 1.3 device, including Mesa's
// software driver lavapipe (how CI tests it). Usage:
//
//   Result<Renderer> r = create_headless_renderer(1280, 720);
//   if (!r) ...;                       // "no Vulkan loader", "no Vulkan device", ...
//   r->render_to_png(frame, "out.png");
//
// One thread at a time may use a Renderer (it owns a Dear ImGui context, which is global state).
#pragma once

#include <array>
#include <cstdint>
#include <memory>
#include <span>
#include <string>
#include <vector>

#include "engine/core/base.h"
#include "render/frame.h"

namespace zona {

/// How a renderer is created.
struct RendererOptions {
  /// Enable the Khronos validation layer and count its messages (validation()).
  bool validation = false;
  /// MSAA samples (1, 2, 4, 8); lowered to what the device supports.
  int samples = 4;
  /// Prefer the Vulkan device whose name contains this (else $ZONA_VK_DEVICE, else the best).
  std::string device_name;
  /// TrueType font of the overlay; empty: DejaVu Sans when installed, else ImGui's built-in.
  std::string font_path;
  /// Overlay text height [px]; 0: from the image height.
  float font_pixels = 0;
  /// Enable VK_KHR_external_memory_fd, for the CUDA interop (create_shared_surface()).
  bool external_memory = false;
};

/// What the validation layer reported so far.
struct ValidationReport {
  bool enabled = false;
  int errors = 0;
  int warnings = 0;
  std::vector<std::string> messages;  ///< the first few, one line each
};

/// The cell surface in device memory exported for CUDA (CUDA-Vulkan interop): what
/// kernels/surface_interop.h's make_surface_writer needs to write it.
struct SharedSurface {
  int fd = -1;           ///< opaque fd of the memory; the receiver owns it (close it, or import it)
  uint64_t bytes = 0;    ///< size of the allocation [bytes]
  uint64_t positions_offset = 0;  ///< vec4 positions, xyz render space, w the scalar [bytes]
  uint64_t normals_offset = 0;    ///< vec4 unit normals [bytes]
  std::array<uint8_t, 16> device_uuid{};  ///< the Vulkan device (CUDA must be on the same GPU)
  std::vector<int32_t> mesh_vertex;  ///< compact vertex -> mesh vertex, (surface vertex count)
  std::vector<uint32_t> indices;     ///< compact triangles, 3 per triangle
};

/// The render space of a camera: the renderer draws (x - origin) * scale, x in metres (float
/// positions keep their precision at micrometre scale). What a SurfaceWriter must be given.
void camera_render_space(const OrbitCamera& camera, Vec3d* origin, double* scale);

/// A headless renderer. Move-only; destroying it waits for the device and releases everything.
class Renderer {
 public:
  Renderer();
  Renderer(Renderer&&) noexcept;
  Renderer& operator=(Renderer&&) noexcept;
  ~Renderer();

  /// Draws the frame into the offscreen image and waits for it. Errors: inconsistent spans,
  /// a Vulkan failure.
  Status render(const RenderFrame& frame);
  /// Copies the last rendered image (RGBA8, sRGB, top row first).
  Status read_pixels(PixelImage* image) const;
  /// render() then write_png().
  Status render_to_png(const RenderFrame& frame, const std::string& path);

  int width() const;
  int height() const;
  int samples() const;
  /// Name of the Vulkan device ("llvmpipe (LLVM 15.0.6, 256 bits)", "NVIDIA H100 80GB HBM3").
  std::string device_name() const;
  ValidationReport validation() const;

  /// CUDA-Vulkan interop: allocates the cell surface of `triangles` (over `vertex_count` mesh
  /// vertices, compacted as the copy path does) in one device-local buffer whose memory is
  /// exported as an opaque fd, positions then normals, and uploads its triangles. Frames with
  /// RenderFrame::shared_surface then draw the cell from it. Replaces an earlier one. Needs
  /// RendererOptions::external_memory and a device with VK_KHR_external_memory_fd. Errors: no
  /// external memory, a vertex index out of range, an empty surface, a Vulkan failure.
  Result<SharedSurface> create_shared_surface(std::span<const Triangle> triangles,
                                              size_t vertex_count);

  struct Impl;

 private:
  std::unique_ptr<Impl> impl_;
  friend Result<Renderer> create_headless_renderer(int, int, const RendererOptions&);
};

/// Creates a headless renderer for `width` x `height` images. Errors: "no Vulkan loader",
/// "no Vulkan device ...", validation requested but not installed, a bad size.
Result<Renderer> create_headless_renderer(int width, int height,
                                          const RendererOptions& options = {});

/// Writes RGBA pixels as an RGB PNG. Errors name the path.
Status write_png(const std::string& path, const PixelImage& image);

/// Writes numbered frames DIR/frame_00000.png, frame_00001.png, ... (for `zona run --frames`).
class FrameSequence {
 public:
  /// Frames go to `directory` (created when missing) named PREFIX + 5-digit index + ".png".
  FrameSequence(Renderer* renderer, std::string directory, std::string prefix = "frame_");
  /// Renders and writes the next frame; returns its path through `path` when given.
  Status write(const RenderFrame& frame, std::string* path = nullptr);
  int count() const { return count_; }

 private:
  Renderer* renderer_;
  std::string directory_, prefix_;
  int count_ = 0;
};

}  // namespace zona
