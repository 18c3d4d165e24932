// The haptic thread: a 1 kHz loop on its own clock (absolute deadlines, real-time priority when
// permitted) that never waits on the simulation, and the session that runs it beside a
// simulation thread. Measures its achieved rate, period jitter and sample age.
//
//   haptic thread (1 kHz)                      simulation thread (as fast as it steps)
//   ---------------------                      -----------------------------------------
//   sleep to absolute deadline k T             read newest ToolCommand  <- commands buffer
//   read newest HapticSample <- samples buffer  step1; set tool pose; step2
//   device.update -> renderer.tick -> command   publish HapticSample  -> samples buffer
//   publish ToolCommand -> commands buffer
#pragma once

#include <atomic>
#include <cstdint>
#include <string>
#include <vector>

#include "engine/haptics/haptics_device.h"
#include "engine/haptics/haptics_exchange.h"
#include "engine/haptics/haptics_render.h"

namespace zona {

/// One haptic tick, as logged.
struct HapticLogRow {
  double t = 0;               ///< haptic clock [s]
  Vec3d position{0, 0, 0};    ///< device position, device units [m]
  Vec3d force{0, 0, 0};       ///< force sent to the device [N]
  double sample_age = -1;     ///< age of the newest simulation sample [s]; negative: none
};

/// What a haptic run measured.
struct HapticLoopStats {
  int64_t ticks = 0;
  int64_t missed_deadlines = 0;   ///< deadlines skipped because a tick overran a whole period
  double rate_hz = 0;             ///< ticks per second of the loop's clock [Hz]
  double period_p50_us = 0, period_p99_us = 0, period_max_us = 0;  ///< tick-to-tick [us]
  double sample_age_p99_ms = 0;   ///< [ms]
  double max_force = 0;           ///< largest force magnitude sent [N]
  double passivity_energy = 0;    ///< observed energy at the end [J]
  double passivity_min_energy = 0;  ///< lowest observed energy [J]
  int64_t passivity_active_ticks = 0;
  int64_t clamped_ticks = 0, nan_ticks = 0, stalled_ticks = 0;
  int64_t samples_received = 0;   ///< fresh simulation samples taken
  bool realtime = false;          ///< SCHED_FIFO was granted
  bool log_full = false;          ///< the log's capacity ran out (rows after it were dropped)
  /// The simulation failed: the force was ramped to zero and the loop ended before `duration`.
  bool simulation_failed = false;
  Vec3d passivity_axis_energy{0, 0, 0};  ///< observed energy per device axis at the end [J]
  double passivity_dissipated = 0;  ///< energy the passivity controller dissipated [J]
  double passivity_clipped = 0;     ///< energy its bound kept from the hand [J]
  /// The puncture as the haptic thread saw it (loop clock [s]; -1: did not happen). The
  /// simulation published its first punctured sample at `published`; its published axial force
  /// first fell to half of the last unpunctured sample's at `sim_drop` (publication time); the
  /// haptic thread took the first punctured sample at `received`; the axial force sent to the
  /// device first fell to half of the force sent just before at `felt`.
  double puncture_published_s = -1, puncture_sim_drop_s = -1;
  double puncture_received_s = -1, puncture_felt_s = -1;
  double puncture_force_before = 0;  ///< axial force sent on the tick before `received` [N]
};

/// Options of a haptic run.
struct HapticLoopOptions {
  double duration = 1.0;          ///< [s] of the haptic clock
  bool try_realtime = true;       ///< ask for SCHED_FIFO (said once on stderr when refused)
  int realtime_priority = 80;
  bool keep_log = true;           ///< store one HapticLogRow per tick (sized up front)
};

/// What one step of a HapticSimulationPort did.
enum class HapticPortStatus {
  kStepped,   ///< stepped: publish the sample
  kFinished,  ///< reached its end: nothing more to publish; the loop runs on (stall fade)
  kFailed,    ///< failed its health check: the session ramps the force to zero and stops
};

/// The simulation side of a session, adapted by the caller (engine/haptics/haptics_sim_port.h
/// wraps a Simulation): one call advances it by one step with the newest commanded tool pose
/// and returns the sample to publish. Called from the simulation thread only.
class HapticSimulationPort {
 public:
  virtual ~HapticSimulationPort() = default;
  /// One step. `command` is null until the haptic thread has commanded a pose. `sample` is
  /// published only when kStepped is returned.
  virtual HapticPortStatus step(const ToolCommand* command, HapticSample& sample) = 0;
};

/// The haptic thread's loop. run() blocks the calling thread for `duration`; stop() (from any
/// thread) ends it early. Use from one thread at a time.
class HapticLoop {
 public:
  HapticLoop(HapticDevice& device, HapticRenderer& renderer, HapticChannel& channel,
             const HapticLoopOptions& options);
  /// Runs the loop on the calling thread until the duration passes or stop() is called.
  void run();
  /// Asks run() to return after its current tick.
  void stop() { stop_.store(true, std::memory_order_relaxed); }
  /// Latches the emergency stop: zero force from the next tick on (the loop keeps running).
  void emergency_stop() { estop_.store(true, std::memory_order_relaxed); }
  /// The simulation failed (from any thread): the force ramps to zero over the renderer's
  /// fade_time, and run() returns once a zero force has been sent (stats().simulation_failed).
  void simulation_failed() { sim_failed_.store(true, std::memory_order_relaxed); }

  /// Steady-clock time [ns] that the loop's clock counts from (set when run() starts).
  int64_t epoch_ns() const { return epoch_ns_; }
  const HapticLoopStats& stats() const { return stats_; }
  const std::vector<HapticLogRow>& log() const { return log_; }

 private:
  HapticDevice& device_;
  HapticRenderer& renderer_;
  HapticChannel& channel_;
  HapticLoopOptions options_;
  std::atomic<bool> stop_{false};
  std::atomic<bool> estop_{false};
  std::atomic<bool> sim_failed_{false};
  int64_t epoch_ns_ = 0;
  HapticLoopStats stats_;
  std::vector<HapticLogRow> log_;
  std::vector<float> periods_us_;  // tick-to-tick intervals, sized up front
  std::vector<float> ages_ms_;
  // Puncture watch (see HapticLoopStats): the last unpunctured sample's axial force [N], the
  // needle axis, the force sent on the previous tick [N].
  void watch_puncture_sample(const HapticSample& sample, double published, double t,
                             Vec3d sent_before);
  double unpunctured_sample_force_ = 0;
  Vec3d puncture_axis_{1, 0, 0};
  Vec3d last_sent_{0, 0, 0};
};

/// Runs a session: the haptic loop on a new thread, the simulation port stepped on the calling
/// thread until the loop ends (the simulation never blocks the haptic thread and vice versa).
/// Returns the loop's statistics; `loop` keeps the log.
HapticLoopStats run_haptic_session(HapticSimulationPort& simulation, HapticLoop& loop,
                                   HapticChannel& channel);

/// Steady-clock now [ns] (the clock samples are stamped with).
int64_t haptic_clock_ns();

/// Writes the log as CSV: t_s,x_m,y_m,z_m,fx_N,fy_N,fz_N,sample_age_ms (one row per tick).
Status write_haptic_log_csv(const std::string& path, const std::vector<HapticLogRow>& rows);

}  // namespace zona
