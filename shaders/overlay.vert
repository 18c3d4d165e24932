// Overlay (Dear ImGui draw lists): pixel coordinates to clip space; colours to linear.
#version 450
#extension GL_GOOGLE_include_directive : require
#include "shared.h"

layout(location = 0) in vec2 in_position;
layout(location = 1) in vec2 in_uv;
layout(location = 2) in vec4 in_color;

layout(push_constant) uniform Push { OverlayConstants overlay; };

layout(location = 0) out vec4 out_color;
layout(location = 1) out vec2 out_uv;

void main() {
  // ImGui colours are sRGB; the target stores sRGB, so convert to linear first.
  out_color = vec4(pow(in_color.rgb, vec3(2.2)), in_color.a);
  out_uv = in_uv;
  gl_Position = vec4(in_position * overlay.scale + overlay.translate, 0.0, 1.0);
}
