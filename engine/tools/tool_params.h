// The tools as the injection step sees them: plain data (passed by value to kernels), SI units.
#pragma once

#include <cstdint>

#include "engine/core/base.h"
#include "engine/core/vec.h"

namespace zona {

/// The needle: a scripted straight insertion or path, or a pose handed in by the haptic thread.
struct NeedleParams {
  int32_t on = 0;        ///< the scene has a needle
  int32_t flat = 0;      ///< flat tip instead of the hemisphere
  /// The needle's pressure is integrated over the surface triangles (needle_face_force) instead
  /// of lumped at the vertices: the tip cannot pass between vertices that it pushes apart.
  int32_t on_faces = 0;
  Vec3d start{0, 0, 0};      ///< tip at t = 0 [m]
  Vec3d direction{1, 0, 0};  ///< unit direction of travel [-]
  double speed = 0;          ///< [m/s]
  double max_travel = 0;     ///< travel after which the tip stops [m]; 0: no limit
  /// A scripted path (needle.trajectory) instead of the straight insertion: path_count tip
  /// positions [m] at strictly increasing times [s], linear in between, held after the last.
  /// Host arrays on the CPU, device arrays on the GPU (the runner owns them); travel is still
  /// measured along `direction`.
  int32_t path_count = 0;
  const double* path_time = nullptr;
  const Vec3d* path_position = nullptr;
  /// A tip handed in by the haptic thread (set_tip) is followed at most at this speed [m/s],
  /// step by step on the stepping side: the host hands poses in batches (the GPU reads its
  /// mailbox every few steps), and a jump of a batch's travel in one step shakes the contact.
  /// 0: the handed-in tip is taken as it is.
  double external_tip_max_speed = 0;
  double radius = 0;              ///< tip and shaft radius [m]
  double pressure_stiffness = 0;  ///< contact pressure per penetration [Pa/m]
  double friction = 0;            ///< Coulomb coefficient [-]
  double stick_length = 0;        ///< friction's stick zone at least this wide (penalty.h) [m]
  /// Before puncture, a contact point deeper than this inside the needle means the surface let
  /// the tool through (the record stage halts: kStepToolBreach) [m]; 0: not checked.
  double breach_depth = 0;
};

/// The needle's scripted tip at time t [s] [m]: the path interpolated (linear between its
/// points, held before the first and after the last), else start + speed t direction, stopped
/// at max_travel. One function for the host's script (needle_tip_at) and the step's tool stage.
ZONA_HOST_DEVICE ZONA_INLINE Vec3d needle_scripted_tip(const NeedleParams& needle, double t) {
  const int32_t n = needle.path_count;
  if (n > 0) {
    const double* time = needle.path_time;
    const Vec3d* x = needle.path_position;
    if (!(t > time[0])) return x[0];
    if (!(t < time[n - 1])) return x[n - 1];
    int32_t lo = 0, hi = n - 1;  // time[lo] < t < time[hi]
    while (hi - lo > 1) {
      const int32_t mid = (lo + hi) / 2;
      if (time[mid] <= t) lo = mid; else hi = mid;
    }
    const double a = (t - time[lo]) / (time[hi] - time[lo]);
    return (1.0 - a) * x[lo] + a * x[hi];
  }
  double travel = needle.speed * (t > 0 ? t : 0.0);
  if (needle.max_travel > 0 && travel > needle.max_travel) travel = needle.max_travel;
  return needle.start + travel * needle.direction;
}

/// The holding pipette in suction mode: its rim as a contact tool, the suction ramped in.
struct RimParams {
  int32_t on = 0;            ///< the scene holds the cell by suction
  Vec3d mouth{0, 0, 0};      ///< [m]
  Vec3d axis{1, 0, 0};       ///< unit, from the cell into the pipette [-]
  double inner_radius = 0, outer_radius = 0;  ///< [m]
  double edge_radius = 0;    ///< rounding of the mouth's edges [m]
  double pressure_stiffness = 0;  ///< [Pa/m]
  double friction = 0;            ///< [-]
  double stick_length = 0;        ///< friction's stick zone at least this wide (penalty.h) [m]
  /// Normal damper of the contact as a fraction of each contact point's critical damping
  /// (rim_damper_coefficient) [-]; 0: an undamped spring.
  double damping = 0;
  double suction_ramp_time = 0;   ///< suction reaches full strength after this [s]
};

}  // namespace zona
