// `zona plot`: force-deformation figures (PNG and SVG) of finished runs, measured data and
// convergence studies, drawn by python/zona_plot.py (docs/plots.md).
#include <cstdio>
#include <filesystem>
#include <memory>
#include <string>
#include <vector>

#include "apps/commands.h"
#include "apps/plot_script.h"

namespace zona::cli {
namespace {

struct PlotArgs {
  std::vector<std::string> runs;        // run folders or force.csv files, [:label]
  std::vector<std::string> data;        // measured CSVs, [:label]
  std::vector<std::string> references;  // DEFORMATION_UM,FORCE_UN[:label]
  std::string study;                    // a convergence study's folder
  std::string title;
  std::string out = "zona_plot";
};

Status plot_command(const PlotArgs& a) {
  // One figure of one kind: runs with their data, or one study's curves.
  if (!a.study.empty() && (!a.runs.empty() || !a.data.empty() || !a.references.empty()))
    return make_error("--study draws a study's curves alone: give it without runs, --data or "
                      "--reference");
  if (a.study.empty() && a.runs.empty() && a.data.empty())
    return make_error("nothing to plot: give runs (folders or force.csv files), --data or --study");
  std::vector<std::string> words;
  if (!a.study.empty()) {
    words = {"convergence", "--study", a.study};
  } else {
    words = {"force"};
    for (const std::string& r : a.runs) words.insert(words.end(), {"--run", r});
    for (const std::string& d : a.data) words.insert(words.end(), {"--data", d});
    for (const std::string& r : a.references) words.insert(words.end(), {"--reference", r});
  }
  // --out as STEM, STEM.png or STEM.svg: both files are written either way.
  std::filesystem::path stem = a.out;
  if (stem.extension() == ".png" || stem.extension() == ".svg") stem.replace_extension();
  words.insert(words.end(), {"--title", a.title, "--out", stem.string()});
  if (Status s = run_plot_script(words); !s) return s;
  const std::vector<std::string> files = plot_files(stem.string());
  std::printf("wrote %s, %s\n", files[0].c_str(), files[1].c_str());
  return Status::ok_status();
}

}  // namespace

void add_plot_command(CLI::App& app) {
  auto args = std::make_shared<PlotArgs>();
  auto* cmd = app.add_subcommand(
      "plot",
      "Force-deformation figure (PNG and SVG) of runs, measured data or a convergence study");
  cmd->add_option("runs", args->runs,
                  "Runs of zona run: output folders or force.csv files, each as PATH[:label]");
  cmd->add_option("--data", args->data,
                  "Measured points: CSV with deformation_m (or _um), force_N (or _uN) and an "
                  "optional force_std_* / force_sem_* column for error bars; FILE[:label] "
                  "(repeatable)");
  cmd->add_option("--reference", args->references,
                  "Mark a point: DEFORMATION_UM,FORCE_UN[:label] (repeatable)");
  cmd->add_option("--study", args->study,
                  "The output folder of zona study convergence: its curves, one per mesh size");
  cmd->add_option("--title", args->title, "Title above the figure");
  cmd->add_option("--out", args->out, "Output STEM: writes STEM.png and STEM.svg")
      ->capture_default_str();
  cmd->callback([args] {
    if (Status s = plot_command(*args); !s) fail(s.error().message);
  });
}

}  // namespace zona::cli
