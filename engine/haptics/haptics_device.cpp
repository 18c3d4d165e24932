// Scripted, emulated and replay haptic devices, device profiles, trajectory CSV reading.
#include "engine/haptics/haptics_device.h"

#include <algorithm>
#include <cmath>
#include <fstream>
#include <sstream>

namespace zona {

Result<DeviceInfo> device_profile(const std::string& name) {
  DeviceInfo d;
  d.name = name;
  if (name == "touch") {
    d.max_force = 3.3; d.max_stiffness = 400; d.max_damping = 3.0;
    d.impedance = {0.045, 0.4};
  } else if (name == "falcon") {
    d.max_force = 8.0; d.max_stiffness = 3000; d.max_damping = 10.0;
    d.impedance = {0.15, 4.0};
  } else if (name == "omega") {
    d.max_force = 12.0; d.max_stiffness = 14500; d.max_damping = 20.0;
    d.impedance = {0.2, 10.0};
  } else {
    return make_error("device profile '%s': expected touch, falcon or omega", name.c_str());
  }
  return d;
}

Status read_trajectory_csv(const std::string& path, std::vector<double>& times,
                           std::vector<Vec3d>& positions) {
  // Before opening: a FIFO blocks the open, a device (/dev/zero) never ends.
  if (Status st = check_regular_file(path); !st) return st;
  std::ifstream in(path);
  if (!in) return make_error("%s: cannot open", path.c_str());
  times.clear();
  positions.clear();
  std::string line;
  if (!std::getline(in, line)) return make_error("%s: empty file", path.c_str());
  int line_no = 1;
  while (std::getline(in, line)) {
    ++line_no;
    if (line.empty() || line[0] == '#') continue;
    std::replace(line.begin(), line.end(), ',', ' ');
    std::istringstream row(line);
    double t, x, y, z;
    if (!(row >> t >> x >> y >> z) || !std::isfinite(t) || !std::isfinite(x) ||
        !std::isfinite(y) || !std::isfinite(z))
      return make_error("%s:%d: expected t_s,x_m,y_m,z_m numbers", path.c_str(), line_no);
    if (!times.empty() && t <= times.back())
      return make_error("%s:%d: time %g s does not increase", path.c_str(), line_no, t);
    times.push_back(t);
    positions.push_back({x, y, z});
  }
  if (times.empty()) return make_error("%s: no rows", path.c_str());
  return {};
}

namespace {

// Position and velocity on a piecewise-linear trajectory (held after the last point).
DeviceState sample_trajectory(const std::vector<double>& times,
                              const std::vector<Vec3d>& positions, double t) {
  DeviceState s;
  if (times.empty()) return s;
  if (t <= times.front()) { s.position = positions.front(); return s; }
  if (t >= times.back()) { s.position = positions.back(); return s; }
  const auto it = std::upper_bound(times.begin(), times.end(), t);
  const size_t i = static_cast<size_t>(it - times.begin());
  const double dt = times[i] - times[i - 1];
  const double w = (t - times[i - 1]) / dt;
  s.position = positions[i - 1] + w * (positions[i] - positions[i - 1]);
  s.velocity = (1.0 / dt) * (positions[i] - positions[i - 1]);
  return s;
}

class ScriptedDevice final : public HapticDevice {
 public:
  ScriptedDevice(const DeviceInfo& info, const ScriptedDeviceDef& def) : info_(info), def_(def) {}
  const DeviceInfo& info() const override { return info_; }
  Vec3d home() const override {
    return def_.times.empty() ? def_.home : def_.positions.front();
  }
  DeviceState update(double time) override {
    if (!def_.times.empty()) return sample_trajectory(def_.times, def_.positions, time);
    DeviceState s;
    double travel = def_.speed * time;
    const bool moving = def_.max_travel <= 0 || travel < def_.max_travel;
    if (!moving) travel = def_.max_travel;
    s.position = def_.home + travel * def_.direction;
    s.velocity = moving ? def_.speed * def_.direction : Vec3d{0, 0, 0};
    return s;
  }
  void command(Vec3d, double) override {}  // a script does not yield to force

 private:
  DeviceInfo info_;
  ScriptedDeviceDef def_;
};

class EmulatedDevice final : public HapticDevice {
 public:
  EmulatedDevice(const DeviceInfo& info, const EmulatedHandDef& def)
      : info_(info), def_(def), state_{def.home, {0, 0, 0}} {}
  const DeviceInfo& info() const override { return info_; }
  Vec3d home() const override { return def_.home; }
  DeviceState update(double time) override {
    if (time <= time_) return state_;
    const int n = std::max(1, def_.substeps);
    const double h = (time - time_) / n;
    const double m = def_.hand_mass + info_.impedance.mass;
    for (int i = 0; i < n; ++i) {
      const double t = time_ + (i + 1) * h;
      double travel = def_.speed * t;
      Vec3d target_v = def_.speed * def_.direction;
      if (def_.max_travel > 0 && travel >= def_.max_travel) {
        travel = def_.max_travel;
        target_v = {0, 0, 0};
      }
      const Vec3d target = def_.home + travel * def_.direction;
      // Hand tracking the path, device damping, the rendered force held since the command.
      const Vec3d f = def_.hand_stiffness * (target - state_.position) +
                      def_.hand_damping * (target_v - state_.velocity) -
                      info_.impedance.damping * state_.velocity + force_;
      // Semi-implicit Euler: stable for these stiffnesses at sub-millisecond steps.
      state_.velocity += (h / m) * f;
      state_.position += h * state_.velocity;
    }
    time_ = time;
    return state_;
  }
  void command(Vec3d force, double) override { force_ = force; }

 private:
  DeviceInfo info_;
  EmulatedHandDef def_;
  DeviceState state_;
  Vec3d force_{0, 0, 0};
  double time_ = 0;
};

class ReplayDevice final : public HapticDevice {
 public:
  ReplayDevice(const DeviceInfo& info, std::vector<double> times, std::vector<Vec3d> positions)
      : info_(info), times_(std::move(times)), positions_(std::move(positions)) {}
  const DeviceInfo& info() const override { return info_; }
  Vec3d home() const override { return positions_.front(); }
  DeviceState update(double time) override {
    // Session time starts at the recording's first row.
    return sample_trajectory(times_, positions_, times_.front() + time);
  }
  void command(Vec3d, double) override {}

 private:
  DeviceInfo info_;
  std::vector<double> times_;
  std::vector<Vec3d> positions_;
};

}  // namespace

std::unique_ptr<HapticDevice> make_scripted_device(const DeviceInfo& info,
                                                   const ScriptedDeviceDef& def) {
  return std::make_unique<ScriptedDevice>(info, def);
}

std::unique_ptr<HapticDevice> make_emulated_device(const DeviceInfo& info,
                                                   const EmulatedHandDef& def) {
  return std::make_unique<EmulatedDevice>(info, def);
}

Result<std::unique_ptr<HapticDevice>> make_replay_device(const DeviceInfo& info,
                                                         const std::string& path) {
  std::vector<double> times;
  std::vector<Vec3d> positions;
  if (Status s = read_trajectory_csv(path, times, positions); !s.ok())
    return s.error();
  return std::unique_ptr<HapticDevice>(
      std::make_unique<ReplayDevice>(info, std::move(times), std::move(positions)));
}

}  // namespace zona
