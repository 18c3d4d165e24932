// A small line-chart writer for run outputs: force-deformation curves as PNG, drawn in memory
// (axes, 1-2-5 ticks, grid, polylines, markers, legend; text from stb_easy_font) and encoded by
// stb_image_write, so `zona run` needs no Python or plotting library.
#pragma once

#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include "engine/core/base.h"

namespace zona {

/// One curve or point set.
struct PlotSeries {
  std::string label;         ///< legend text; empty: not in the legend
  std::vector<double> x, y;  ///< data in axis units, (point_count)
  uint32_t rgb = 0x1f77b4;   ///< colour 0xRRGGBB
  double line_width = 2.0;   ///< [px]; 0: no line
  double marker_radius = 0;  ///< [px]; > 0 draws a disc at each point
};

/// A chart: title, axis labels, series; axis ranges automatic unless given.
struct PlotSpec {
  std::string title;
  std::string x_label;
  std::string y_label;
  std::vector<PlotSeries> series;
  int width = 900;   ///< [px]
  int height = 600;  ///< [px]
  std::optional<double> x_min, x_max, y_min, y_max;
};

/// True when this build can write PNG files (stb_image_write was found at compile time).
bool plot_png_available();

/// Draws the chart and writes it as PNG. Errors: no PNG support in this build, no data, a
/// file that cannot be written.
Status write_plot_png(const std::string& path, const PlotSpec& spec);

}  // namespace zona
