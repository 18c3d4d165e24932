// SIGINT / SIGTERM end a running simulation at its next step (stop_signals.h).
#include "apps/stop_signals.h"

#include <csignal>
#include <utility>

namespace zona::cli {
namespace {

std::atomic<bool> g_stop_requested{false};
volatile std::sig_atomic_t g_stop_signal = 0;
static_assert(std::atomic<bool>::is_always_lock_free, "the signal handler needs a lock-free flag");

extern "C" void on_stop_signal(int sig) {
  g_stop_signal = sig;
  g_stop_requested.store(true, std::memory_order_relaxed);
}

}  // namespace

std::atomic<bool>& stop_requested() {
  return g_stop_requested;
}

int stop_signal() {
  return g_stop_signal;
}

const char* stop_signal_name(int sig) {
  return sig == SIGINT ? "SIGINT" : "SIGTERM";
}

StopOnSignals::StopOnSignals() {
  struct sigaction action {};
  action.sa_handler = on_stop_signal;
  sigemptyset(&action.sa_mask);
  action.sa_flags = SA_RESETHAND;
  for (auto [sig, previous] :
       {std::pair{SIGINT, &previous_int_}, std::pair{SIGTERM, &previous_term_}}) {
    sigaction(sig, nullptr, previous);
    if (previous->sa_handler != SIG_IGN) sigaction(sig, &action, nullptr);
  }
}

StopOnSignals::~StopOnSignals() {
  sigaction(SIGINT, &previous_int_, nullptr);
  sigaction(SIGTERM, &previous_term_, nullptr);
}

}  // namespace zona::cli
