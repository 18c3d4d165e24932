// Structs and functions shared by the GLSL shaders and the C++ renderer (render/), so that
// push-constant layouts, vertex attribute locations and the colour map cannot drift apart.
//
// In GLSL this file is #included (GL_GOOGLE_include_directive); in C++ the GLSL types map to
// glm. Only the common subset of both languages may be used below: vec/mat types, float math,
// clamp/mix, no references, no C++ initialisers.
#ifndef ZONA_SHADERS_SHARED_H
#define ZONA_SHADERS_SHARED_H

#ifdef __cplusplus
#include <cstdint>

#include <glm/glm.hpp>

namespace zona::gpu {
using vec2 = glm::vec2;
using vec3 = glm::vec3;
using vec4 = glm::vec4;
using mat4 = glm::mat4;
using uint = uint32_t;
using glm::clamp;
using glm::mix;
#define ZONA_CONST inline constexpr
#else
#define ZONA_CONST const
#endif

// Vertex attribute locations of the 3D pass: positions and normals live in two buffers so that
// the positions buffer alone can later be written by CUDA (external memory) and normals
// recomputed on the GPU.
ZONA_CONST uint kAttribPosition = 0u;  // vec4: xyz render-space position, w per-vertex scalar
ZONA_CONST uint kAttribNormal = 1u;    // vec4: xyz unit normal (w unused)

// DrawConstants::mode values.
ZONA_CONST uint kShadeColorMap = 0u;  // colour from the per-vertex scalar through the colour map
ZONA_CONST uint kShadeFlat = 1u;      // DrawConstants::color, opaque
ZONA_CONST uint kShadeGlass = 2u;     // DrawConstants::color, transparent with a rim highlight

// Push constants of the 3D pass (<= 128 bytes, the guaranteed minimum).
struct DrawConstants {
  mat4 view_proj;  // render space -> clip space
  vec4 color;      // sRGB base colour (rgb) and opacity (a) for flat / glass shading
  vec4 eye;        // xyz: camera position in render space; w: mode (as float)
  vec4 range;      // x: scalar at the colour map's bottom, y: 1 / (max - min), z: 1 when a
                   // colour map is shown, w: ambient strength
};

// Push constants of the overlay pass (Dear ImGui draw data, pixel coordinates).
struct OverlayConstants {
  vec2 scale;      // 2 / framebuffer size
  vec2 translate;  // -1 - display offset * scale
};

// The colour map: a five-stop ramp, blue (low) -> cyan -> green -> yellow -> red (high),
// in sRGB. A familiar FEM ramp: high values read as warm. t is clamped to [0, 1].
#ifdef __cplusplus
inline
#endif
vec3 color_map(float t) {
  float s = clamp(t, 0.0f, 1.0f) * 4.0f;
  vec3 c0 = vec3(0.19f, 0.25f, 0.80f);
  vec3 c1 = vec3(0.15f, 0.70f, 0.92f);
  vec3 c2 = vec3(0.30f, 0.80f, 0.35f);
  vec3 c3 = vec3(0.98f, 0.85f, 0.20f);
  vec3 c4 = vec3(0.85f, 0.12f, 0.10f);
  if (s < 1.0f) return mix(c0, c1, s);
  if (s < 2.0f) return mix(c1, c2, s - 1.0f);
  if (s < 3.0f) return mix(c2, c3, s - 2.0f);
  return mix(c3, c4, s - 3.0f);
}

#ifdef __cplusplus
#undef ZONA_CONST
}  // namespace zona::gpu
#endif

#endif  // ZONA_SHADERS_SHARED_H
