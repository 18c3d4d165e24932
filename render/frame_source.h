// From the engine's data to a RenderFrame: per-vertex fields (displacement magnitude, von Mises
// stress), tool poses and the overlay text of a Simulation, a default camera, and an analytic
// indentation for pictures and tests without a simulation.
#pragma once

#include <span>
#include <string>
#include <vector>

#include "engine/mesh/mesh.h"
#include "engine/sim/simulation.h"
#include "render/frame.h"

namespace zona {

/// |u| per vertex [m], (vertex_count).
void displacement_magnitude(std::span<const Vec3d> u, std::vector<float>* out);

/// Per-vertex von Mises stress [Pa], (vertex_count): the volume-weighted mean of the Cauchy
/// stress's von Mises value over the tetrahedra around each vertex (recorder.h's frame_fields).
void vertex_von_mises(const Simulation& simulation, std::vector<float>* out);

/// A camera that frames the mesh's bounding sphere from the default direction.
OrbitCamera default_camera(const Mesh& mesh, double fill = 0.62);

/// Parses "displacement", "stress", "none".
Result<ColorField> parse_color_field(const std::string& name);

/// Rates shown by the overlay.
struct OverlayRates {
  double simulation_hz = 0;  ///< simulation steps per wall-clock second [1/s]; 0: not shown
  double haptic_hz = 0;      ///< haptic loop rate [1/s]; 0: "no device"
  double render_hz = 0;      ///< frames per second; 0: not shown
};

/// The overlay lines for a needle report: time, needle force, travel, deformation, puncture.
std::vector<std::string> overlay_lines(const std::string& title, const NeedleReport& report,
                                       const OverlayRates& rates);

/// Arrays a RenderFrame built from a simulation points into; keep it alive while rendering.
struct SimulationFrameData {
  std::vector<Vec3d> displacement;  ///< [m], (vertex_count)
  std::vector<float> scalar;        ///< field [SI], (vertex_count)
};

/// Fills `frame` (and `data`) from the simulation's current state: rest positions, displacement,
/// boundary triangles, the field, the needle and holding pipette. Camera and overlay are left
/// as they are.
void frame_from_simulation(const Simulation& simulation, ColorField field,
                           SimulationFrameData* data, RenderFrame* frame);

/// Tool poses of a simulation at needle tip `tip` [m].
NeedlePose needle_pose(const Simulation& simulation, Vec3d tip);
HoldingPose holding_pose(const Simulation& simulation);

/// A smooth dimple: every vertex within `radius` [m] of `centre` [m] moves by
/// depth * (1 - (d / radius)^2)^2 along unit `direction` (an indentation for pictures and tests
/// of the renderer without a simulation), (vertex_count).
std::vector<Vec3d> indentation_field(std::span<const Vec3d> rest, Vec3d centre, Vec3d direction,
                                     double depth, double radius);

}  // namespace zona
