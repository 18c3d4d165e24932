// PNG line charts drawn into an RGB buffer: axes, ticks, grid, curves, markers, legend.
#include "engine/analysis/plot.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <limits>
#include <vector>

#if __has_include(<stb/stb_image_write.h>) && __has_include(<stb/stb_easy_font.h>)
#define ZONA_HAVE_STB_PNG 1
// stb is third-party C: keep its implementation private to this file (static functions, so no
// symbol clashes with the renderer's copy) and out of zona's warning flags.
#pragma GCC diagnostic push
#pragma GCC diagnostic ignored "-Wconversion"
#pragma GCC diagnostic ignored "-Wsign-conversion"
#pragma GCC diagnostic ignored "-Wmissing-field-initializers"
#pragma GCC diagnostic ignored "-Wunused-function"
#pragma GCC diagnostic ignored "-Wshadow"
#pragma GCC diagnostic ignored "-Wdouble-promotion"
#pragma GCC diagnostic ignored "-Wpedantic"
#define STB_IMAGE_WRITE_STATIC
#define STB_IMAGE_WRITE_IMPLEMENTATION
#include <stb/stb_image_write.h>
#include <stb/stb_easy_font.h>
#pragma GCC diagnostic pop
#else
#define ZONA_HAVE_STB_PNG 0
#endif

namespace zona {

bool plot_png_available() { return ZONA_HAVE_STB_PNG != 0; }

#if ZONA_HAVE_STB_PNG
namespace {

struct Canvas {
  int w, h;
  std::vector<uint8_t> rgb;
  int clip_x0 = 0, clip_y0 = 0, clip_x1 = 0, clip_y1 = 0;  // [x0, x1) x [y0, y1)

  Canvas(int width, int height) : w(width), h(height), rgb(static_cast<size_t>(width * height * 3), 255) {
    clip_x1 = w;
    clip_y1 = h;
  }
  void pixel(int x, int y, uint32_t c) {
    if (x < clip_x0 || y < clip_y0 || x >= clip_x1 || y >= clip_y1) return;
    uint8_t* p = &rgb[static_cast<size_t>((y * w + x) * 3)];
    p[0] = static_cast<uint8_t>(c >> 16);
    p[1] = static_cast<uint8_t>(c >> 8);
    p[2] = static_cast<uint8_t>(c);
  }
  void rect(double x0, double y0, double x1, double y1, uint32_t c) {
    const int ix0 = static_cast<int>(std::floor(std::min(x0, x1)));
    const int ix1 = static_cast<int>(std::ceil(std::max(x0, x1)));
    const int iy0 = static_cast<int>(std::floor(std::min(y0, y1)));
    const int iy1 = static_cast<int>(std::ceil(std::max(y0, y1)));
    for (int y = iy0; y < iy1; ++y)
      for (int x = ix0; x < ix1; ++x) pixel(x, y, c);
  }
  void disc(double cx, double cy, double r, uint32_t c) {
    const int x0 = static_cast<int>(std::floor(cx - r)), x1 = static_cast<int>(std::ceil(cx + r));
    const int y0 = static_cast<int>(std::floor(cy - r)), y1 = static_cast<int>(std::ceil(cy + r));
    for (int y = y0; y <= y1; ++y)
      for (int x = x0; x <= x1; ++x) {
        const double dx = x + 0.5 - cx, dy = y + 0.5 - cy;
        if (dx * dx + dy * dy <= r * r) pixel(x, y, c);
      }
  }
  void line(double x0, double y0, double x1, double y1, double width, uint32_t c) {
    const double length = std::hypot(x1 - x0, y1 - y0);
    const int n = std::max(1, static_cast<int>(std::ceil(length * 2)));
    const double r = std::max(0.5, 0.5 * width);
    for (int i = 0; i <= n; ++i) {
      const double a = static_cast<double>(i) / n;
      disc(x0 + a * (x1 - x0), y0 + a * (y1 - y0), r, c);
    }
  }
  // Text from stb_easy_font's quads, scaled; vertical text reads bottom to top.
  void text(double x, double y, const std::string& s, double scale, uint32_t c, bool vertical = false) {
    static thread_local std::vector<char> buffer(1 << 16);
    std::string copy = s;
    const int quads = stb_easy_font_print(0, 0, copy.data(), nullptr, buffer.data(),
                                          static_cast<int>(buffer.size()));
    for (int q = 0; q < quads; ++q) {
      float qx0 = 1e9f, qy0 = 1e9f, qx1 = -1e9f, qy1 = -1e9f;
      for (int k = 0; k < 4; ++k) {
        float vx, vy;
        std::memcpy(&vx, buffer.data() + (q * 4 + k) * 16, 4);
        std::memcpy(&vy, buffer.data() + (q * 4 + k) * 16 + 4, 4);
        qx0 = std::min(qx0, vx), qx1 = std::max(qx1, vx);
        qy0 = std::min(qy0, vy), qy1 = std::max(qy1, vy);
      }
      if (!vertical)
        rect(x + scale * qx0, y + scale * qy0, x + scale * qx1, y + scale * qy1, c);
      else
        rect(x + scale * qy0, y - scale * qx1, x + scale * qy1, y - scale * qx0, c);
    }
  }
  static double text_width(const std::string& s, double scale) {
    std::string copy = s;
    return scale * stb_easy_font_width(copy.data());
  }
};

// Tick step: 1, 2 or 5 times a power of ten giving about `target` intervals.
double nice_step(double range, int target) {
  const double raw = range / target;
  const double p = std::pow(10.0, std::floor(std::log10(raw)));
  const double f = raw / p;
  return (f < 1.5 ? 1 : f < 3.5 ? 2 : f < 7.5 ? 5 : 10) * p;
}

std::string tick_label(double v, double step) {
  char buf[32];
  const int decimals = std::max(0, -static_cast<int>(std::floor(std::log10(step) + 1e-9)));
  std::snprintf(buf, sizeof buf, "%.*f", decimals, std::fabs(v) < 1e-12 * step ? 0.0 : v);
  return buf;
}

}  // namespace

Status write_plot_png(const std::string& path, const PlotSpec& spec) {
  double xmin = std::numeric_limits<double>::infinity(), xmax = -xmin, ymin = xmin, ymax = -xmin;
  size_t points = 0;
  for (const PlotSeries& s : spec.series)
    for (size_t i = 0; i < std::min(s.x.size(), s.y.size()); ++i) {
      if (!std::isfinite(s.x[i]) || !std::isfinite(s.y[i])) continue;
      xmin = std::min(xmin, s.x[i]), xmax = std::max(xmax, s.x[i]);
      ymin = std::min(ymin, s.y[i]), ymax = std::max(ymax, s.y[i]);
      ++points;
    }
  if (points == 0) return make_error("%s: nothing to plot", path.c_str());
  xmin = spec.x_min.value_or(xmin), xmax = spec.x_max.value_or(xmax);
  ymin = spec.y_min.value_or(ymin), ymax = spec.y_max.value_or(ymax);
  if (!(xmax > xmin)) xmax = xmin + 1;
  if (!(ymax > ymin)) ymax = ymin + 1;
  const double xstep = nice_step(xmax - xmin, 8), ystep = nice_step(ymax - ymin, 6);
  // Expand automatic ranges to whole ticks.
  if (!spec.x_min) xmin = std::floor(xmin / xstep) * xstep;
  if (!spec.x_max) xmax = std::ceil(xmax / xstep) * xstep;
  if (!spec.y_min) ymin = std::floor(ymin / ystep) * ystep;
  if (!spec.y_max) ymax = std::ceil(ymax / ystep) * ystep;

  Canvas cv(spec.width, spec.height);
  const double left = 90, right = spec.width - 30.0, top = 50, bottom = spec.height - 70.0;
  auto px = [&](double x) { return left + (x - xmin) / (xmax - xmin) * (right - left); };
  auto py = [&](double y) { return bottom - (y - ymin) / (ymax - ymin) * (bottom - top); };
  const uint32_t kGrid = 0xe4e4e4, kAxis = 0x202020;

  // Grid, ticks and labels.
  for (double x = std::ceil(xmin / xstep - 1e-9) * xstep; x <= xmax + 1e-9 * xstep; x += xstep) {
    cv.line(px(x), top, px(x), bottom, 1, kGrid);
    cv.line(px(x), bottom, px(x), bottom + 6, 1, kAxis);
    const std::string label = tick_label(x, xstep);
    cv.text(px(x) - Canvas::text_width(label, 2) / 2, bottom + 12, label, 2, kAxis);
  }
  for (double y = std::ceil(ymin / ystep - 1e-9) * ystep; y <= ymax + 1e-9 * ystep; y += ystep) {
    cv.line(left, py(y), right, py(y), 1, kGrid);
    cv.line(left - 6, py(y), left, py(y), 1, kAxis);
    const std::string label = tick_label(y, ystep);
    cv.text(left - 12 - Canvas::text_width(label, 2), py(y) - 7, label, 2, kAxis);
  }
  cv.line(left, bottom, right, bottom, 1.5, kAxis);
  cv.line(left, top, left, bottom, 1.5, kAxis);
  cv.line(right, top, right, bottom, 1, kAxis);
  cv.line(left, top, right, top, 1, kAxis);
  cv.text(0.5 * (left + right) - Canvas::text_width(spec.x_label, 2) / 2, spec.height - 30.0,
          spec.x_label, 2, kAxis);
  cv.text(18, 0.5 * (top + bottom) + Canvas::text_width(spec.y_label, 2) / 2, spec.y_label, 2, kAxis,
          true);
  cv.text(0.5 * (left + right) - Canvas::text_width(spec.title, 2.5) / 2, 14, spec.title, 2.5, kAxis);

  // Series, clipped to the plot area.
  cv.clip_x0 = static_cast<int>(left), cv.clip_x1 = static_cast<int>(right) + 1;
  cv.clip_y0 = static_cast<int>(top), cv.clip_y1 = static_cast<int>(bottom) + 1;
  for (const PlotSeries& s : spec.series) {
    const size_t n = std::min(s.x.size(), s.y.size());
    if (s.line_width > 0)
      for (size_t i = 1; i < n; ++i)
        if (std::isfinite(s.x[i - 1] + s.y[i - 1] + s.x[i] + s.y[i]))
          cv.line(px(s.x[i - 1]), py(s.y[i - 1]), px(s.x[i]), py(s.y[i]), s.line_width, s.rgb);
    if (s.marker_radius > 0)
      for (size_t i = 0; i < n; ++i)
        if (std::isfinite(s.x[i] + s.y[i])) cv.disc(px(s.x[i]), py(s.y[i]), s.marker_radius, s.rgb);
  }

  // Legend, top left inside the plot.
  double ly = top + 14;
  for (const PlotSeries& s : spec.series) {
    if (s.label.empty()) continue;
    const double lx = left + 14;
    if (s.line_width > 0) cv.line(lx, ly + 6, lx + 30, ly + 6, s.line_width, s.rgb);
    if (s.marker_radius > 0) cv.disc(lx + 15, ly + 6, s.marker_radius, s.rgb);
    cv.text(lx + 40, ly, s.label, 2, kAxis);
    ly += 22;
  }

  if (!stbi_write_png(path.c_str(), spec.width, spec.height, 3, cv.rgb.data(), spec.width * 3))
    return make_error("%s: cannot write the PNG file", path.c_str());
  return Status::ok_status();
}

#else

Status write_plot_png(const std::string& path, const PlotSpec&) {
  return make_error("%s: this build has no PNG writer (stb_image_write not found)", path.c_str());
}

#endif

}  // namespace zona
