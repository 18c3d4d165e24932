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
#include "engine/haptics/haptics_loop.h"
#include "engine/haptics/haptics_sim_port.h"
#include "engine/scene/scene.h"
#include "engine/sim/recorder.h"
#include "engine/sim/simulation.h"
#include "kernels/backend_factory.h"

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
  std::string backend = "cpu";
  int threads = 1;
  double hand_speed = 0;  // [m/s]; 0: the scene's needle speed mapped to the hand
  bool no_realtime = false;
  bool lateral_force = false;     // also render the (low-passed) lateral contact force
  bool allow_remote_bridge = false;  // --device network may bind a non-loopback address
  double stiffness_window = 0.5e-6;  // travel over which the local stiffness is taken [m]
};

Result<std::unique_ptr<HapticDevice>> make_device(const HapticsArgs& a, const Scene& scene,
                                                  const DeviceInfo& info, const Vec3d& axis,
                                                  double hand_speed, double coupling_stiffness) {
  if (!a.plugin.empty()) return make_plugin_device(a.plugin, a.plugin_config);
  // Hand-side path: the needle axis, a travel of 6 cm at most (a stylus workspace).
  const double travel = scene.needle.max_travel > 0
                            ? std::min(0.06, scene.needle.max_travel / scene.haptics.workspace_scale)
                            : 0.06;
  if (a.device == "scripted") {
    ScriptedDeviceDef d;
    d.direction = axis;
    d.speed = hand_speed;
    // A scripted hand holds its path rigidly; the coupling spring is what pushes the needle.
    // It aims past the path's end by the spring's stretch at the device's full force: a hand
    // stopped at the end alone stalls where the spring's pull meets the cell's resistance (the
    // mouse cell: about 4 of the 7.5 uN it punctures at, the tip stuck near 34 um).
    d.max_travel = std::min(0.06, travel + info.max_force / coupling_stiffness);
    return make_scripted_device(info, d);
  }
  if (a.device == "emulated") {
    EmulatedHandDef d;
    d.direction = axis;
    d.speed = hand_speed;
    // The operator aims past the path's end by the lag at which the hand's grip spring pushes
    // the device's full force: otherwise a soft hand stops short of a membrane that needs most
    // of that force (the mouse cell: 2.25 N at the hand, a 0.75 cm lag at 300 N/m).
    d.max_travel = std::min(0.06, travel + info.max_force / d.hand_stiffness);
    return make_emulated_device(info, d);
  }
  if (a.device == "replay") {
    const std::string path = a.replay.empty() ? scene.haptics.replay_file : a.replay;
    if (path.empty()) return make_error("--device replay needs --replay FILE or haptics.replay_file");
    return make_replay_device(info, path);
  }
  if (a.device == "network") {
    const HapticsDef& h = scene.haptics;
    Result<std::unique_ptr<HapticDevice>> device =
        make_network_device(info, h.network_host, h.network_port, a.allow_remote_bridge);
    if (device && !is_loopback_ipv4(h.network_host))
      std::fprintf(stderr,
                   "zona haptics: warning: the UDP bridge listens on %s:%d, not loopback: any "
                   "machine that reaches it can drive the needle (--allow-remote-bridge)\n",
                   h.network_host.c_str(), network_device_port(**device));
    return device;
  }
  return make_error("--device %s: expected scripted, emulated, replay or network",
                    a.device.c_str());
}

void run_haptics(const HapticsArgs& a) {
  if (!(a.duration > 0) || a.duration > 3600) return fail("--duration: expected 0 < SECONDS <= 3600");
  if (!(a.stiffness_window > 0) || a.stiffness_window > 1e-3)
    return fail("--stiffness-window: expected 0 < METRES <= 1e-3");
  if (a.hand_speed < 0 || !std::isfinite(a.hand_speed))
    return fail("--hand-speed: expected METRES_PER_SECOND >= 0");
  if (a.threads < 0) return fail("--threads: expected N >= 0");
  auto path = find_scene_file(a.scene);
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

  auto kind = parse_backend_kind(a.backend);
  if (!kind) return fail("--backend: " + kind.error().message);
  // A hand-driven session is dynamics: measured, never held to the quasi-static check.
  scene.experiment = Experiment::kDynamic;
  // The hand moves the needle: the simulation runs as long as the session, not to the end of
  // the scene's scripted insertion.
  if (!(scene.integrator.duration > 0)) scene.integrator.duration = 3600.0;

  // The tip follows the hand at up to haptics.max_tip_speed in simulated time (auto: 20x the
  // scene's insertion speed): here for every step the host hands over, and in the job for every
  // step it runs (the GPU takes the hand's pose up every few steps).
  const double max_tip_speed =
      h.max_tip_speed ? *h.max_tip_speed : 20 * std::max(scene.needle.speed, 1e-6);
  SimulationOptions so;
  so.threads = a.threads;
  so.stiffness_window = a.stiffness_window;
  so.external_tip_max_speed = max_tip_speed;
  if (*kind != BackendKind::kCpu) {
    BackendOptions bo;
    bo.cpu_threads = a.threads;
    const BackendKind k = *kind;
    so.backend_factory = [k, bo](std::string* notice) { return make_backend(k, bo, notice); };
  }
  auto sim = Simulation::create(scene, so);
  if (!sim) return fail(sim.error().message);
  const NeedleScript& script = (*sim)->needle_script();
  // The scene's insertion speed mapped to the hand, unless given.
  const double hand_speed =
      a.hand_speed > 0 ? a.hand_speed : script.speed / h.workspace_scale;

  auto device = make_device(a, scene, *info, script.direction, hand_speed, gains->stiffness);
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
  SimulationHapticPort port(**sim, max_tip_speed, a.lateral_force);
  const HapticLoopStats s = run_haptic_session(port, loop, channel);

  if (!a.log.empty()) {
    if (Status st = write_haptic_log_csv(a.log, loop.log()); !st.ok())
      return fail(st.error().message);
  }
  const NeedleReport& r = (*sim)->report();
  // A simulation that failed its health check (blow-up, non-finite, the needle through the
  // surface) ended the session: the force was ramped to zero first. The measurements and the
  // log are still written; the exit code says it failed.
  const bool sim_failed = s.simulation_failed;
  const double puncture_s =
      port.puncture_wall_ns() < 0
          ? -1.0
          : static_cast<double>(port.puncture_wall_ns() - loop.epoch_ns()) * 1e-9;
  // The operator feels the drop when the axial force sent to the device has halved; the delay
  // counts from the simulation's first punctured sample (its publication, the moment the
  // simulation saw it). -1: no puncture, or not felt within the run.
  auto delay_ms = [](double from, double to) {
    return from >= 0 && to >= 0 ? (to - from) * 1e3 : -1.0;
  };
  const double felt_delay_ms = delay_ms(s.puncture_published_s, s.puncture_felt_s);
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
    j["sim_failed"] = sim_failed;
    if (sim_failed) j["sim_failure"] = port.failure();
    j["sim_samples_received"] = s.samples_received;
    j["sim_time_s"] = r.time;
    j["needle_travel_m"] = r.travel;
    j["punctured"] = r.punctured;
    j["puncture_wall_s"] = puncture_s;
    j["puncture_felt_delay_ms"] = felt_delay_ms;
    j["puncture_sim_drop_delay_ms"] = delay_ms(s.puncture_published_s, s.puncture_sim_drop_s);
    j["puncture_received_delay_ms"] = delay_ms(s.puncture_published_s, s.puncture_received_s);
    j["puncture_force_before_N"] = s.puncture_force_before;
    j["passivity_axis_energy_J"] = {s.passivity_axis_energy.x, s.passivity_axis_energy.y,
                                    s.passivity_axis_energy.z};
    j["passivity_dissipated_J"] = s.passivity_dissipated;
    j["passivity_clipped_J"] = s.passivity_clipped;
    j["lateral_force"] = a.lateral_force;
    j["stiffness_window_m"] = a.stiffness_window;
    j["sim_real_time_ratio"] = a.duration > 0 ? r.time / a.duration : 0.0;
    std::printf("%s\n", j.dump(2).c_str());
  } else {
    std::printf("zona haptics: %s, %s (%s), %.1f s: %.1f Hz, period p50 %.0f us p99 %.0f us max "
                "%.0f us, sample age p99 %.1f ms, max force %.3f N, passivity %.3g J, "
                "clamped %lld, nan %lld, sim steps %lld (t %.3g s)%s",
                scene.name.c_str(), a.device.c_str(), (*device)->info().name.c_str(), a.duration,
                s.rate_hz, s.period_p50_us, s.period_p99_us, s.period_max_us,
                s.sample_age_p99_ms, s.max_force, s.passivity_energy,
                static_cast<long long>(s.clamped_ticks), static_cast<long long>(s.nan_ticks),
                static_cast<long long>(port.steps()), r.time, r.punctured ? ", punctured" : "");
    if (felt_delay_ms >= 0) std::printf(", drop felt %.1f ms after the simulation", felt_delay_ms);
    std::printf("\n");
  }
  if (sim_failed)
    fail(scene.name + ": " + port.failure() +
         "; the device force was ramped to zero and the session stopped");
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
  cmd->add_option("--backend", args->backend,
                  "Compute backend: auto, cpu or cuda (the GPU runs the injection step on the "
                  "device and hands the haptic thread its record)")
      ->capture_default_str();
  cmd->add_option("--threads", args->threads, "Simulation threads (default 1: a core is left "
                                              "to the haptic thread)");
  cmd->add_option("--hand-speed", args->hand_speed, "Hand insertion speed [m/s]");
  cmd->add_flag("--no-realtime", args->no_realtime, "Do not ask for SCHED_FIFO");
  cmd->add_flag("--lateral-force", args->lateral_force,
                "Also render the lateral contact force (low-passed like the axial one)");
  cmd->add_flag("--allow-remote-bridge", args->allow_remote_bridge,
                "--device network: allow haptics.network_host to be a non-loopback address "
                "(other machines can then drive the needle)");
  cmd->add_option("--stiffness-window", args->stiffness_window,
                  "Needle travel over which the local stiffness is taken [m] (default 0.5e-6)");
  cmd->callback([args] { run_haptics(*args); });
}

}  // namespace zona::cli
