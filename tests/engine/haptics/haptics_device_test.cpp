// Haptic devices: profiles, scripted motion, trajectory/replay CSV, UDP loopback bridge, plug-in
// loading errors.
#include "engine/haptics/haptics_device.h"

#include <arpa/inet.h>
#include <netinet/in.h>
#include <sys/socket.h>
#include <unistd.h>

#include <gtest/gtest.h>

#include <chrono>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <thread>

#include "engine/haptics/haptics_network.h"

namespace zona {
namespace {

TEST(HapticsDevice, ProfilesCarryLimits) {
  EXPECT_EQ(device_profile("touch").value().max_force, 3.3);
  EXPECT_EQ(device_profile("touch").value().max_stiffness, 400);
  EXPECT_EQ(device_profile("falcon").value().max_force, 8.0);
  EXPECT_EQ(device_profile("falcon").value().max_stiffness, 3000);
  EXPECT_EQ(device_profile("omega").value().max_force, 12.0);
  EXPECT_FALSE(device_profile("phantom9000").ok());
}

TEST(HapticsDevice, ScriptedConstantSpeedStopsAtMaxTravel) {
  ScriptedDeviceDef def;
  def.home = {0.01, 0, 0};
  def.direction = {0, 0, 1};
  def.speed = 0.02;
  def.max_travel = 0.01;
  auto d = make_scripted_device(device_profile("touch").value(), def);
  DeviceState s = d->update(0.25);
  EXPECT_NEAR(s.position.z, 0.005, 1e-15);
  EXPECT_NEAR(s.velocity.z, 0.02, 1e-15);
  s = d->update(1.0);
  EXPECT_NEAR(s.position.z, 0.01, 1e-15);
  EXPECT_EQ(s.velocity.z, 0.0);
  EXPECT_EQ(d->home().x, 0.01);
}

std::string temp_path(const char* name) {
  return (std::filesystem::temp_directory_path() /
          (std::string("zona_haptics_") + std::to_string(::getpid()) + name))
      .string();
}

TEST(HapticsDevice, ReplayInterpolatesRecordedSession) {
  const std::string path = temp_path("_replay.csv");
  {
    std::ofstream f(path);
    f << "t_s,x_m,y_m,z_m,fx_N,fy_N,fz_N,sample_age_ms\n"
         "0.5,0,0,0,0,0,0,1\n0.6,0.01,0,-0.002,0.1,0,0,1\n0.7,0.01,0,0,0,0,0,1\n";
  }
  auto d = make_replay_device(device_profile("touch").value(), path);
  ASSERT_TRUE(d.ok()) << d.error().message;
  // Session time 0 is the recording's first row.
  DeviceState s = (*d)->update(0.05);
  EXPECT_NEAR(s.position.x, 0.005, 1e-12);
  EXPECT_NEAR(s.position.z, -0.001, 1e-12);
  EXPECT_NEAR(s.velocity.x, 0.1, 1e-9);
  s = (*d)->update(5.0);
  EXPECT_NEAR(s.position.x, 0.01, 1e-15);
  std::filesystem::remove(path);
}

TEST(HapticsDevice, TrajectoryCsvErrorsNameLine) {
  const std::string path = temp_path("_bad.csv");
  {
    std::ofstream f(path);
    f << "t_s,x_m,y_m,z_m\n0,0,0,0\n0,1,1,1\n";
  }
  std::vector<double> t;
  std::vector<Vec3d> p;
  const Status s = read_trajectory_csv(path, t, p);
  ASSERT_FALSE(s.ok());
  EXPECT_NE(s.error().message.find(":3:"), std::string::npos) << s.error().message;
  EXPECT_FALSE(read_trajectory_csv(temp_path("_missing.csv"), t, p).ok());
  std::filesystem::remove(path);
}

TEST(HapticsDevice, NetworkMessagesRoundTrip) {
  HapticStateMessage m;
  m.sequence = 7;
  m.time = 1.25;
  m.position = {1, -2, 3};
  m.velocity = {0.5, 0, -0.5};
  unsigned char buf[kHapticStateBytes];
  encode_state(m, buf);
  HapticStateMessage r;
  ASSERT_TRUE(decode_state(buf, kHapticStateBytes, r));
  EXPECT_EQ(r.sequence, 7u);
  EXPECT_EQ(r.position.y, -2.0);
  EXPECT_EQ(r.velocity.z, -0.5);
  EXPECT_FALSE(decode_state(buf, kHapticStateBytes - 1, r));
  buf[0] ^= 1;
  EXPECT_FALSE(decode_state(buf, kHapticStateBytes, r));
  HapticForceMessage f;
  f.force = {0.1, 0.2, 0.3};
  f.flags = 1;
  unsigned char fb[kHapticForceBytes];
  encode_force(f, fb);
  HapticForceMessage g;
  ASSERT_TRUE(decode_force(fb, kHapticForceBytes, g));
  EXPECT_EQ(g.force.z, 0.3);
  EXPECT_EQ(g.flags, 1u);
}

TEST(HapticsDevice, NetworkBridgeOnLoopback) {
  auto made = make_network_device(device_profile("touch").value(), "127.0.0.1", 0);
  ASSERT_TRUE(made.ok()) << made.error().message;
  HapticDevice& d = **made;
  const int port = network_device_port(d);
  ASSERT_GT(port, 0);
  // A stand-in driver process: a plain UDP socket on loopback.
  const int fd = ::socket(AF_INET, SOCK_DGRAM, 0);
  ASSERT_GE(fd, 0);
  timeval tv{0, 200000};  // bounded wait for the reply
  ::setsockopt(fd, SOL_SOCKET, SO_RCVTIMEO, &tv, sizeof tv);
  sockaddr_in to{};
  to.sin_family = AF_INET;
  to.sin_port = htons(static_cast<uint16_t>(port));
  ::inet_pton(AF_INET, "127.0.0.1", &to.sin_addr);
  HapticStateMessage m;
  m.sequence = 1;
  m.position = {0.01, 0.02, 0.03};
  m.velocity = {0.1, 0, 0};
  unsigned char buf[kHapticStateBytes];
  encode_state(m, buf);
  ASSERT_EQ(::sendto(fd, buf, sizeof buf, 0, reinterpret_cast<sockaddr*>(&to), sizeof to),
            static_cast<ssize_t>(sizeof buf));
  // Bounded poll: the datagram is on loopback within a few ms.
  DeviceState s;
  for (int i = 0; i < 200 && s.position.x == 0; ++i) {
    s = d.update(0);
    if (s.position.x == 0) std::this_thread::sleep_for(std::chrono::milliseconds(1));
  }
  EXPECT_EQ(s.position.y, 0.02);
  EXPECT_EQ(s.velocity.x, 0.1);
  d.command({0.5, 0, -0.25}, 0.001);
  unsigned char in[128];
  const ssize_t n = ::recv(fd, in, sizeof in, 0);
  ASSERT_EQ(n, kHapticForceBytes);
  HapticForceMessage f;
  ASSERT_TRUE(decode_force(in, static_cast<int>(n), f));
  EXPECT_EQ(f.force.x, 0.5);
  EXPECT_EQ(f.force.z, -0.25);
  ::close(fd);
  EXPECT_FALSE(make_network_device(device_profile("touch").value(), "not-an-ip", 0).ok());
}

TEST(HapticsDevice, NetworkBridgeBindsOnlyLoopbackUnlessAllowed) {
  const DeviceInfo touch = device_profile("touch").value();
  EXPECT_TRUE(is_loopback_ipv4("127.0.0.1"));
  EXPECT_TRUE(is_loopback_ipv4("127.255.0.9"));
  EXPECT_FALSE(is_loopback_ipv4("0.0.0.0"));
  EXPECT_FALSE(is_loopback_ipv4("192.168.1.20"));
  EXPECT_FALSE(is_loopback_ipv4("128.0.0.1"));
  EXPECT_FALSE(is_loopback_ipv4("localhost"));  // names are not resolved
  // Any address off loopback is refused by default, naming the key and the address.
  for (const char* host : {"0.0.0.0", "192.168.1.20"}) {
    auto refused = make_network_device(touch, host, 0);
    ASSERT_FALSE(refused.ok()) << host;
    EXPECT_EQ(refused.error().message.rfind(std::string("haptics.network_host: '") + host +
                                                "' is not a loopback address",
                                            0),
              0u)
        << refused.error().message;
    EXPECT_NE(refused.error().message.find("--allow-remote-bridge"), std::string::npos);
  }
  // Other loopback addresses bind; so does the wildcard when allowed.
  auto loopback = make_network_device(touch, "127.0.0.2", 0);
  EXPECT_TRUE(loopback.ok()) << loopback.error().message;
  auto allowed = make_network_device(touch, "0.0.0.0", 0, /*allow_remote=*/true);
  ASSERT_TRUE(allowed.ok()) << allowed.error().message;
  EXPECT_GT(network_device_port(**allowed), 0);
}

TEST(HapticsDevice, PluginErrorsAreOneLine) {
  auto r = make_plugin_device("/nonexistent/libzona_driver.so", "");
  ASSERT_FALSE(r.ok());
  EXPECT_EQ(r.error().message.find('\n'), std::string::npos);
  // A real library without the symbols.
  auto c = make_plugin_device("libc.so.6", "");
  ASSERT_FALSE(c.ok());
  EXPECT_NE(c.error().message.find("missing zona_haptic_"), std::string::npos);
}

}  // namespace
}  // namespace zona
