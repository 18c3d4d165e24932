// End-to-end tests of `zona haptics`: the --json keys and the log's columns, a replayed session,
// passivity of an emulated-hand run, and bad arguments refused with one-line errors. Runs are
// a few tenths of a second on a tiny cell; nothing here asserts a rate or a jitter (those
// belong in the benchmark: docs/haptics.md).
#include <arpa/inet.h>
#include <gtest/gtest.h>
#include <netinet/in.h>
#include <sys/socket.h>
#include <unistd.h>

#include <algorithm>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <sstream>
#include <string>
#include <vector>

#include "tests/apps/cli_runner.h"

namespace {

using zona::test::CliRun;
using zona::test::run_zona;
using zona::test::TempDir;

namespace fs = std::filesystem;

int count_lines(const std::string& s) {
  int n = 0;
  for (char c : s) n += c == '\n';
  return n;
}

// A tiny held cell that steps in microseconds, with the mouse scene's haptic scaling.
const char* kScene = R"({
  "name": "tiny_haptic",
  "mesh": {"generate": {"diameter": "20 um", "vertices": 150}},
  "model": "svk",
  "materials": {"default": {"young": "10 kPa", "poisson": 0.45, "damping": "50 1/s"}},
  "integrator": {"target_dt": "20 us", "mass_scaling_mode": "selective", "dt_safety": 0.25,
                 "stiffness_damping": "100 us", "duration": "100 s"},
  "needle": {"tip_radius": "2 um", "standoff": "0.5 um", "speed": "0.1 mm/s", "max_travel": "80 um",
             "force_filter": "0.5 ms"},
  "puncture": {"criterion": "force", "threshold": "0.2 uN", "force_drop": 0.9, "drop_time": "0.1 ms"},
  "holding_pipette": {"mode": "fixed", "inner_radius": "5 um"},
  "haptics": {"workspace_scale": "50 um/cm", "force_scale": "0.3 N/uN", "max_force": "3.3 N"}
})";

fs::path write_scene(const TempDir& dir, const char* text = kScene) {
  const fs::path scene = dir.path / "tiny.json";
  std::ofstream(scene) << text;
  return scene;
}

std::vector<std::vector<double>> read_rows(const fs::path& csv, std::string& header) {
  std::ifstream in(csv);
  std::getline(in, header);
  std::vector<std::vector<double>> rows;
  std::string line;
  while (std::getline(in, line)) {
    std::stringstream ss(line);
    std::vector<double> row;
    std::string cell;
    while (std::getline(ss, cell, ',')) row.push_back(std::stod(cell));
    rows.push_back(row);
  }
  return rows;
}

TEST(CmdHaptics, JsonKeysAndLogColumns) {
  TempDir dir;
  const fs::path scene = write_scene(dir);
  const fs::path log = dir.path / "session.csv";
  const CliRun r =
      run_zona("haptics " + scene.string() +
                   " --device scripted --duration 0.3 --no-realtime --json --log " + log.string(),
               dir.path);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  const nlohmann::json j = nlohmann::json::parse(r.out);
  // The keys the issue lists, and the puncture measurement.
  for (const char* key :
       {"rate_hz", "period_p50_us", "period_p99_us", "period_max_us", "sample_age_p99_ms",
        "device_max_force_N", "passivity_energy_J", "clamped_ticks", "nan_ticks",
        "puncture_felt_delay_ms", "passivity_axis_energy_J", "coupling_stiffness_N_per_m",
        "llewellyn_margin_Ns_per_m", "sim_steps", "ticks"})
    EXPECT_TRUE(j.contains(key)) << key;
  EXPECT_EQ(j["nan_ticks"].get<int64_t>(), 0);
  EXPECT_LE(j["device_max_force_N"].get<double>(), 3.3 + 1e-9);  // the scene's (and Touch's) limit
  EXPECT_GT(j["sim_steps"].get<int64_t>(), 0);
  EXPECT_GT(j["llewellyn_margin_Ns_per_m"].get<double>(), 0);  // auto gains satisfy the criterion
  EXPECT_EQ(j["passivity_axis_energy_J"].size(), 3u);
  // The log: the documented header, one row per tick, finite positions along +x (the script).
  std::string header;
  const auto rows = read_rows(log, header);
  EXPECT_EQ(header, "t_s,x_m,y_m,z_m,fx_N,fy_N,fz_N,sample_age_ms");
  ASSERT_EQ(static_cast<int64_t>(rows.size()), j["ticks"].get<int64_t>());
  ASSERT_GT(rows.size(), 10u);
  for (const auto& row : rows) ASSERT_EQ(row.size(), 8u);
  // The scripted hand moves at 0.1 mm/s / (50 um/cm) = 2 cm/s along +x.
  const auto& last = rows.back();
  EXPECT_NEAR(last[1], 0.02 * last[0], 1e-6);
  EXPECT_EQ(last[2], 0.0);
  // Time increases tick by tick.
  for (size_t i = 1; i < rows.size(); ++i) ASSERT_GT(rows[i][0], rows[i - 1][0]);
}

TEST(CmdHaptics, TipFollowsTheHandAtMostAtTheSceneSpeedLimit) {
  // haptics.max_tip_speed a fifth of the hand's speed mapped to the cell (0.1 mm/s): the tip lags
  // the hand and moves at the limit in simulated time, never faster.
  TempDir dir;
  std::string text = kScene;
  const std::string key = R"("max_force": "3.3 N")";
  text.replace(text.find(key), key.size(), key + R"(, "max_tip_speed": "0.02 mm/s")");
  const fs::path scene = write_scene(dir, text.c_str());
  const CliRun r = run_zona(
      "haptics " + scene.string() + " --device scripted --duration 0.3 --no-realtime --json",
      dir.path);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  const nlohmann::json j = nlohmann::json::parse(r.out);
  const double sim_time = j["sim_time_s"].get<double>();
  const double travel = j["needle_travel_m"].get<double>();
  ASSERT_GT(sim_time, 1e-3);
  EXPECT_LE(travel, 0.02e-3 * sim_time + 1e-9);
  EXPECT_GE(travel, 0.5 * 0.02e-3 * sim_time);
}

TEST(CmdHaptics, ScriptedHandPushesPastThePathsEndByTheCouplingsStretch) {
  // The scripted hand holds its path rigidly and the coupling's spring pushes the needle: it
  // aims past the path's end (max_travel 2 um: 0.4 mm of hand) by the spring's stretch at the
  // device's force (Touch: 3.3 N), so that the spring can push the device's full force into a
  // membrane at the path's end. At 2 cm/s the hand is there after about 0.55 s.
  TempDir dir;
  std::string text = kScene;
  const std::string key = R"("max_travel": "80 um")";
  text.replace(text.find(key), key.size(), R"("max_travel": "2 um")");
  const fs::path scene = write_scene(dir, text.c_str());
  const fs::path log = dir.path / "session.csv";
  const CliRun r = run_zona("haptics " + scene.string() +
                                " --device scripted --profile touch --duration 0.8 --no-realtime "
                                "--json --log " + log.string(),
                            dir.path);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  const nlohmann::json j = nlohmann::json::parse(r.out);
  const double kc = j["coupling_stiffness_N_per_m"].get<double>();
  ASSERT_GT(kc, 0);
  std::string header;
  const auto rows = read_rows(log, header);
  ASSERT_GT(rows.size(), 100u);
  const double end = 2e-6 / (50e-6 / 1e-2) + 3.3 / kc;
  EXPECT_NEAR(rows.back()[1], end, 1e-9);
  double furthest = 0;
  for (const auto& row : rows) furthest = std::max(furthest, row[1]);
  EXPECT_LE(furthest, end + 1e-9);
}

TEST(CmdHaptics, ReplaysRecordedSession) {
  TempDir dir;
  const fs::path scene = write_scene(dir);
  const fs::path log = dir.path / "session.csv", replayed = dir.path / "replayed.csv";
  const CliRun a =
      run_zona("haptics " + scene.string() +
                   " --device scripted --duration 0.2 --no-realtime --log " + log.string(),
               dir.path);
  ASSERT_EQ(a.exit_code, 0) << a.err;
  EXPECT_NE(a.out.find("zona haptics:"), std::string::npos) << a.out;  // the summary line
  const CliRun b =
      run_zona("haptics " + scene.string() + " --device replay --replay " + log.string() +
                   " --duration 0.1 --no-realtime --json --log " + replayed.string(),
               dir.path);
  ASSERT_EQ(b.exit_code, 0) << b.err;
  // The replayed hand retraces the recording: positions at the same session time agree.
  std::string h1, h2;
  const auto rec = read_rows(log, h1), rep = read_rows(replayed, h2);
  ASSERT_GT(rep.size(), 10u);
  const auto& row = rep[rep.size() / 2];
  // Replay time starts at the recording's first row; the recording moved at 2 cm/s.
  EXPECT_NEAR(row[1], rec.front()[1] + 0.02 * row[0], 1e-6);
}

TEST(CmdHaptics, FailedSimulationStopsTheSessionWithZeroForce) {
  // A hand driving the tip at 1 m/s (10^4 times the insertion speed) blows the cell up within
  // a few steps: the session ramps the device force to zero, stops long before its 30 s, and
  // exits non-zero with the step and the reason; the log and the JSON are still written.
  TempDir dir;
  const fs::path scene = write_scene(dir);
  const fs::path log = dir.path / "failed.csv";
  const CliRun r = run_zona("haptics " + scene.string() +
                                " --device scripted --duration 30 --hand-speed 1 --no-realtime "
                                "--set haptics.max_tip_speed=1m/s --json --log " +
                                log.string(),
                            dir.path);
  EXPECT_EQ(r.exit_code, 1) << r.err;
  EXPECT_EQ(count_lines(r.err), 1) << r.err;
  EXPECT_NE(r.err.find("the simulation failed at step"), std::string::npos) << r.err;
  EXPECT_NE(r.err.find("ramped to zero"), std::string::npos) << r.err;
  const nlohmann::json j = nlohmann::json::parse(r.out);
  EXPECT_TRUE(j["sim_failed"].get<bool>());
  EXPECT_LT(j["ticks"].get<int64_t>(), 30000);
  std::string header;
  const auto rows = read_rows(log, header);
  ASSERT_FALSE(rows.empty());
  EXPECT_EQ(rows.back()[4], 0.0);
  EXPECT_EQ(rows.back()[5], 0.0);
  EXPECT_EQ(rows.back()[6], 0.0);
}

TEST(CmdHaptics, EmulatedHandRunIsPassive) {
  TempDir dir;
  const fs::path scene = write_scene(dir);
  const CliRun r = run_zona(
      "haptics " + scene.string() + " --device emulated --duration 0.4 --no-realtime --json",
      dir.path);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  const nlohmann::json j = nlohmann::json::parse(r.out);
  // The hand put energy in and the controller never gave it back (observer >= 0 all run). The
  // controller predicts one period ahead; if the haptic thread itself is descheduled (a loaded
  // CI machine) a force is held longer than predicted, so the run-long minimum gets a margin of
  // 0.1 % of the energy put in rather than zero.
  const double energy = j["passivity_energy_J"].get<double>();
  EXPECT_GE(energy, 0.0);
  EXPECT_GE(j["passivity_min_energy_J"].get<double>(), -1e-3 * energy);
  EXPECT_EQ(j["nan_ticks"].get<int64_t>(), 0);
  EXPECT_LE(j["device_max_force_N"].get<double>(), 3.3 + 1e-9);
  EXPECT_GT(j["passivity_energy_J"].get<double>(), 0.0);  // it did touch the cell
}

TEST(CmdHaptics, BadArgumentsAreOneLineErrors) {
  TempDir dir;
  const fs::path scene = write_scene(dir);
  const std::string s = scene.string();
  struct Case {
    std::string args;
    std::string names;  // what the message must mention
  };
  const std::vector<Case> cases = {
      {"haptics " + s + " --device bogus --duration 0.1", "--device"},
      {"haptics " + s + " --device emulated --duration 0", "--duration"},
      {"haptics " + s + " --device emulated --duration -1", "--duration"},
      {"haptics " + s + " --device emulated", "--duration"},
      {"haptics " + s + " --device emulated --duration 0.1 --profile wand", "wand"},
      {"haptics " + s + " --device replay --duration 0.1", "--replay"},
      {"haptics " + s + " --device replay --replay /nonexistent/log.csv --duration 0.1",
       "/nonexistent/log.csv"},
      {"haptics /nonexistent/scene.json --device emulated --duration 0.1",
       "/nonexistent/scene.json"},
      {"haptics " + s + " --device emulated --duration 0.1 --stiffness-window 0",
       "--stiffness-window"},
      {"haptics " + s + " --device emulated --duration 0.1 --set haptics.coupling_stiffness=1e5",
       "coupling_stiffness"},
  };
  for (const Case& c : cases) {
    const CliRun r = run_zona(c.args, dir.path);
    EXPECT_NE(r.exit_code, 0) << c.args;
    EXPECT_EQ(count_lines(r.err), 1) << c.args << "\n" << r.err;
    EXPECT_NE(r.err.find(c.names), std::string::npos) << c.args << "\n" << r.err;
    EXPECT_TRUE(r.out.empty()) << c.args << "\n" << r.out;
  }
}

// A free UDP port on every interface (a bound and closed socket's; another process could take
// it in between, which the test would report as a bind error).
int free_udp_port() {
  const int fd = ::socket(AF_INET, SOCK_DGRAM, 0);
  sockaddr_in a{};
  a.sin_family = AF_INET;
  socklen_t len = sizeof a;
  int port = -1;
  if (fd >= 0 && ::bind(fd, reinterpret_cast<sockaddr*>(&a), sizeof a) == 0 &&
      ::getsockname(fd, reinterpret_cast<sockaddr*>(&a), &len) == 0)
    port = ntohs(a.sin_port);
  if (fd >= 0) ::close(fd);
  return port;
}

// The UDP bridge binds loopback only, unless --allow-remote-bridge: then with a warning.
TEST(CmdHaptics, RemoteBridgeNeedsTheFlag) {
  TempDir dir;
  const fs::path scene = write_scene(dir);
  const int port = free_udp_port();
  ASSERT_GT(port, 0);
  const std::string args = "haptics " + scene.string() +
                           " --device network --duration 0.1 --no-realtime --threads 1 --set "
                           "haptics.network_host=0.0.0.0 --set haptics.network_port=" +
                           std::to_string(port);
  CliRun r = run_zona(args, dir.path);
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_EQ(count_lines(r.err), 1) << r.err;
  EXPECT_NE(r.err.find("haptics.network_host: '0.0.0.0' is not a loopback address"),
            std::string::npos)
      << r.err;
  EXPECT_NE(r.err.find("--allow-remote-bridge"), std::string::npos) << r.err;
  EXPECT_TRUE(r.out.empty()) << r.out;

  r = run_zona(args + " --allow-remote-bridge", dir.path);
  EXPECT_EQ(r.exit_code, 0) << r.err;
  EXPECT_EQ(count_lines(r.err), 1) << r.err;
  EXPECT_NE(r.err.find("zona haptics: warning: the UDP bridge listens on 0.0.0.0:" +
                       std::to_string(port) + ", not loopback"),
            std::string::npos)
      << r.err;
  EXPECT_NE(r.out.find("zona haptics: "), std::string::npos) << r.out;

  // Loopback needs no flag and says nothing.
  r = run_zona("haptics " + scene.string() +
                   " --device network --duration 0.1 --no-realtime --threads 1 --set "
                   "haptics.network_port=" + std::to_string(port),
               dir.path);
  EXPECT_EQ(r.exit_code, 0) << r.err;
  EXPECT_TRUE(r.err.empty()) << r.err;
}

TEST(CmdHaptics, SceneWithoutNeedleIsRefused) {
  TempDir dir;
  const fs::path scene = dir.path / "no_needle.json";
  std::ofstream(scene)
      << R"({"name": "ball", "mesh": {"generate": {"diameter": "20 um", "vertices": 150}},
    "integrator": {"duration": "1 ms"}})";
  const CliRun r =
      run_zona("haptics " + scene.string() + " --device emulated --duration 0.1", dir.path);
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_EQ(count_lines(r.err), 1) << r.err;
  EXPECT_NE(r.err.find("needle"), std::string::npos) << r.err;
}

}  // namespace
