// CPU side of a frame: the render space (camera-relative, scaled by the camera distance so that
// float positions keep their precision at micrometre scale), the cell surface with smooth
// normals recomputed from the deformed positions, and the pipette meshes.
#pragma once

#include <cstdint>
#include <vector>

#include "engine/core/base.h"
#include "render/frame.h"
#include "shaders/shared.h"

namespace zona::render {

/// World [m] -> render space [-]: (x - camera target) / camera distance.
struct RenderSpace {
  Vec3d origin{0, 0, 0};  ///< [m]
  double scale = 1;       ///< [1/m]
  gpu::vec3 to_render(Vec3d x) const;
};

/// The render space and matrices of a camera for a viewport of aspect width / height.
struct CameraMatrices {
  RenderSpace space;
  gpu::mat4 view_proj;  ///< render space -> Vulkan clip space (y down, depth 0..1)
  gpu::vec3 eye;        ///< eye in render space
};
CameraMatrices camera_matrices(const OrbitCamera& camera, double aspect);

/// Triangles with their own vertex arrays, in render space.
struct MeshData {
  std::vector<gpu::vec4> positions;  ///< xyz render space, w scalar, (vertex_count)
  std::vector<gpu::vec4> normals;    ///< xyz unit normal, (vertex_count)
  std::vector<uint32_t> indices;     ///< three per triangle
  void clear() {
    positions.clear();
    normals.clear();
    indices.clear();
  }
};

/// The cell surface: mesh vertices used by the triangles, compacted, and cached between frames
/// (rebuilt only when the triangle array changes).
struct SurfaceGeometry {
  const Triangle* cached_triangles = nullptr;
  size_t cached_count = 0;
  size_t cached_vertex_count = 0;
  std::vector<int32_t> mesh_vertex;       ///< compact index -> mesh vertex, (surface vertex count)
  MeshData mesh;                          ///< compact vertices and triangles
  double scalar_min = 0, scalar_max = 0;  ///< range of the scalar over the surface
  double scalar_p98 = 0;                  ///< its 98th percentile over the surface vertices
  std::vector<float> scratch;             ///< for the percentile
};

/// Fills `surface` from the frame: deformed positions, area-weighted vertex normals from the
/// deformed triangles, scalar per vertex. Errors: a span of the wrong length, an index out of
/// range.
Status update_surface(const RenderFrame& frame, const RenderSpace& space, SurfaceGeometry* surface);

/// One point of a profile revolved about an axis: axial coordinate, radius and the 2D normal.
struct ProfilePoint {
  double axial = 0;                            ///< along the axis [m]
  double radius = 0;                           ///< from the axis [m]
  double normal_axial = 0, normal_radial = 1;  ///< unit normal in (axial, radial) [-]
};

/// Appends the surface of revolution of `profile` (one smooth band between consecutive points)
/// about the axis through `origin` [m] along unit `axis`, with `segments` around.
void append_revolution(const std::vector<ProfilePoint>& profile, Vec3d origin, Vec3d axis,
                       int segments, const RenderSpace& space, MeshData* mesh);

/// Appends the needle: hemisphere (or flat disc) at the tip, cylinder behind it.
void append_needle(const NeedlePose& needle, double default_length, const RenderSpace& space,
                   MeshData* mesh);

/// Appends the holding pipette: rim annulus at the mouth, outer and inner walls.
void append_holding(const HoldingPose& holding, double default_length, const RenderSpace& space,
                    MeshData* mesh);

}  // namespace zona::render
