// The UDP message format between zona and an external device driver process (OpenHaptics,
// Force Dimension SDK, libnifalcon bridges). Loopback by default. All fields little-endian,
// packed, no padding; one message per datagram.
//
//   driver -> zona, "state" (64 bytes), sent once per device tick to zona's port:
//     u32 magic 'ZHS1' (0x3153485A) | u32 sequence | f64 time_s (driver clock) |
//     f64 x_m, y_m, z_m | f64 vx_mps, vy_mps, vz_mps
//   zona -> driver, "force" (48 bytes), sent each haptic tick to the address the last state
//   came from:
//     u32 magic 'ZHF1' (0x3146485A) | u32 sequence (zona's tick) | f64 time_s (zona clock) |
//     f64 fx_N, fy_N, fz_N | u32 flags (bit 0: emergency stop, bit 1: force faded) | u32 0
//
// zona never blocks on the socket: each tick drains what has arrived and keeps the newest
// state; a driver that stops sending leaves the last state in place (zona's stall fade covers
// the simulation side, the driver must zero its own force on silence).
#pragma once

#include <cstdint>
#include <cstring>

#include "engine/core/vec.h"

namespace zona {

inline constexpr uint32_t kHapticStateMagic = 0x3153485Au;  // "ZHS1" little-endian
inline constexpr uint32_t kHapticForceMagic = 0x3146485Au;  // "ZHF1" little-endian
inline constexpr int kHapticStateBytes = 64;
inline constexpr int kHapticForceBytes = 48;

/// Device state as sent by the driver.
struct HapticStateMessage {
  uint32_t sequence = 0;
  double time = 0;            ///< driver clock [s]
  Vec3d position{0, 0, 0};    ///< [m]
  Vec3d velocity{0, 0, 0};    ///< [m/s]
};

/// Force as sent by zona.
struct HapticForceMessage {
  uint32_t sequence = 0;
  double time = 0;            ///< zona's haptic clock [s]
  Vec3d force{0, 0, 0};       ///< [N]
  uint32_t flags = 0;         ///< bit 0: emergency stop, bit 1: faded
};

/// Encoders/decoders (the host must be little-endian, which every supported target is).
void encode_state(const HapticStateMessage& m, unsigned char out[kHapticStateBytes]);
bool decode_state(const unsigned char* data, int size, HapticStateMessage& m);
void encode_force(const HapticForceMessage& m, unsigned char out[kHapticForceBytes]);
bool decode_force(const unsigned char* data, int size, HapticForceMessage& m);

}  // namespace zona
