// Needle geometry (signed distance of the tip and shaft) and its scripted motion.
#include "engine/tools/needle.h"

#include "engine/tools/tool_params.h"
#include "engine/tools/tool_sdf.h"

#include <algorithm>
#include <cmath>
#include <fstream>
#include <sstream>

namespace zona {

ToolDistance needle_distance(const NeedleGeometry& needle, Vec3d tip, Vec3d x) {
  // One distance function for every path: engine/tools/tool_sdf.h, host and device.
  const ToolSdf sdf = needle_sdf(tip, needle.direction, needle.tip_radius,
                                 needle.shape == NeedleShape::kFlat, x);
  return ToolDistance{sdf.distance, sdf.normal};
}

Result<NeedleTrajectory> read_needle_trajectory(const std::string& path) {
  // Before opening: a FIFO blocks the open, a device (/dev/zero) never ends.
  if (Status st = check_regular_file(path); !st) return st.error();
  std::ifstream in(path);
  if (!in) return make_error("%s: cannot open the needle trajectory", path.c_str());
  NeedleTrajectory t;
  std::string line;
  int line_number = 0;
  bool header = false;
  while (std::getline(in, line)) {
    ++line_number;
    if (!line.empty() && line.back() == '\r') line.pop_back();
    if (line.empty() || line[0] == '#') continue;
    if (!header) {
      std::string compact;
      for (char c : line)
        if (c != ' ' && c != '\t') compact += c;
      if (compact != "time_s,x_m,y_m,z_m")
        return make_error("%s:%d: expected the header 'time_s,x_m,y_m,z_m', got '%s'",
                          path.c_str(), line_number, line.c_str());
      header = true;
      continue;
    }
    double v[4];
    std::stringstream ss(line);
    std::string cell;
    int n = 0;
    while (std::getline(ss, cell, ',')) {
      if (n >= 4) return make_error("%s:%d: more than 4 columns", path.c_str(), line_number);
      char* end = nullptr;
      v[n] = std::strtod(cell.c_str(), &end);
      while (end && (*end == ' ' || *end == '\t')) ++end;
      if (end == cell.c_str() || (end && *end != '\0') || !std::isfinite(v[n]))
        return make_error("%s:%d: column %d: '%s' is not a finite number", path.c_str(),
                          line_number, n + 1, cell.c_str());
      ++n;
    }
    if (n != 4) return make_error("%s:%d: expected 4 columns, got %d", path.c_str(), line_number, n);
    if (t.time.empty() && v[0] != 0)
      return make_error("%s:%d: the first time must be 0 s, got %g", path.c_str(), line_number, v[0]);
    if (!t.time.empty() && !(v[0] > t.time.back()))
      return make_error("%s:%d: times must increase strictly (%g after %g)", path.c_str(),
                        line_number, v[0], t.time.back());
    t.time.push_back(v[0]);
    t.position.push_back(Vec3d{v[1], v[2], v[3]});
  }
  if (!header) return make_error("%s: empty needle trajectory", path.c_str());
  if (t.time.size() < 2)
    return make_error("%s: a needle trajectory needs at least 2 rows, got %zu", path.c_str(),
                      t.time.size());
  return t;
}

Vec3d needle_tip_at(const NeedleScript& script, double t) {
  NeedleParams p;
  p.start = script.start;
  p.direction = script.direction;
  p.speed = script.speed;
  p.max_travel = script.max_travel;
  p.path_count = static_cast<int32_t>(script.trajectory.time.size());
  p.path_time = script.trajectory.time.data();
  p.path_position = script.trajectory.position.data();
  return needle_scripted_tip(p, t);
}

double needle_script_end_time(const NeedleScript& script) {
  if (!script.trajectory.time.empty()) return script.trajectory.time.back();
  if (script.max_travel > 0 && script.speed > 0) return script.max_travel / script.speed;
  return 0;
}

}  // namespace zona
