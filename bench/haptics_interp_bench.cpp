// Haptic force interpolation benchmark: zero-order hold (the SOFA complaint), first-order hold
// and the local stiffness model, against a reference run that evaluates the environment at
// every 1 kHz tick; then (with --loop SECONDS) the haptic loop's achieved rate and jitter.
//
// usage: haptics_interp_bench [--sim-hz 30] [--latency-ms 5] [--loop SECONDS]
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <string>
#include <vector>

#include "engine/haptics/haptics_loop.h"
#include "engine/haptics/haptics_render.h"

using namespace zona;

namespace {

// Membrane in device units (the mouse scene's scaling applied): a stiffening spring until the
// puncture depth, then a small drag. Force on the tool [N] and its slope [N/m] at depth d [m].
struct Membrane {
  double k = 250;          // [N/m] initial slope at the hand
  double d0 = 0.006;       // stiffening length [m]
  double puncture = 0.009; // [m]
  double force(double d) const {
    if (d <= 0) return 0;
    if (d >= puncture) return -0.05;
    return -k * d * (1 + d / d0);
  }
  double slope(double d) const { return d <= 0 || d >= puncture ? 0 : k * (1 + 2 * d / d0); }
};

struct Errors {
  double rms = 0, max = 0, rms_loading = 0;
  int n = 0, n_loading = 0;
};

void run_interp(double sim_hz, double latency_ms) {
  const double T = 1e-3;
  const double speed = 0.02;  // [m/s] at the hand
  const int ticks = 700;
  const int every = std::max(1, static_cast<int>(std::lround(1.0 / (sim_hz * T))));
  const int latency = static_cast<int>(std::lround(latency_ms * 1e-3 / T));
  const Membrane m;
  const char* names[3] = {"zero_order_hold", "first_order_hold", "stiffness"};
  Errors e[3];
  ForceInterpolator in;
  int pending_at = -1;
  double pending_x = 0, pending_t = 0;
  for (int i = 0; i < ticks; ++i) {
    const double t = i * T;
    const double x = speed * t;  // scripted hand, open loop: the same path for every method
    if (i % every == 0) {
      pending_x = x;
      pending_t = t;
      pending_at = i + latency;
    }
    if (i == pending_at)
      in.push({m.force(pending_x), 0, 0}, m.slope(pending_x), {1, 0, 0}, {pending_x, 0, 0},
              pending_t);
    if (in.count == 0) continue;
    const double reference = m.force(x);
    const double got[3] = {in.force1.x, in.first_order_hold(t).x,
                           in.stiffness_model({x, 0, 0}).x};
    const bool loading = x < m.puncture;
    for (int k = 0; k < 3; ++k) {
      const double err = got[k] - reference;
      e[k].rms += err * err;
      e[k].max = std::max(e[k].max, std::abs(err));
      ++e[k].n;
      if (loading) {
        e[k].rms_loading += err * err;
        ++e[k].n_loading;
      }
    }
  }
  std::printf("# interpolation vs reference (1 kHz), simulation %.0f Hz, latency %.1f ms, "
              "hand 20 mm/s, membrane 250 N/m stiffening, puncture at 9 mm\n",
              sim_hz, latency_ms);
  std::printf("method,rms_error_N,max_error_N,rms_error_loading_N\n");
  for (int k = 0; k < 3; ++k)
    std::printf("%s,%.5f,%.5f,%.5f\n", names[k], std::sqrt(e[k].rms / e[k].n), e[k].max,
                std::sqrt(e[k].rms_loading / std::max(1, e[k].n_loading)));
}

// The loop alone (no simulation thread): achieved rate and jitter on this machine.
void run_loop(double seconds) {
  const DeviceInfo touch = device_profile("touch").value();
  HapticsDef h;
  HapticRenderConfig c = make_render_config(
      h, auto_coupling_gains(touch.impedance, 1e-3, touch.max_stiffness), touch.max_force,
      touch.max_stiffness);
  HapticRenderer r(c);
  auto device = make_emulated_device(touch, EmulatedHandDef{});
  HapticChannel channel;
  HapticLoopOptions o;
  o.duration = seconds;
  HapticLoop loop(*device, r, channel, o);
  loop.run();
  const HapticLoopStats& s = loop.stats();
  std::printf("# haptic loop alone, %.1f s\n", seconds);
  std::printf("rate_hz,period_p50_us,period_p99_us,period_max_us,missed,realtime\n");
  std::printf("%.2f,%.1f,%.1f,%.1f,%lld,%d\n", s.rate_hz, s.period_p50_us, s.period_p99_us,
              s.period_max_us, static_cast<long long>(s.missed_deadlines), s.realtime ? 1 : 0);
}

}  // namespace

int main(int argc, char** argv) {
  double sim_hz = 30, latency_ms = 5, loop_seconds = 0;
  for (int i = 1; i + 1 < argc; i += 2) {
    if (!std::strcmp(argv[i], "--sim-hz")) sim_hz = std::atof(argv[i + 1]);
    else if (!std::strcmp(argv[i], "--latency-ms")) latency_ms = std::atof(argv[i + 1]);
    else if (!std::strcmp(argv[i], "--loop")) loop_seconds = std::atof(argv[i + 1]);
    else {
      std::fprintf(stderr, "usage: %s [--sim-hz HZ] [--latency-ms MS] [--loop SECONDS]\n",
                   argv[0]);
      return 2;
    }
  }
  if (!(sim_hz > 0) || !(latency_ms >= 0)) {
    std::fprintf(stderr, "haptics_interp_bench: --sim-hz must be > 0, --latency-ms >= 0\n");
    return 2;
  }
  run_interp(sim_hz, latency_ms);
  if (loop_seconds > 0) run_loop(loop_seconds);
  return 0;
}
