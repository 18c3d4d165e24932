// `zona haptics SCENE --device scripted|emulated|replay|network --duration SECONDS`: runs the
// scene's simulation with the 1 kHz haptic thread and a virtual coupling between them; logs one
// row per haptic tick and prints the loop's measurements.
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <memory>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "apps/commands.h"
#include "engine/haptics_loop.h"
#include "engine/scene.h"
#include "engine/simulation.h"

namespace zona::cli {
namespace {

struct HapticsArgs {
  std::string scene = "mouse_oocyte";
  std::string device = "emulated";
  std::string profile;  // empty: from the scene's max_force
  double duration = 2.0;
  std::string log;
  bool json = false;
  std::string replay;
  std::string plugin;
  std::string plugin_config;
  std::vector<std::string> sets;
  int threads = 1;
  double hand_speed = 0;  // [m/s]; 0: the scene's needle speed mapped to the hand
  bool no_realtime = false;
};

// The Simulation behind the session's port: the commanded tip goes in between step1 and step2
// (rate-limited, see below), the needle report comes out as the haptic sample.
class SimulationPortAdapter final : public HapticSimulationPort {
 public:
  SimulationPortAdapter(Simulation& sim, double max_tip_speed)
      : sim_(sim), max_tip_speed_(max_tip_speed), tip_(sim.needle_script().start) {}

  bool step(const ToolCommand* command, HapticSample& sample) override {
    if (sim_.finished()) return false;
    sim_.step1();
    if (command) {
      // The explicit solver advances dt of simulated time per step, far less than the wall
      // time between haptic ticks; the tip follows the command at most at max_tip_speed (the
      // coupling spring renders the lag rather than the solver taking a jump it cannot
      // resolve).
      const Vec3d delta = command->tool - tip_;
      const double len = norm(delta);
      const double max_step = max_tip_speed_ * sim_.model().dt;
      tip_ = len > max_step ? tip_ + (max_step / len) * delta : command->tool;
      sim_.set_needle_tip(tip_);
    }
    const StepStatus status = sim_.step2();
    if (status & kStepNotAdvanced) return false;
    const NeedleReport& r = sim_.report();
    sample.sim_time = r.time;
    sample.force = -r.force_vector;  // the cell's force on the needle
    sample.stiffness = r.stiffness;
    sample.axis = sim_.needle_script().direction;
    sample.tool = r.tip;
    sample.punctured = r.punctured;
    if (r.punctured && puncture_wall_ns_ < 0) puncture_wall_ns_ = haptic_clock_ns();
    ++steps_;
    return true;
  }

  int64_t steps() const { return steps_; }
  int64_t puncture_wall_ns() const { return puncture_wall_ns_; }

 private:
  Simulation& sim_;
  double max_tip_speed_;
  Vec3d tip_;
  int64_t steps_ = 0;
  int64_t puncture_wall_ns_ = -1;
};

Result<std::unique_ptr<HapticDevice>> make_device(const HapticsArgs& a, const Scene& scene,
                                                  const DeviceInfo& info, const Vec3d& axis,
                                                  double hand_speed) {
  if (!a.plugin.empty()) return make_plugin_device(a.plugin, a.plugin_config);
  // Hand-side path: the needle axis, a travel of 6 cm at most (a stylus workspace).
  const double travel = scene.needle.max_travel > 0
                            ? std::min(0.06, scene.needle.max_travel / scene.haptics.workspace_scale)
                            : 0.06;
  if (a.device == "scripted") {
    ScriptedDeviceDef d;
    d.direction = axis;
    d.speed = hand_speed;
    d.max_travel = travel;
    return make_scripted_device(info, d);
  }
  if (a.device == "emulated") {
    EmulatedHandDef d;
    d.direction = axis;
    d.speed = hand_speed;
    d.max_travel = travel;
    return make_emulated_device(info, d);
  }
  if (a.device == "replay") {
    const std::string path = a.replay.empty() ? scene.haptics.replay_file : a.replay;
    if (path.empty()) return make_error("--device replay needs --replay FILE or haptics.replay_file");
    return make_replay_device(info, path);
  }
  if (a.device == "network")
    return make_network_device(info, scene.haptics.network_host, scene.haptics.network_port);
  return make_error("--device %s: expected scripted, emulated, replay or network",
                    a.device.c_str());
}

void run_haptics(const HapticsArgs& a) {
  if (!(a.duration > 0) || a.duration > 3600) return fail("--duration: expected 0 < SECONDS <= 3600");
  auto path = find_scene(a.scene);
  if (!path) return fail(path.error().message);
  auto loaded = load_scene(*path, a.sets);
  if (!loaded) return fail(loaded.error().message);
  Scene& scene = *loaded;
  if (!scene.needle.enabled) return fail(scene.name + ": the scene has no needle to couple");
  const HapticsDef& h = scene.haptics;
  if (!(h.rate > 0) || !(h.workspace_scale > 0) || !(h.force_scale > 0))
    return fail(scene.name + ": haptics.rate, workspace_scale, force_scale must be > 0");

  // Device limits: the named profile, else the smallest profile covering the scene's force.
  std::string profile = a.profile;
  if (profile.empty()) profile = h.max_force <= 3.3 ? "touch" : h.max_force <= 8 ? "falcon" : "omega";
  auto info = device_profile(profile);
  if (!info) return fail(info.error().message);
  const double period = 1.0 / h.rate;
  const double max_stiffness = std::min(h.max_stiffness, info->max_stiffness);
  auto gains = choose_coupling_gains(h.coupling_stiffness ? &*h.coupling_stiffness : nullptr,
                                     h.coupling_damping ? &*h.coupling_damping : nullptr,
                                     info->impedance, period, max_stiffness);
  if (!gains) return fail(scene.source + ": " + gains.error().message);

  SimulationOptions so;
  so.threads = a.threads;
  auto sim = Simulation::create(scene, so);
  if (!sim) return fail(sim.error().message);
  const NeedleScript& script = (*sim)->needle_script();
  // The scene's insertion speed mapped to the hand, unless given.
  const double hand_speed =
      a.hand_speed > 0 ? a.hand_speed : script.speed / h.workspace_scale;

  auto device = make_device(a, scene, *info, script.direction, hand_speed);
  if (!device) return fail(device.error().message);

  HapticRenderConfig config =
      make_render_config(h, *gains, (*device)->info().max_force, (*device)->info().max_stiffness);
  config.max_pc_damping = (*device)->info().max_damping;
  config.scaling.device_origin = (*device)->home();
  config.scaling.cell_origin = script.start;
  HapticRenderer renderer(config);
  HapticChannel channel;
  HapticLoopOptions lo;
  lo.duration = a.duration;
  lo.try_realtime = !a.no_realtime;
  lo.keep_log = !a.log.empty();
  HapticLoop loop(**device, renderer, channel, lo);
  // The tip may follow the hand at up to 20x the scene's insertion speed in simulated time.
  SimulationPortAdapter port(**sim, 20 * std::max(script.speed, 1e-6));
  const HapticLoopStats s = run_haptic_session(port, loop, channel);

  if (!a.log.empty()) {
    if (Status st = write_haptic_log_csv(a.log, loop.log()); !st.ok())
      return fail(st.error().message);
  }
  const NeedleReport& r = (*sim)->report();
  const double puncture_s =
      port.puncture_wall_ns() < 0
          ? -1.0
          : static_cast<double>(port.puncture_wall_ns() - loop.epoch_ns()) * 1e-9;
  if (a.json) {
    nlohmann::json j;
    j["rate_hz"] = s.rate_hz;
    j["period_p50_us"] = s.period_p50_us;
    j["period_p99_us"] = s.period_p99_us;
    j["period_max_us"] = s.period_max_us;
    j["sample_age_p99_ms"] = s.sample_age_p99_ms;
    j["device_max_force_N"] = s.max_force;
    j["passivity_energy_J"] = s.passivity_energy;
    j["clamped_ticks"] = s.clamped_ticks;
    j["nan_ticks"] = s.nan_ticks;
    j["ticks"] = s.ticks;
    j["missed_deadlines"] = s.missed_deadlines;
    j["stalled_ticks"] = s.stalled_ticks;
    j["passivity_min_energy_J"] = s.passivity_min_energy;
    j["passivity_controller_ticks"] = s.passivity_active_ticks;
    j["realtime"] = s.realtime;
    j["device"] = a.device;
    j["profile"] = (*device)->info().name;
    j["coupling_stiffness_N_per_m"] = gains->stiffness;
    j["coupling_damping_Ns_per_m"] = gains->damping;
    j["llewellyn_margin_Ns_per_m"] = llewellyn_margin(*gains, (*device)->info().impedance, period);
    j["sim_steps"] = port.steps();
    j["sim_samples_received"] = s.samples_received;
    j["sim_time_s"] = r.time;
    j["needle_travel_m"] = r.travel;
    j["punctured"] = r.punctured;
    j["puncture_wall_s"] = puncture_s;
    std::printf("%s\n", j.dump(2).c_str());
  } else {
    std::printf("zona haptics: %s, %s (%s), %.1f s: %.1f Hz, period p50 %.0f us p99 %.0f us max "
                "%.0f us, sample age p99 %.1f ms, max force %.3f N, passivity %.3g J, "
                "clamped %lld, nan %lld, sim steps %lld (t %.3g s)%s\n",
                scene.name.c_str(), a.device.c_str(), (*device)->info().name.c_str(), a.duration,
                s.rate_hz, s.period_p50_us, s.period_p99_us, s.period_max_us,
                s.sample_age_p99_ms, s.max_force, s.passivity_energy,
                static_cast<long long>(s.clamped_ticks), static_cast<long long>(s.nan_ticks),
                static_cast<long long>(port.steps()), r.time, r.punctured ? ", punctured" : "");
  }
}

}  // namespace

void add_haptics_command(CLI::App& app) {
  auto args = std::make_shared<HapticsArgs>();
  CLI::App* cmd = app.add_subcommand(
      "haptics", "Run a scene with the 1 kHz haptic thread and a virtual coupling");
  cmd->add_option("scene", args->scene, "Scene file or name")->required();
  cmd->add_option("--device", args->device, "scripted|emulated|replay|network")
      ->check(CLI::IsMember({"scripted", "emulated", "replay", "network"}));
  cmd->add_option("--duration", args->duration, "Seconds of haptic clock")->required();
  cmd->add_option("--log", args->log, "CSV, one row per haptic tick");
  cmd->add_flag("--json", args->json, "Print the measurements as JSON");
  cmd->add_option("--profile", args->profile, "Device limits: touch|falcon|omega");
  cmd->add_option("--replay", args->replay, "Recorded session CSV for --device replay");
  cmd->add_option("--plugin", args->plugin, "Native driver shared library (C ABI)");
  cmd->add_option("--plugin-config", args->plugin_config, "Text passed to the plug-in");
  cmd->add_option("--set", args->sets, "Override a scene key: key.path=value");
  cmd->add_option("--threads", args->threads, "Simulation threads (default 1: a core is left "
                                              "to the haptic thread)");
  cmd->add_option("--hand-speed", args->hand_speed, "Hand insertion speed [m/s]");
  cmd->add_flag("--no-realtime", args->no_realtime, "Do not ask for SCHED_FIFO");
  cmd->callback([args] { run_haptics(*args); });
}

}  // namespace zona::cli
