// The injection needle: a rigid micropipette (hemispherical or flat tip on a cylindrical shaft)
// whose tip follows a script (straight insertion at constant speed, or a trajectory file).
//
// Geometry: the tip advances along the unit axis d. A point or sphere tip is a hemisphere of
// radius R whose apex is the tip point; the shaft behind it is a cylinder of the same radius. A
// flat tip is a disk of radius R at the tip point on the same shaft. Ladjal et al. treats the tip as
// a point found by ray-triangle intersection; zona keeps that for the contact point and the
// deformation measure, and spreads the load over the hemisphere of `tip_radius` (the footprint),
// so that the force does not depend on which single vertex the point happens to hit
// (docs/injection.md).
#pragma once

#include <string>
#include <vector>

#include "engine/core/base.h"
#include "engine/scene/scene.h"
#include "engine/core/vec.h"

namespace zona {

/// Shape of the rigid needle (pose excluded).
struct NeedleGeometry {
  NeedleShape shape = NeedleShape::kPoint;
  double tip_radius = 1e-6;       ///< tip and shaft radius [m]
  Vec3d direction{1.0, 0.0, 0.0};  ///< unit direction of travel [-]
};

/// Distance of a point from a tool surface.
struct ToolDistance {
  double distance = 0;      ///< signed distance [m]: negative inside the tool
  Vec3d normal{0, 0, 0};    ///< unit outward normal of the tool at the closest surface point
};

/// Signed distance of `x` [m] from the needle whose tip point is `tip` [m], and the outward
/// normal of the closest surface point (pointing from the needle into the cell).
ToolDistance needle_distance(const NeedleGeometry& needle, Vec3d tip, Vec3d x);

/// The closest point on the needle surface to `x` [m] (x itself projected along the normal).
inline Vec3d project_to_surface(Vec3d x, const ToolDistance& d) { return x - d.distance * d.normal; }

/// A tip trajectory: tip positions over time, linearly interpolated, held at the last point.
struct NeedleTrajectory {
  std::vector<double> time;       ///< sample times [s], strictly increasing, (sample_count)
  std::vector<Vec3d> position;    ///< tip positions [m], (sample_count)
};

/// Reads a trajectory CSV: a header line `time_s,x_m,y_m,z_m` then one row per sample (times
/// strictly increasing, at least two rows, first time 0). Errors name the file and line.
Result<NeedleTrajectory> read_needle_trajectory(const std::string& path);

/// The scripted motion of the needle tip.
struct NeedleScript {
  Vec3d start{0, 0, 0};        ///< tip at t = 0 [m]
  Vec3d direction{1, 0, 0};    ///< unit direction of travel [-]
  double speed = 1e-4;         ///< insertion speed [m/s]
  double max_travel = 0;       ///< travel after which the tip stops [m]; 0: no limit
  NeedleTrajectory trajectory; ///< when not empty, replaces the straight insertion
};

/// Tip position at time t [s] [m]: start + speed t d (stopped at max_travel), or the
/// trajectory interpolated. Does not allocate.
Vec3d needle_tip_at(const NeedleScript& script, double t);

/// Time [s] at which the scripted motion ends: max_travel / speed, the trajectory's last
/// time, or 0 when unbounded.
double needle_script_end_time(const NeedleScript& script);

}  // namespace zona
