// The 2D overlay drawn over the 3D view with Dear ImGui's draw lists: the text panel (needle
// force, rates, puncture state) and the colour legend with its labels. This module makes the
// vertices; the renderer draws them with its own pipeline (shaders/overlay.*).
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "engine/core/base.h"
#include "render/frame.h"

struct ImGuiContext;
struct ImDrawData;

namespace zona::render {

/// The ImGui context and its font atlas (RGBA8 pixels to upload once).
struct OverlayState {
  ImGuiContext* imgui = nullptr;
  std::vector<uint8_t> font_pixels;  ///< (font_height x font_width x 4)
  int font_width = 0, font_height = 0;
  float font_size = 13;  ///< [px]
};

/// Creates the ImGui context and bakes the font: `font_path` when it names a TTF file, else
/// DejaVu Sans when installed, else ImGui's built-in font; `pixel_height` of the text [px].
Status create_overlay(const std::string& font_path, float pixel_height, OverlayState* overlay);
void destroy_overlay(OverlayState* overlay);

/// Builds the overlay of `frame` for a `width` x `height` target, with the colour map's range
/// [lo, hi] in the field's SI unit. The returned draw data lives until the next call.
ImDrawData* build_overlay(OverlayState* overlay, const RenderFrame& frame, double lo, double hi,
                          int width, int height);

/// The legend's unit of a field in SI (1e-6 m for displacement, 1e3 Pa for stress).
double field_unit(ColorField field);
/// The legend's title of a field ("displacement |u| [um]", "von Mises stress [kPa]").
std::string field_title(ColorField field);
/// A value of the field in the legend's unit, 3 significant digits ("12.5").
std::string format_field_value(ColorField field, double value);

}  // namespace zona::render
