// SIGINT and SIGTERM while a command runs a simulation (`zona run`, `zona study`): they end the
// run at its next step instead of killing the process, so that the command writes what it has
// (a cluster's time limit sends SIGTERM before it kills). The handler only stores
// (async-signal-safe); the run loop reads the flag once per step (RunOptions::stop), and the
// command exits 128 + the signal.
#pragma once

#include <signal.h>

#include <atomic>

namespace zona::cli {

/// The flag the handler sets, for RunOptions::stop.
std::atomic<bool>& stop_requested();

/// The signal that set it (SIGINT or SIGTERM), or 0.
int stop_signal();

/// "SIGINT" or "SIGTERM" for stop_signal().
const char* stop_signal_name(int sig);

/// Installs the handler for SIGINT and SIGTERM while it lives; the previous handlers return with
/// it. SA_RESETHAND makes a second signal kill at once, for a run stuck outside the step loop. A
/// signal the parent ignores stays ignored (a shell script's background job ignores SIGINT, so
/// that Ctrl-C reaches only the foreground).
class StopOnSignals {
 public:
  StopOnSignals();
  ~StopOnSignals();
  StopOnSignals(const StopOnSignals&) = delete;
  StopOnSignals& operator=(const StopOnSignals&) = delete;

 private:
  struct sigaction previous_int_ {};
  struct sigaction previous_term_ {};
};

}  // namespace zona::cli
