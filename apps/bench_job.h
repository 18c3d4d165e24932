// `zona bench --job`: the injection job at a list of mesh sizes beside the bare step
// (apps/bench_job.cpp).
#pragma once

#include <cstdio>
#include <string>
#include <vector>

#include "engine/core/base.h"

namespace zona::cli {

/// Options of the job benchmark.
struct JobBenchArgs {
  std::string scene = "mouse_oocyte";  ///< scene file or name
  std::vector<std::string> sets;       ///< scene overrides (key=value)
  std::string backend = "cpu";         ///< cpu or cuda
  std::string vertices = "1e3,4e3,16e3";
  int threads = 0;                     ///< CPU threads (0: automatic)
  int steps = 0;                       ///< steps per timed block (0: automatic)
  int repeats = 5;                     ///< timed blocks per size
  double max_run_seconds = 120;        ///< run to puncture when the estimate is below this [s]
  std::string device_name;             ///< GPU name for the CSV
  std::string commit;                  ///< source revision for the CSV
  std::string command;                 ///< the reproducing command line
};

/// The CSV's header line (without a newline).
std::string job_bench_csv_header();

/// Runs the job benchmark, writing the CSV (comments, header, one row per size) to `csv` as
/// rows finish. Errors: bad options, a scene that does not build, a backend that is missing.
Status run_job_bench(const JobBenchArgs& args, FILE* csv);

}  // namespace zona::cli
