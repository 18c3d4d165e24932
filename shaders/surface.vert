// Cell surface and pipettes: transforms render-space positions, passes normal and scalar on.
#version 450
#extension GL_GOOGLE_include_directive : require
#include "shared.h"

layout(location = kAttribPosition) in vec4 in_position;
layout(location = kAttribNormal) in vec4 in_normal;

layout(push_constant) uniform Push { DrawConstants draw; };

layout(location = 0) out vec3 out_position;
layout(location = 1) out vec3 out_normal;
layout(location = 2) out float out_scalar;

void main() {
  out_position = in_position.xyz;
  out_normal = in_normal.xyz;
  out_scalar = in_position.w;
  gl_Position = draw.view_proj * vec4(in_position.xyz, 1.0);
}
