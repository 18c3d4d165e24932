// CUDA-Vulkan interop for the renderer: two kernels turn the CUDA backend's displacements into
// the renderer's cell-surface vertices (render-space positions carrying the colour scalar, and
// smooth normals) written straight into memory the renderer exported
// (render/renderer.h, Renderer::create_shared_surface): no device-to-host copy of the state, no
// CPU surface pass and no host-to-device upload per frame. The copy path (download, CPU
// surface, upload) stays the fallback wherever this is unavailable. Implemented in
// surface_interop.cu, or surface_interop_stub.cpp (an error value) without CUDA.
//
// Synchronisation is by completion, not by semaphores: write() returns after the kernels have
// finished, and the headless renderer's render() returns after the frame has been drawn, so the
// two never touch the memory at the same time as long as one thread alternates them (which is
// how `zona render --interop` and bench/interop_bench use them).
#pragma once

#include <array>
#include <cstdint>
#include <memory>
#include <span>
#include <vector>

#include "engine/sim/backend.h"
#include "engine/fem/model.h"

namespace zona {

/// The renderer's exported memory and the surface it draws from it.
struct SharedSurfaceTarget {
  int memory_fd = -1;  ///< opaque fd of the exported memory; make_surface_writer takes it over
  uint64_t memory_bytes = 0;      ///< size of the exported allocation [bytes]
  uint64_t positions_offset = 0;  ///< vec4 positions: xyz render space, w the scalar [bytes]
  uint64_t normals_offset = 0;    ///< vec4 unit normals, w 0 [bytes]
  std::array<uint8_t, 16> device_uuid{};  ///< the Vulkan device's UUID; must be the CUDA device's
  std::span<const int32_t> mesh_vertex;   ///< compact vertex -> model vertex, (surface vertices)
  std::span<const uint32_t> indices;      ///< compact triangles, outward CCW, (3 x triangles)
};

/// The scalar written into each position's w (the colour map's field).
enum class SurfaceScalar {
  kNone,          ///< 0
  kDisplacement,  ///< |u| [m]
};

/// What one write produced.
struct SurfaceWriteResult {
  double scalar_min = 0;  ///< min of the scalar over the surface [field SI unit]
  double scalar_max = 0;  ///< max of the scalar over the surface [field SI unit]
};

/// Writes a backend's deformed boundary surface into the renderer's shared memory.
class SurfaceWriter {
 public:
  virtual ~SurfaceWriter() = default;
  /// Positions (x - origin) * scale with x = rest + u (the renderer's render space for the
  /// frame's camera: render/renderer.h, camera_render_space), the scalar in w, then the
  /// area-weighted vertex normals of the deformed triangles, exactly as the CPU surface pass
  /// computes them; waits for the kernels. `backend` must be the one the writer was made for.
  /// Errors: a CUDA failure, a backend without device state.
  virtual Result<SurfaceWriteResult> write(const Backend& backend, Vec3d origin, double scale,
                                           SurfaceScalar scalar) = 0;
  /// Tests: copies the shared positions and normals back to the host, (surface vertices).
  virtual Status read_back(std::vector<std::array<float, 4>>* positions,
                           std::vector<std::array<float, 4>>* normals) = 0;
  /// Surface vertices written per call.
  virtual size_t vertex_count() const = 0;
};

/// Imports the target's memory into CUDA (on the backend's device, which must be the Vulkan
/// device: UUIDs compared) and uploads the surface's rest positions and vertex-to-triangle lists.
/// Takes over target.memory_fd in every case (closed on failure).
/// Errors (one line): built without CUDA, a backend without device state (the CPU), different
/// devices, an index out of range, the import failing.
Result<std::unique_ptr<SurfaceWriter>> make_surface_writer(const Backend& backend,
                                                           const Model& model,
                                                           const SharedSurfaceTarget& target);

}  // namespace zona
