// Smooth shading of the cell (colour-mapped or flat) and of the glass pipettes: two
// directional lights fixed to the camera, hemisphere ambient, Blinn-Phong highlight.
// Colours are given in sRGB and shaded in linear space; the target is an sRGB format.
#version 450
#extension GL_GOOGLE_include_directive : require
#include "shared.h"

layout(push_constant) uniform Push { DrawConstants draw; };

layout(location = 0) in vec3 in_position;
layout(location = 1) in vec3 in_normal;
layout(location = 2) in float in_scalar;

layout(location = 0) out vec4 out_color;

vec3 to_linear(vec3 c) { return pow(c, vec3(2.2)); }

void main() {
  uint mode = uint(draw.eye.w + 0.5);
  vec3 v = normalize(draw.eye.xyz - in_position);
  vec3 n = normalize(in_normal);
  // Two-sided: a surface seen from behind (inside of a tube, a folded triangle) is lit too.
  if (dot(n, v) < 0.0) n = -n;

  vec3 base = draw.color.rgb;
  if (mode == kShadeColorMap && draw.range.z > 0.5)
    base = color_map((in_scalar - draw.range.x) * draw.range.y);
  base = to_linear(base);

  // Key light from the upper left of the camera, fill light from the lower right: both in
  // render space derived from the view direction so that the cell is lit from the front.
  vec3 up = vec3(0.0, 1.0, 0.0);
  vec3 right = normalize(cross(v, up) + vec3(1e-6));
  vec3 key = normalize(v + 0.6 * up - 0.5 * right);
  vec3 fill = normalize(v - 0.3 * up + 0.7 * right);
  float ambient = draw.range.w;
  float hemi = 0.5 + 0.5 * n.y;
  float diffuse = 0.75 * max(dot(n, key), 0.0) + 0.25 * max(dot(n, fill), 0.0);
  vec3 h = normalize(key + v);
  float spec = pow(max(dot(n, h), 0.0), 48.0);

  if (mode == kShadeGlass) {
    // Glass: faint body, bright rim where the surface turns away from the eye.
    float rim = pow(1.0 - abs(dot(n, v)), 2.0);
    vec3 c = base * (0.35 + 0.5 * diffuse) + vec3(0.6) * spec;
    out_color = vec4(c, clamp(draw.color.a + 0.6 * rim, 0.0, 1.0));
    return;
  }
  vec3 c = base * (ambient * mix(0.6, 1.0, hemi) + (1.0 - ambient) * diffuse) + vec3(0.25) * spec;
  out_color = vec4(c, 1.0);
}
