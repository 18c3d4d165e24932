// Glue between the renderer's shared surface (render/renderer.h) and the CUDA surface writer
// (kernels/surface_interop.h): the one place that maps one struct onto the other.
#pragma once

#include "kernels/surface_interop.h"
#include "render/renderer.h"

namespace zona {

/// What make_surface_writer needs from a shared surface; the spans point into `shared`, which
/// must outlive the call. The fd passes on with it (make_surface_writer takes it over).
inline SharedSurfaceTarget shared_surface_target(const SharedSurface& shared) {
  SharedSurfaceTarget target;
  target.memory_fd = shared.fd;
  target.memory_bytes = shared.bytes;
  target.positions_offset = shared.positions_offset;
  target.normals_offset = shared.normals_offset;
  target.device_uuid = shared.device_uuid;
  target.mesh_vertex = shared.mesh_vertex;
  target.indices = shared.indices;
  return target;
}

}  // namespace zona
