// What the renderer draws: plain structs filled by the caller (the simulation driver, a test,
// the CLI) and read by Renderer::render. Physical values in SI; the renderer converts.
#pragma once

#include <cstdint>
#include <span>
#include <string>
#include <vector>

#include "engine/mesh/mesh.h"
#include "engine/core/vec.h"

namespace zona {

/// The field shown by the colour map (and named in the legend).
enum class ColorField {
  kNone,          ///< flat cell colour, no legend
  kDisplacement,  ///< displacement magnitude |u| [m]
  kStress,        ///< von Mises stress [Pa]
};

/// Orbit camera: the eye sits on a sphere around `target`.
struct OrbitCamera {
  Vec3d target{0, 0, 0};     ///< point looked at [m]
  double distance = 150e-6;  ///< eye to target [m]
  double yaw_deg = -40;      ///< rotation of the eye about +y; 0: eye on +z [deg]
  double pitch_deg = 20;     ///< elevation of the eye above the x-z plane, (-89, 89) [deg]
  double fov_y_deg = 35;     ///< vertical field of view [deg]
};

/// A camera that shows a sphere of `radius` [m] around `centre` [m] filling `fill` of the
/// view's height, from the given direction.
OrbitCamera fit_camera(Vec3d centre, double radius, double fill = 0.75, double yaw_deg = -40,
                       double pitch_deg = 20, double fov_y_deg = 35);

/// Turns the camera about its target [deg]; pitch is kept within (-89, 89).
void orbit_camera(OrbitCamera* camera, double yaw_deg, double pitch_deg);

/// Eye position of the camera [m].
Vec3d camera_eye(const OrbitCamera& camera);

/// The injection pipette: a hemispherical (or flat) tip on a cylindrical shaft.
struct NeedlePose {
  bool visible = false;
  Vec3d tip{0, 0, 0};        ///< tip point [m]
  Vec3d direction{1, 0, 0};  ///< unit direction of travel (from the shaft to the tip) [-]
  double tip_radius = 1e-6;  ///< tip and shaft radius [m]
  bool flat_tip = false;     ///< a blunt disc instead of a hemisphere
  double length = 0;         ///< drawn shaft length [m]; 0: long enough to leave the view
};

/// The holding pipette: a tube whose mouth touches the cell.
struct HoldingPose {
  bool visible = false;
  Vec3d mouth{0, 0, 0};           ///< centre of the mouth [m]
  Vec3d axis{1, 0, 0};            ///< unit vector from the cell into the pipette [-]
  double inner_radius = 10e-6;    ///< bore radius [m]
  double outer_radius = 12.5e-6;  ///< outer radius of the wall [m] (> inner_radius)
  double length = 0;              ///< drawn length [m]; 0: long enough to leave the view
};

/// One frame's input. Spans point into the caller's arrays, which must outlive the call.
struct RenderFrame {
  std::span<const Vec3d> rest;          ///< rest positions [m], (vertex_count)
  std::span<const Vec3d> displacement;  ///< displacement [m], (vertex_count); empty: at rest
  std::span<const Triangle> triangles;  ///< boundary triangles, outward CCW, (triangle_count)
  /// Per-vertex field for the colour map, in the field's SI unit, (vertex_count); empty: none.
  std::span<const float> scalar;
  ColorField field = ColorField::kNone;
  bool auto_range = true;  ///< colour range from the scalar's min and max
  double scalar_min = 0;   ///< colour range when !auto_range, in the field's SI unit
  double scalar_max = 1;
  /// Draw the cell from the renderer's shared surface (Renderer::create_shared_surface), which
  /// the CUDA backend has written for this frame's camera (kernels/surface_interop.h): `rest`,
  /// `displacement`, `triangles` and `scalar` are not read, and the colour range is always
  /// [scalar_min, scalar_max] (the writer returns the field's range).
  bool shared_surface = false;
  NeedlePose needle;
  HoldingPose holding;
  std::vector<std::string> overlay_lines;  ///< text at the top left, one line each
  OrbitCamera camera;
  Vec3f cell_color{0.86f, 0.74f, 0.62f};     ///< sRGB colour without a colour map [-]
  Vec3f background{0.075f, 0.085f, 0.105f};  ///< sRGB clear colour [-]
};

/// RGBA8 pixels, rows top to bottom, sRGB.
struct PixelImage {
  int width = 0;
  int height = 0;
  std::vector<uint8_t> rgba;  ///< (height x width x 4)
};

}  // namespace zona
