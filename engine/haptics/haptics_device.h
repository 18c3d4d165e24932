// Haptic devices behind one interface (position and velocity in, force out, device limits):
// scripted, emulated (a hand model), replay (a recorded session), network (UDP bridge to an
// external driver process) and a plug-in seam (a shared library with a C ABI, see
// engine/haptics/haptics_plugin_abi.h).
#pragma once

#include <memory>
#include <string>
#include <vector>

#include "engine/core/base.h"
#include "engine/haptics/haptics_coupling.h"
#include "engine/core/vec.h"

namespace zona {

/// What a device can do. Limits after CHAI3D's device descriptions; the impedance (mass,
/// damping) values are nominal estimates used for the coupling gains (docs/haptics.md).
struct DeviceInfo {
  std::string name;             ///< "touch", "falcon", "omega", ...
  double max_force = 3.3;       ///< continuous force limit [N]
  double max_stiffness = 400;   ///< stiffness limit [N/m]
  double max_damping = 3.0;     ///< damping limit [N*s/m]
  DeviceImpedance impedance;    ///< mass [kg], physical damping [N*s/m]
};

/// Profiles: "touch" (3.3 N, 400 N/m), "falcon" (8 N, 3000 N/m), "omega" (12 N, 14500 N/m).
Result<DeviceInfo> device_profile(const std::string& name);

/// Device position and velocity at one instant (device frame) [m], [m/s].
struct DeviceState {
  Vec3d position{0, 0, 0};
  Vec3d velocity{0, 0, 0};
};

/// One haptic device. update() and command() are called from the haptic thread only and must
/// not allocate or block (the network device polls a non-blocking socket).
class HapticDevice {
 public:
  virtual ~HapticDevice() = default;
  virtual const DeviceInfo& info() const = 0;
  /// Position and velocity at haptic-clock time `time` [s] (monotonic, from 0).
  virtual DeviceState update(double time) = 0;
  /// Force to hold on the handle until the next command [N].
  virtual void command(Vec3d force, double time) = 0;
  /// Device position at time 0 (the origin the workspace mapping starts from) [m].
  virtual Vec3d home() const { return {0, 0, 0}; }
};

/// Constant-speed insertion: home + speed * t along `direction` (or a trajectory).
struct ScriptedDeviceDef {
  Vec3d home{0, 0, 0};         ///< [m]
  Vec3d direction{1, 0, 0};    ///< unit [-]
  double speed = 0.02;         ///< [m/s]
  double max_travel = 0.05;    ///< [m]; the handle stops there
  /// Optional trajectory: times [s] and positions [m], linear in between, held after the end.
  std::vector<double> times;
  std::vector<Vec3d> positions;
};

/// Reads "t_s,x_m,y_m,z_m" rows (header line first; extra columns ignored) into a trajectory.
/// Used by the scripted device's trajectory file and by replay (whose input is a session log).
Status read_trajectory_csv(const std::string& path, std::vector<double>& times,
                           std::vector<Vec3d>& positions);

/// A hand model: the operator is a mass-spring-damper tracking a target insertion path,
/// holding the device (its mass and damping), feeling the rendered force. Integrated with
/// sub-steps between updates, the force held constant in between (zero-order hold).
struct EmulatedHandDef {
  Vec3d home{0, 0, 0};       ///< [m]
  Vec3d direction{1, 0, 0};  ///< target path direction, unit [-]
  double speed = 0.02;       ///< target path speed [m/s]
  double max_travel = 0.05;  ///< target stops after this travel [m]
  double hand_mass = 0.3;    ///< [kg]
  double hand_stiffness = 300;  ///< grip/arm tracking stiffness [N/m]
  double hand_damping = 4;   ///< [N*s/m]
  int substeps = 20;         ///< integration sub-steps per update (>= 1)
};

/// The available devices.
std::unique_ptr<HapticDevice> make_scripted_device(const DeviceInfo& info,
                                                   const ScriptedDeviceDef& def);
std::unique_ptr<HapticDevice> make_emulated_device(const DeviceInfo& info,
                                                   const EmulatedHandDef& def);
/// Replays a recorded session (a `zona haptics --log` file or any t_s,x_m,y_m,z_m CSV).
Result<std::unique_ptr<HapticDevice>> make_replay_device(const DeviceInfo& info,
                                                         const std::string& path);
/// UDP bridge: binds `host`:`port` (port 0: any free port) and talks to the driver process that
/// sends state datagrams there (protocol in engine/haptics/haptics_network.h). Whoever can reach the
/// port drives the needle and reads the forces, unauthenticated: `host` must be a loopback
/// address (127.0.0.0/8) unless `allow_remote` (zona haptics --allow-remote-bridge); otherwise
/// an error naming haptics.network_host and the address.
Result<std::unique_ptr<HapticDevice>> make_network_device(const DeviceInfo& info,
                                                          const std::string& host, int port,
                                                          bool allow_remote = false);
/// True for an IPv4 address in 127.0.0.0/8 written as make_network_device reads it.
bool is_loopback_ipv4(const std::string& host);
/// The UDP port a network device is bound to (-1 for other devices).
int network_device_port(const HapticDevice& device);
/// Native driver loaded at run time from a shared library (engine/haptics/haptics_plugin_abi.h).
Result<std::unique_ptr<HapticDevice>> make_plugin_device(const std::string& library_path,
                                                         const std::string& config);

}  // namespace zona
