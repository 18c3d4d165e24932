// UDP network haptic device (non-blocking socket) and the dlopen plug-in device.
#include "engine/haptics/haptics_network.h"

#include <arpa/inet.h>
#include <dlfcn.h>
#include <fcntl.h>
#include <netinet/in.h>
#include <sys/socket.h>
#include <unistd.h>

#include <cerrno>
#include <cmath>
#include <cstring>

#include "engine/haptics/haptics_device.h"
#include "engine/haptics/haptics_plugin_abi.h"

namespace zona {
namespace {

template <class T>
void put(unsigned char*& p, T v) {
  std::memcpy(p, &v, sizeof v);
  p += sizeof v;
}
template <class T>
T get(const unsigned char*& p) {
  T v;
  std::memcpy(&v, p, sizeof v);
  p += sizeof v;
  return v;
}

}  // namespace

void encode_state(const HapticStateMessage& m, unsigned char out[kHapticStateBytes]) {
  unsigned char* p = out;
  put(p, kHapticStateMagic);
  put(p, m.sequence);
  put(p, m.time);
  for (int i = 0; i < 3; ++i) put(p, m.position[i]);
  for (int i = 0; i < 3; ++i) put(p, m.velocity[i]);
}

bool decode_state(const unsigned char* data, int size, HapticStateMessage& m) {
  if (size != kHapticStateBytes) return false;
  const unsigned char* p = data;
  if (get<uint32_t>(p) != kHapticStateMagic) return false;
  HapticStateMessage r;
  r.sequence = get<uint32_t>(p);
  r.time = get<double>(p);
  for (int i = 0; i < 3; ++i) r.position[i] = get<double>(p);
  for (int i = 0; i < 3; ++i) r.velocity[i] = get<double>(p);
  m = r;
  return true;
}

void encode_force(const HapticForceMessage& m, unsigned char out[kHapticForceBytes]) {
  unsigned char* p = out;
  put(p, kHapticForceMagic);
  put(p, m.sequence);
  put(p, m.time);
  for (int i = 0; i < 3; ++i) put(p, m.force[i]);
  put(p, m.flags);
  put(p, uint32_t{0});
}

bool decode_force(const unsigned char* data, int size, HapticForceMessage& m) {
  if (size != kHapticForceBytes) return false;
  const unsigned char* p = data;
  if (get<uint32_t>(p) != kHapticForceMagic) return false;
  HapticForceMessage r;
  r.sequence = get<uint32_t>(p);
  r.time = get<double>(p);
  for (int i = 0; i < 3; ++i) r.force[i] = get<double>(p);
  r.flags = get<uint32_t>(p);
  m = r;
  return true;
}

namespace {

class NetworkDevice final : public HapticDevice {
 public:
  NetworkDevice(const DeviceInfo& info, int fd) : info_(info), fd_(fd) {}
  ~NetworkDevice() override { ::close(fd_); }
  const DeviceInfo& info() const override { return info_; }
  int fd() const { return fd_; }

  DeviceState update(double) override {
    // Drain everything that arrived; keep the newest valid state (bounded by the queue).
    unsigned char buffer[256];
    for (int i = 0; i < 1024; ++i) {
      sockaddr_in from{};
      socklen_t from_len = sizeof from;
      const ssize_t n = ::recvfrom(fd_, buffer, sizeof buffer, 0,
                                   reinterpret_cast<sockaddr*>(&from), &from_len);
      if (n < 0) break;  // EAGAIN: nothing more
      HapticStateMessage m;
      if (!decode_state(buffer, static_cast<int>(n), m)) continue;
      if (!std::isfinite(m.position.x + m.position.y + m.position.z)) continue;
      state_.position = m.position;
      state_.velocity = m.velocity;
      peer_ = from;
      have_peer_ = true;
    }
    return state_;
  }

  void command(Vec3d force, double time) override {
    if (!have_peer_) return;
    HapticForceMessage m;
    m.sequence = ++sequence_;
    m.time = time;
    m.force = force;
    unsigned char out[kHapticForceBytes];
    encode_force(m, out);
    // Non-blocking: a full socket buffer drops this tick's force (the next one follows).
    (void)::sendto(fd_, out, sizeof out, 0, reinterpret_cast<const sockaddr*>(&peer_),
                   sizeof peer_);
  }

 private:
  DeviceInfo info_;
  int fd_;
  DeviceState state_;
  sockaddr_in peer_{};
  bool have_peer_ = false;
  uint32_t sequence_ = 0;
};

class PluginDevice final : public HapticDevice {
 public:
  using ReadFn = int (*)(void*, double, double*, double*);
  using WriteFn = int (*)(void*, double, const double*);
  using CloseFn = void (*)(void*);
  PluginDevice(void* library, void* handle, ReadFn r, WriteFn w, CloseFn c, DeviceInfo info)
      : library_(library), handle_(handle), read_(r), write_(w), close_(c), info_(info) {}
  ~PluginDevice() override {
    close_(handle_);
    ::dlclose(library_);
  }
  const DeviceInfo& info() const override { return info_; }
  DeviceState update(double time) override {
    double p[3], v[3];
    if (read_(handle_, time, p, v) == 0) {
      state_.position = {p[0], p[1], p[2]};
      state_.velocity = {v[0], v[1], v[2]};
    }
    return state_;
  }
  void command(Vec3d force, double time) override {
    const double f[3] = {force.x, force.y, force.z};
    (void)write_(handle_, time, f);
  }

 private:
  void* library_;
  void* handle_;
  ReadFn read_;
  WriteFn write_;
  CloseFn close_;
  DeviceInfo info_;
  DeviceState state_;
};

}  // namespace

bool is_loopback_ipv4(const std::string& host) {
  in_addr a{};
  return ::inet_pton(AF_INET, host.c_str(), &a) == 1 && (ntohl(a.s_addr) >> 24) == 127;
}

Result<std::unique_ptr<HapticDevice>> make_network_device(const DeviceInfo& info,
                                                          const std::string& host, int port,
                                                          bool allow_remote) {
  if (port < 0 || port > 65535)
    return make_error("haptics.network_port: %d is not a UDP port", port);
  sockaddr_in address{};
  address.sin_family = AF_INET;
  address.sin_port = htons(static_cast<uint16_t>(port));
  if (::inet_pton(AF_INET, host.c_str(), &address.sin_addr) != 1)
    return make_error("haptics.network_host: '%s' is not an IPv4 address", host.c_str());
  // Nothing authenticates the datagrams: off loopback, any machine that reaches the port moves
  // the needle and reads the forces, so a scene file alone cannot open it.
  if (!allow_remote && !is_loopback_ipv4(host))
    return make_error("haptics.network_host: '%s' is not a loopback address (127.0.0.0/8); "
                      "binding it lets other machines drive the needle: allow it with "
                      "zona haptics --allow-remote-bridge",
                      host.c_str());
  const int fd = ::socket(AF_INET, SOCK_DGRAM | SOCK_NONBLOCK | SOCK_CLOEXEC, 0);
  if (fd < 0) return make_error("network device: socket: %s", std::strerror(errno));
  if (::bind(fd, reinterpret_cast<sockaddr*>(&address), sizeof address) != 0) {
    const int e = errno;
    ::close(fd);
    return make_error("network device: bind %s:%d: %s", host.c_str(), port, std::strerror(e));
  }
  return std::unique_ptr<HapticDevice>(std::make_unique<NetworkDevice>(info, fd));
}

int network_device_port(const HapticDevice& device) {
  const auto* net = dynamic_cast<const NetworkDevice*>(&device);
  if (!net) return -1;
  sockaddr_in address{};
  socklen_t len = sizeof address;
  if (::getsockname(net->fd(), reinterpret_cast<sockaddr*>(&address), &len) != 0) return -1;
  return ntohs(address.sin_port);
}

Result<std::unique_ptr<HapticDevice>> make_plugin_device(const std::string& library_path,
                                                         const std::string& config) {
  void* lib = ::dlopen(library_path.c_str(), RTLD_NOW | RTLD_LOCAL);
  if (!lib) return make_error("haptic plug-in: %s", ::dlerror());
  auto sym = [&](const char* name) { return ::dlsym(lib, name); };
  using VersionFn = int (*)();
  using OpenFn = void* (*)(const char*, ZonaHapticInfo*);
  auto version = reinterpret_cast<VersionFn>(sym("zona_haptic_abi_version"));
  auto open = reinterpret_cast<OpenFn>(sym("zona_haptic_open"));
  auto read = reinterpret_cast<PluginDevice::ReadFn>(sym("zona_haptic_read"));
  auto write = reinterpret_cast<PluginDevice::WriteFn>(sym("zona_haptic_write"));
  auto close = reinterpret_cast<PluginDevice::CloseFn>(sym("zona_haptic_close"));
  if (!version || !open || !read || !write || !close) {
    ::dlclose(lib);
    return make_error("haptic plug-in %s: missing zona_haptic_* symbols", library_path.c_str());
  }
  if (version() != ZONA_HAPTIC_ABI_VERSION) {
    const int v = version();
    ::dlclose(lib);
    return make_error("haptic plug-in %s: ABI version %d, expected %d", library_path.c_str(), v,
                      ZONA_HAPTIC_ABI_VERSION);
  }
  ZonaHapticInfo raw{};
  void* handle = open(config.c_str(), &raw);
  if (!handle) {
    ::dlclose(lib);
    return make_error("haptic plug-in %s: open failed", library_path.c_str());
  }
  DeviceInfo info;
  raw.name[sizeof raw.name - 1] = 0;
  info.name = raw.name;
  info.max_force = raw.max_force;
  info.max_stiffness = raw.max_stiffness;
  info.max_damping = raw.max_damping;
  info.impedance = {raw.mass, raw.damping};
  return std::unique_ptr<HapticDevice>(
      std::make_unique<PluginDevice>(lib, handle, read, write, close, info));
}

}  // namespace zona
