// The 1 kHz haptic loop (absolute-deadline sleep, SCHED_FIFO when permitted) and the session
// that runs it beside the simulation thread.
#include "engine/haptics/haptics_loop.h"

#include <pthread.h>
#include <sched.h>
#include <time.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <thread>

namespace zona {
namespace {

double percentile(std::vector<float> values, double p) {
  if (values.empty()) return 0;
  const size_t k = std::min(values.size() - 1,
                            static_cast<size_t>(p * static_cast<double>(values.size() - 1) + 0.5));
  std::nth_element(values.begin(), values.begin() + static_cast<std::ptrdiff_t>(k), values.end());
  return values[k];
}

void sleep_until_ns(int64_t deadline_ns) {
  // steady_clock is CLOCK_MONOTONIC on Linux, so the absolute deadline is on the same clock.
  timespec ts;
  ts.tv_sec = static_cast<time_t>(deadline_ns / 1000000000);
  ts.tv_nsec = static_cast<long>(deadline_ns % 1000000000);
  while (clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &ts, nullptr) != 0) {
  }
}

// Says once per process that real-time priority was refused.
std::atomic<bool> g_said_realtime{false};

}  // namespace

int64_t haptic_clock_ns() {
  return std::chrono::duration_cast<std::chrono::nanoseconds>(
             std::chrono::steady_clock::now().time_since_epoch())
      .count();
}

HapticLoop::HapticLoop(HapticDevice& device, HapticRenderer& renderer, HapticChannel& channel,
                       const HapticLoopOptions& options)
    : device_(device), renderer_(renderer), channel_(channel), options_(options) {
  const double T = renderer.config().period;
  const size_t capacity = static_cast<size_t>(std::max(0.0, options.duration / T)) + 16;
  if (options.keep_log) log_.reserve(capacity);
  periods_us_.reserve(capacity);
  ages_ms_.reserve(capacity);
}

void HapticLoop::run() {
  const double T = renderer_.config().period;
  const auto period_ns = static_cast<int64_t>(std::llround(T * 1e9));
  // Real-time priority when the system grants it; otherwise best effort, said once.
  if (options_.try_realtime) {
    sched_param param{};
    param.sched_priority = options_.realtime_priority;
    const int rc = pthread_setschedparam(pthread_self(), SCHED_FIFO, &param);
    stats_.realtime = rc == 0;
    if (rc != 0 && !g_said_realtime.exchange(true))
      std::fprintf(stderr, "zona: haptics: real-time priority not permitted (SCHED_FIFO), "
                           "running best effort\n");
  }
  const auto total_ticks = static_cast<int64_t>(std::llround(options_.duration / T));
  epoch_ns_ = haptic_clock_ns();
  int64_t k = 0;
  int64_t previous_ns = -1;
  while (k < total_ticks && !stop_.load(std::memory_order_relaxed)) {
    sleep_until_ns(epoch_ns_ + k * period_ns);
    // 1. Newest simulation sample (never waits), taken before the tick's clock reading so that
    // a sample is never received before it was published, however the thread is scheduled.
    HapticSample sample;
    const bool fresh = channel_.samples.read(sample) && sample.sequence > 0;
    const int64_t now_ns = haptic_clock_ns();
    const double t = static_cast<double>(now_ns - epoch_ns_) * 1e-9;
    if (previous_ns >= 0 && periods_us_.size() < periods_us_.capacity())
      periods_us_.push_back(static_cast<float>(static_cast<double>(now_ns - previous_ns) * 1e-3));
    previous_ns = now_ns;

    const Vec3d sent_before = last_sent_;
    if (fresh) {
      const double published = static_cast<double>(sample.wall_ns - epoch_ns_) * 1e-9;
      renderer_.push_sample(sample, published);
      ++stats_.samples_received;
      watch_puncture_sample(sample, published, t, sent_before);
    }
    // 2. Device -> renderer -> device.
    if (estop_.load(std::memory_order_relaxed) && !renderer_.safety().stopped())
      renderer_.safety().emergency_stop();
    const bool failed = sim_failed_.load(std::memory_order_relaxed);
    if (failed && !renderer_.safety().shutting_down()) renderer_.safety().shut_down();
    const DeviceState state = device_.update(t);
    const HapticOutput out = renderer_.tick(state.position, state.velocity, t);
    device_.command(out.force, t);
    // 3. The commanded tool pose for the simulation.
    ToolCommand command;
    command.sequence = k + 1;
    command.wall_ns = now_ns;
    command.tool = out.tool_cell;
    channel_.commands.write(command);

    // 4. Measure and log (no allocation: capacities were reserved).
    last_sent_ = out.force;
    if (stats_.puncture_received_s >= 0 && stats_.puncture_felt_s < 0 &&
        std::abs(dot(out.force, puncture_axis_)) <= 0.5 * stats_.puncture_force_before)
      stats_.puncture_felt_s = t;
    stats_.max_force = std::max(stats_.max_force, norm(out.force));
    if (out.sample_age >= 0 && ages_ms_.size() < ages_ms_.capacity())
      ages_ms_.push_back(static_cast<float>(out.sample_age * 1e3));
    if (options_.keep_log) {
      if (log_.size() < log_.capacity())
        log_.push_back({t, state.position, out.force, out.sample_age});
      else
        stats_.log_full = true;
    }
    ++stats_.ticks;
    // A tick that overran whole periods skips their deadlines instead of bursting to catch up.
    const int64_t next_ns = epoch_ns_ + (k + 1) * period_ns;
    const int64_t after_ns = haptic_clock_ns();
    if (after_ns > next_ns) {
      const int64_t skip = (after_ns - next_ns) / period_ns;
      stats_.missed_deadlines += skip;
      k += skip;
    }
    ++k;
    // A failed simulation ends the session once the ramp has brought the force to zero.
    if (failed && norm(out.force) == 0.0) {
      stats_.simulation_failed = true;
      break;
    }
  }
  const double elapsed = static_cast<double>(haptic_clock_ns() - epoch_ns_) * 1e-9;
  stats_.rate_hz = elapsed > 0 ? static_cast<double>(stats_.ticks) / elapsed : 0;
  stats_.period_p50_us = percentile(periods_us_, 0.50);
  stats_.period_p99_us = percentile(periods_us_, 0.99);
  stats_.period_max_us = periods_us_.empty()
                             ? 0
                             : *std::max_element(periods_us_.begin(), periods_us_.end());
  stats_.sample_age_p99_ms = percentile(ages_ms_, 0.99);
  stats_.passivity_energy = renderer_.passivity().energy();
  stats_.passivity_min_energy = renderer_.passivity().min_energy();
  stats_.passivity_active_ticks = renderer_.passivity().active_ticks();
  stats_.passivity_axis_energy = renderer_.passivity().axis_energy();
  stats_.passivity_dissipated = renderer_.passivity().dissipated();
  stats_.passivity_clipped = renderer_.passivity().clipped();
  stats_.clamped_ticks = renderer_.safety().clamped_ticks();
  stats_.nan_ticks = renderer_.safety().nan_ticks();
  stats_.stalled_ticks = renderer_.safety().stalled_ticks();
}

void HapticLoop::watch_puncture_sample(const HapticSample& sample, double published, double t,
                                       Vec3d sent_before) {
  // Axial magnitudes: the drop is along the needle; units do not matter for the ratios.
  const double axial = std::abs(dot(sample.force, sample.axis));
  if (!sample.punctured) {
    unpunctured_sample_force_ = axial;
    return;
  }
  if (stats_.puncture_published_s < 0) {
    stats_.puncture_published_s = published;
    stats_.puncture_received_s = t;
    puncture_axis_ = sample.axis;
    stats_.puncture_force_before = std::abs(dot(sent_before, sample.axis));
  }
  if (stats_.puncture_sim_drop_s < 0 && axial <= 0.5 * unpunctured_sample_force_)
    stats_.puncture_sim_drop_s = published;
}

HapticLoopStats run_haptic_session(HapticSimulationPort& simulation, HapticLoop& loop,
                                   HapticChannel& channel) {
  std::atomic<bool> done{false};
  std::thread haptic([&] {
    loop.run();
    done.store(true, std::memory_order_release);
  });
  // The simulation thread: step with the newest command, publish, never wait on the loop.
  int64_t sequence = 0;
  while (!done.load(std::memory_order_acquire)) {
    ToolCommand command;
    channel.commands.read(command);
    HapticSample sample;
    const HapticPortStatus status =
        simulation.step(command.sequence > 0 ? &command : nullptr, sample);
    if (status != HapticPortStatus::kStepped) {
      // Finished: stop publishing; the haptic thread fades the force out (stall) and runs on.
      // Failed: it ramps the force to zero and ends the session.
      if (status == HapticPortStatus::kFailed) loop.simulation_failed();
      while (!done.load(std::memory_order_acquire))
        std::this_thread::sleep_for(std::chrono::milliseconds(1));
      break;
    }
    sample.sequence = ++sequence;
    sample.wall_ns = haptic_clock_ns();
    channel.samples.write(sample);
  }
  haptic.join();
  return loop.stats();
}

Status write_haptic_log_csv(const std::string& path, const std::vector<HapticLogRow>& rows) {
  std::FILE* f = std::fopen(path.c_str(), "w");
  if (!f) return make_error("%s: cannot write the haptic log", path.c_str());
  std::fprintf(f, "t_s,x_m,y_m,z_m,fx_N,fy_N,fz_N,sample_age_ms\n");
  for (const HapticLogRow& r : rows)
    std::fprintf(f, "%.6f,%.9g,%.9g,%.9g,%.6g,%.6g,%.6g,%.4f\n", r.t, r.position.x, r.position.y,
                 r.position.z, r.force.x, r.force.y, r.force.z,
                 r.sample_age < 0 ? -1.0 : r.sample_age * 1e3);
  const bool ok = std::fclose(f) == 0;
  if (!ok) return make_error("%s: write failed", path.c_str());
  return {};
}

}  // namespace zona
