// The matplotlib plots (PNG and SVG) of `zona run`, `zona study convergence` and `zona plot`:
// python/zona_plot.py, run in a child process by the project's Python (docs/plots.md).
#pragma once

#include <string>
#include <vector>

#include "engine/core/base.h"

namespace zona::cli {

/// The interpreter and the script that draw the plots.
struct PlotScript {
  std::string python;  ///< $ZONA_PYTHON, else the source tree's .venv/bin/python, else python3
  std::string script;  ///< the installed zona_plot.py, else the source tree's python/zona_plot.py
};

/// Finds the script and names its interpreter (looked up on the PATH when it has no '/'). An
/// error when no zona_plot.py is there or $ZONA_PYTHON names no file.
zona::Result<PlotScript> find_plot_script();

/// Runs `PYTHON zona_plot.py ARGS` (ARGS as separate words, no shell; the script writes
/// STEM.png and STEM.svg for `--out STEM`). An error carries the script's one-line message
/// ("FILE: ..."), or says that the interpreter could not start or that matplotlib is missing.
zona::Status run_plot_script(const std::vector<std::string>& args);

/// The two files a plot with `--out STEM` writes: STEM.png and STEM.svg.
std::vector<std::string> plot_files(const std::string& stem);

}  // namespace zona::cli
