// Text panel and colour legend as Dear ImGui draw lists (overlay.h).
#include "render/overlay.h"

#include <imgui.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>

#include "shaders/shared.h"

namespace zona::render {
namespace {

constexpr const char* kSystemFont = "/usr/share/fonts/truetype/dejavu/DejaVuSans.ttf";

ImU32 to_imgui(gpu::vec3 c, float alpha = 1.0f) {
  return ImGui::ColorConvertFloat4ToU32(ImVec4(c.x, c.y, c.z, alpha));
}

}  // namespace

// Micrometres and kilopascals read naturally at cell scale.
double field_unit(ColorField field) {
  return field == ColorField::kStress ? 1e3 : 1e-6;
}

std::string field_title(ColorField field) {
  switch (field) {
    case ColorField::kDisplacement:
      return "displacement |u| [um]";
    case ColorField::kStress:
      return "von Mises stress [kPa]";
    default:
      return "";
  }
}

std::string format_field_value(ColorField field, double value) {
  char text[32];
  std::snprintf(text, sizeof(text), "%.3g", value / field_unit(field));
  return text;
}

Status create_overlay(const std::string& font_path, float pixel_height, OverlayState* overlay) {
  IMGUI_CHECKVERSION();
  overlay->imgui = ImGui::CreateContext();
  ImGui::SetCurrentContext(overlay->imgui);
  ImGuiIO& io = ImGui::GetIO();
  io.IniFilename = nullptr;  // no imgui.ini next to the images
  io.LogFilename = nullptr;
  std::string path = font_path;
  if (path.empty() && std::filesystem::exists(kSystemFont)) path = kSystemFont;
  ImFont* font = nullptr;
  if (!path.empty()) {
    if (!std::filesystem::exists(path))
      return make_error("overlay font %s: no such file", path.c_str());
    font = io.Fonts->AddFontFromFileTTF(path.c_str(), pixel_height);
    if (!font) return make_error("overlay font %s: not a TrueType font", path.c_str());
  } else {
    // The built-in bitmap font is crisp at whole multiples of 13 px.
    ImFontConfig config;
    config.SizePixels = 13.0f * std::max(1.0f, std::round(pixel_height / 13.0f));
    font = io.Fonts->AddFontDefault(&config);
  }
  unsigned char* pixels = nullptr;
  int w = 0, h = 0;
  io.Fonts->GetTexDataAsRGBA32(&pixels, &w, &h);
  if (!pixels || w <= 0 || h <= 0) return make_error("overlay: the font atlas is empty");
  overlay->font_pixels.assign(pixels, pixels + static_cast<size_t>(w) * h * 4);
  overlay->font_width = w;
  overlay->font_height = h;
  overlay->font_size = font->FontSize;
  io.Fonts->SetTexID(reinterpret_cast<ImTextureID>(static_cast<intptr_t>(1)));
  io.Fonts->ClearTexData();
  return {};
}

void destroy_overlay(OverlayState* overlay) {
  if (overlay->imgui) ImGui::DestroyContext(overlay->imgui);
  overlay->imgui = nullptr;
}

ImDrawData* build_overlay(OverlayState* overlay, const RenderFrame& frame, double lo, double hi,
                          int width, int height) {
  ImGui::SetCurrentContext(overlay->imgui);
  ImGuiIO& io = ImGui::GetIO();
  io.DisplaySize = ImVec2(static_cast<float>(width), static_cast<float>(height));
  io.DeltaTime = 1.0f / 60.0f;
  ImGui::NewFrame();
  ImDrawList* draw = ImGui::GetForegroundDrawList();
  const float em = overlay->font_size;
  const float pad = 0.6f * em;
  const ImU32 text = IM_COL32(235, 238, 242, 255);
  const ImU32 panel = IM_COL32(10, 12, 16, 150);

  // Text panel, top left.
  if (!frame.overlay_lines.empty()) {
    float w = 0;
    for (const std::string& line : frame.overlay_lines)
      w = std::max(w, ImGui::CalcTextSize(line.c_str()).x);
    const float line_h = ImGui::GetTextLineHeightWithSpacing();
    const ImVec2 a(pad, pad);
    const ImVec2 b(a.x + w + 2 * pad,
                   a.y + line_h * static_cast<float>(frame.overlay_lines.size()) + pad);
    draw->AddRectFilled(a, b, panel, 0.4f * em);
    float y = a.y + 0.5f * pad;
    for (const std::string& line : frame.overlay_lines) {
      draw->AddText(ImVec2(a.x + pad, y), text, line.c_str());
      y += line_h;
    }
  }

  // Colour legend, right side: a bar of the shader's colour map (the same function, from
  // shaders/shared.h), title above, five labels on its left.
  if (frame.field != ColorField::kNone && !frame.scalar.empty()) {
    const float bar_w = 1.1f * em, bar_h = 0.45f * static_cast<float>(height);
    const float x1 = static_cast<float>(width) - 1.6f * em, x0 = x1 - bar_w;
    const float y0 = 0.5f * (static_cast<float>(height) - bar_h), y1 = y0 + bar_h;
    const std::string title = field_title(frame.field);
    const ImVec2 title_size = ImGui::CalcTextSize(title.c_str());
    float label_w = 0;
    std::string labels[5];
    for (int i = 0; i < 5; ++i) {
      labels[i] = format_field_value(frame.field, lo + (hi - lo) * i / 4.0);
      label_w = std::max(label_w, ImGui::CalcTextSize(labels[i].c_str()).x);
    }
    const float left = std::min(x0 - label_w - 1.2f * pad, x1 - title_size.x) - pad;
    draw->AddRectFilled(ImVec2(left, y0 - title_size.y - 2.5f * pad),
                        ImVec2(static_cast<float>(width) - 0.5f * em, y1 + 1.5f * pad), panel,
                        0.4f * em);
    draw->AddText(ImVec2(x1 - title_size.x, y0 - title_size.y - 1.2f * pad), text, title.c_str());
    constexpr int kSteps = 64;
    for (int i = 0; i < kSteps; ++i) {
      // Top of the bar is the maximum.
      const float t0 = 1.0f - static_cast<float>(i) / kSteps,
                  t1 = 1.0f - static_cast<float>(i + 1) / kSteps;
      const ImU32 c0 = to_imgui(gpu::color_map(t0)), c1 = to_imgui(gpu::color_map(t1));
      const float ya = y0 + bar_h * static_cast<float>(i) / kSteps;
      const float yb = y0 + bar_h * static_cast<float>(i + 1) / kSteps;
      draw->AddRectFilledMultiColor(ImVec2(x0, ya), ImVec2(x1, yb), c0, c0, c1, c1);
    }
    draw->AddRect(ImVec2(x0, y0), ImVec2(x1, y1), IM_COL32(200, 200, 200, 200));
    for (int i = 0; i < 5; ++i) {
      const float y = y1 - bar_h * static_cast<float>(i) / 4.0f;
      const ImVec2 size = ImGui::CalcTextSize(labels[i].c_str());
      draw->AddLine(ImVec2(x0 - 0.4f * pad, y), ImVec2(x0, y), text);
      draw->AddText(ImVec2(x0 - 0.8f * pad - size.x, y - 0.5f * size.y), text, labels[i].c_str());
    }
  }
  ImGui::Render();
  return ImGui::GetDrawData();
}

}  // namespace zona::render
