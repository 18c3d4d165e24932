// Window mode: a GLFW window with a Vulkan swapchain showing a running Simulation. The
// simulation steps on its own thread and publishes SceneSnapshots through a TripleBuffer
// (render/snapshot.h); the window's thread draws the newest one: neither waits for the other.
//
// Controls: drag with the left mouse button to orbit, scroll to zoom, Up/W and Down/S move the
// needle along its axis (with Shift: 5x faster; the first key press takes the needle from its
// script), C cycles the colour field, R resets the camera, Esc or Q closes.
//
// GLFW (libglfw.so.3) is opened at run time like the Vulkan loader: without it, or without a
// display, run_view_window returns an error and nothing else is affected.
#pragma once

#include <cstdint>
#include <string>

#include "engine/core/base.h"
#include "engine/sim/simulation.h"
#include "render/frame.h"
#include "render/renderer.h"

namespace zona {

/// How the window runs.
struct ViewOptions {
  int width = 1280;
  int height = 720;
  std::string title = "zona";
  bool validation = false;  ///< Khronos validation layer, messages counted
  ColorField field = ColorField::kDisplacement;
  double close_after = 0;              ///< close after this many wall-clock seconds; 0: never [s]
  double needle_key_speed = 5e-6;      ///< needle speed while a key is held, wall clock [m/s]
  double publish_interval = 1.0 / 60;  ///< wall-clock time between simulation snapshots [s]
};

/// What the window did.
struct ViewResult {
  int64_t frames = 0;  ///< frames presented
  ValidationReport validation;
};

/// Opens the window and runs `simulation` and the view until the window closes (or
/// close_after). Errors: no GLFW, no display, no Vulkan device able to present.
Status run_view_window(Simulation& simulation, const ViewOptions& options, ViewResult* result);

}  // namespace zona
