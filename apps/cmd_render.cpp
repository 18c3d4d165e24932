// `zona render` (simulate a scene up to a time, then render one frame or a sequence to PNG,
// headless) and `zona view` (simulation and rendering together in a window).
//
// This file compiles with and without the Vulkan renderer: without it (ZONA_HAVE_VULKAN unset,
// zona_render not built) both commands exist and answer "built without the Vulkan renderer",
// so scripts get a clear one-line error instead of an unknown command.
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <memory>
#include <string>
#include <vector>

#include "apps/commands.h"
#include "engine/scene/scene.h"
#include "engine/sim/simulation.h"
#include "engine/core/units.h"
#include "kernels/backend_factory.h"
#include "kernels/surface_interop.h"

#if defined(ZONA_HAVE_VULKAN)
#include "render/frame_source.h"
#include "render/interop.h"
#include "render/renderer.h"
#include "render/window.h"
#endif

namespace zona::cli {
namespace {

struct RenderArgs {
  std::string scene;
  std::vector<std::string> sets;
  std::string out;
  std::string frames_dir;
  int frame_count = 10;
  int width = 1280;
  int height = 720;
  int samples = 4;
  std::string time = "0";
  std::string color = "displacement";
  double yaw = -40, pitch = 20, zoom = 1;
  double close_after = 0;
  bool validate = false;
  std::string backend = "cpu";
  bool copy_path = false;
};

#if defined(ZONA_HAVE_VULKAN)

// The scene's simulation; its setup notes (e.g. the backend it fell back to) go to stderr as
// `zona COMMAND: note: ...`, as `zona run` prints them.
Result<std::unique_ptr<Simulation>> make_simulation(const RenderArgs& args, Scene* scene_out,
                                                    const char* command) {
  Result<std::string> path = find_scene_file(args.scene);
  if (!path.ok()) return path.error();
  Result<Scene> scene = load_scene(*path, args.sets);
  if (!scene.ok()) return scene.error();
  *scene_out = *scene;
  Result<BackendKind> kind = parse_backend_kind(args.backend);
  if (!kind.ok()) return make_error("--backend: %s", kind.error().message.c_str());
  SimulationOptions options;
  if (*kind != BackendKind::kCpu) {
    const BackendKind k = *kind;
    options.backend_factory = [k](std::string* notice) {
      return make_backend(k, BackendOptions{}, notice);
    };
  }
  Result<std::unique_ptr<Simulation>> sim = Simulation::create(*scene, options);
  if (sim.ok())
    for (const std::string& note : (*sim)->notes())
      std::fprintf(stderr, "zona %s: note: %s\n", command, note.c_str());
  return sim;
}

// CUDA-Vulkan interop (docs/rendering.md): when the simulation runs on the CUDA backend, its
// surface is written straight into the renderer's memory; otherwise frames take the copy path.
struct InteropPath {
  SharedSurface shared;
  std::unique_ptr<SurfaceWriter> writer;

  // Sets up the writer when it can: a simulation on the CPU or a stress colour map (computed on
  // the CPU) quietly keep the copy path; any other reason is said on one line.
  void setup(const Simulation& s, ColorField field, Renderer& renderer) {
    if (!s.backend() || field == ColorField::kStress) return;
    Result<SharedSurface> made =
        renderer.create_shared_surface(s.surface().triangles, s.mesh().vertex_count());
    if (!made.ok()) return notice(made.error().message);
    shared = std::move(made).value();
    Result<std::unique_ptr<SurfaceWriter>> w =
        make_surface_writer(*s.backend(), s.model(), shared_surface_target(shared));
    if (!w.ok()) return notice(w.error().message);
    writer = std::move(w).value();
  }

  // Writes the surface for `frame`'s camera and marks the frame to draw it (no-op without a
  // writer: the frame keeps the arrays frame_from_simulation filled).
  Status apply(const Simulation& s, ColorField field, RenderFrame* frame) {
    if (!writer) return {};
    Vec3d origin;
    double scale = 1;
    camera_render_space(frame->camera, &origin, &scale);
    Result<SurfaceWriteResult> w = writer->write(
        *s.backend(), origin, scale,
        field == ColorField::kDisplacement ? SurfaceScalar::kDisplacement : SurfaceScalar::kNone);
    if (!w.ok()) return w.error();
    frame->shared_surface = true;
    frame->scalar_min = w->scalar_min;
    frame->scalar_max = w->scalar_max;
    return {};
  }

  static void notice(const std::string& why) {
    std::fprintf(stderr, "zona: CUDA-Vulkan interop unavailable (%s): using the copy path\n",
                 why.c_str());
  }
};

// Steps until the simulated time reaches `time` [s] or the experiment ends.
void advance(Simulation& sim, double time) {
  while (sim.report().time < time && !sim.finished()) sim.step();
}

// The validation verdict: any error or warning fails, messages go to stderr.
bool validation_clean(const ValidationReport& v) {
  if (!v.enabled) return true;
  for (const std::string& m : v.messages)
    std::fprintf(stderr, "zona: vulkan validation %s\n", m.c_str());
  if (v.errors + v.warnings == 0) return true;
  fail("Vulkan validation reported " + std::to_string(v.errors) + " error(s) and " +
       std::to_string(v.warnings) + " warning(s)");
  return false;
}

// --time: a bare number is seconds, else a quantity with a unit ("2ms").
Result<double> parse_time(const std::string& text) {
  char* end = nullptr;
  const double seconds = std::strtod(text.c_str(), &end);
  if (end && end != text.c_str() && *end == '\0') {
    if (!(seconds >= 0)) return make_error("\"%s\": expected a time >= 0", text.c_str());
    return seconds;
  }
  return parse_quantity(text, dim::kTime);
}

void run_render(const RenderArgs& args) {
  Result<double> time = parse_time(args.time);
  if (!time.ok()) return fail("--time: " + time.error().message);
  Result<ColorField> field = parse_color_field(args.color);
  if (!field.ok()) return fail("--color: " + field.error().message);
  if (args.out.empty() && args.frames_dir.empty()) return fail("render: give --out or --frames");
  Scene scene;
  Result<std::unique_ptr<Simulation>> sim = make_simulation(args, &scene, "render");
  if (!sim.ok()) return fail(sim.error().message);
  Simulation& s = **sim;

  RendererOptions options;
  options.validation = args.validate;
  options.samples = args.samples;
  options.external_memory = !args.copy_path;
  Result<Renderer> renderer = create_headless_renderer(args.width, args.height, options);
  if (!renderer.ok()) return fail(renderer.error().message);
  InteropPath interop;
  if (!args.copy_path) interop.setup(s, *field, *renderer);

  OrbitCamera camera = default_camera(s.mesh());
  camera.yaw_deg = args.yaw;
  camera.pitch_deg = args.pitch;
  camera.distance /= args.zoom > 0 ? args.zoom : 1.0;
  SimulationFrameData data;
  RenderFrame frame;
  frame.camera = camera;
  const auto wall_start = std::chrono::steady_clock::now();
  auto draw = [&](const std::string& path, FrameSequence* sequence) -> Status {
    frame_from_simulation(s, *field, &data, &frame);
    const double wall =
        std::chrono::duration<double>(std::chrono::steady_clock::now() - wall_start).count();
    OverlayRates rates;
    rates.simulation_hz =
        wall > 0 && s.report().step > 0 ? static_cast<double>(s.report().step) / wall : 0;
    frame.overlay_lines = overlay_lines(scene.name, s.report(), rates);
    if (Status st = interop.apply(s, *field, &frame); !st.ok()) return st;
    return sequence ? sequence->write(frame) : renderer->render_to_png(frame, path);
  };

  if (!args.frames_dir.empty()) {
    // A sequence: frame_count frames evenly spaced over [0, time].
    FrameSequence sequence(&*renderer, args.frames_dir);
    const int n = std::max(1, args.frame_count);
    for (int i = 0; i < n; ++i) {
      advance(s, n == 1 ? *time : *time * i / (n - 1));
      if (Status st = draw("", &sequence); !st.ok()) return fail(st.error().message);
    }
    std::printf("wrote %d frames to %s (t = %.4g s, %s)\n", sequence.count(),
                args.frames_dir.c_str(), s.report().time, renderer->device_name().c_str());
  }
  if (!args.out.empty()) {
    advance(s, *time);
    if (Status st = draw(args.out, nullptr); !st.ok()) return fail(st.error().message);
    std::printf("wrote %s (%dx%d, t = %.4g s, %lld steps, %s, %s path)\n", args.out.c_str(),
                args.width, args.height, s.report().time,
                static_cast<long long>(s.report().step), renderer->device_name().c_str(),
                interop.writer ? "interop" : "copy");
  }
  validation_clean(renderer->validation());
}

void run_view(const RenderArgs& args) {
  Result<ColorField> field = parse_color_field(args.color);
  if (!field.ok()) return fail("--color: " + field.error().message);
  Scene scene;
  Result<std::unique_ptr<Simulation>> sim = make_simulation(args, &scene, "view");
  if (!sim.ok()) return fail(sim.error().message);
  ViewOptions options;
  options.width = args.width;
  options.height = args.height;
  options.validation = args.validate;
  options.field = *field;
  options.title = "zona view: " + scene.name;
  options.close_after = args.close_after;
  ViewResult result;
  if (Status st = run_view_window(**sim, options, &result); !st.ok())
    return fail(st.error().message);
  std::printf("view closed after %lld frames (t = %.4g s, %lld steps)\n",
              static_cast<long long>(result.frames), (*sim)->report().time,
              static_cast<long long>((*sim)->report().step));
  validation_clean(result.validation);
}

}  // namespace

Result<PngFrameWriter> make_png_frame_writer(const Simulation& simulation,
                                             const std::string& directory, const std::string& color,
                                             int width, int height) {
  Result<ColorField> field = parse_color_field(color);
  if (!field.ok()) return field.error();
  RendererOptions options;
  options.external_memory = true;  // for interop; ignored where the device lacks it
  Result<Renderer> created = create_headless_renderer(width, height, options);
  if (!created.ok()) return created.error();
  // Shared state of the returned function: the renderer, the sequence and the frame arrays.
  struct Writer {
    Renderer renderer;
    std::unique_ptr<FrameSequence> sequence;
    SimulationFrameData data;
    RenderFrame frame;
    ColorField field;
    InteropPath interop;
    std::chrono::steady_clock::time_point start = std::chrono::steady_clock::now();
  };
  auto w = std::make_shared<Writer>();
  w->renderer = std::move(*created);
  w->sequence = std::make_unique<FrameSequence>(&w->renderer, directory);
  w->field = *field;
  w->frame.camera = default_camera(simulation.mesh());
  w->interop.setup(simulation, w->field, w->renderer);
  return PngFrameWriter([w](const Simulation& s) -> Status {
    frame_from_simulation(s, w->field, &w->data, &w->frame);
    if (Status st = w->interop.apply(s, w->field, &w->frame); !st.ok()) return st;
    const double wall =
        std::chrono::duration<double>(std::chrono::steady_clock::now() - w->start).count();
    OverlayRates rates;
    rates.simulation_hz = wall > 0 ? static_cast<double>(s.report().step) / wall : 0;
    w->frame.overlay_lines = overlay_lines(s.scene().name, s.report(), rates);
    return w->sequence->write(w->frame);
  });
}

namespace {

#else

}  // namespace

Result<PngFrameWriter> make_png_frame_writer(const Simulation&, const std::string&,
                                             const std::string&, int, int) {
  return make_error("PNG frames: built without the Vulkan renderer");
}

namespace {

void run_render(const RenderArgs&) {
  fail("render: built without the Vulkan renderer");
}
void run_view(const RenderArgs&) {
  fail("view: built without the Vulkan renderer");
}

#endif

}  // namespace

void add_render_commands(CLI::App& app) {
  {
    auto args = std::make_shared<RenderArgs>();
    auto* cmd = app.add_subcommand("render", "Simulate a scene up to --time, then render to PNG");
    cmd->add_option("SCENE", args->scene, "Scene file or name (mouse_oocyte)")->required();
    cmd->add_option("--set", args->sets, "Override a scene key: key.path=value");
    cmd->add_option("--out", args->out, "PNG file of the frame at --time");
    cmd->add_option("--frames", args->frames_dir,
                    "Folder for a sequence frame_00000.png ... over [0, --time]");
    cmd->add_option("--frame-count", args->frame_count, "Frames of the sequence")
        ->check(CLI::Range(1, 100000));
    cmd->add_option("--width", args->width, "Image width [px]")->check(CLI::Range(16, 16384));
    cmd->add_option("--height", args->height, "Image height [px]")->check(CLI::Range(16, 16384));
    cmd->add_option("--time", args->time, "Simulated time, seconds or with a unit (2ms)");
    cmd->add_option("--color", args->color, "Colour map: displacement, stress or none");
    cmd->add_option("--samples", args->samples, "MSAA samples (1, 2, 4, 8)");
    cmd->add_option("--yaw", args->yaw, "Camera yaw about +y [deg]");
    cmd->add_option("--pitch", args->pitch, "Camera elevation [deg]");
    cmd->add_option("--zoom", args->zoom, "Camera zoom factor (> 1: closer)");
    cmd->add_flag("--validate", args->validate,
                  "Enable the Khronos validation layer; any message fails the command");
    cmd->add_option("--backend", args->backend, "Compute backend: auto, cpu or cuda");
    cmd->add_flag("--copy-path", args->copy_path,
                  "Always copy the surface through the host (by default the CUDA backend writes "
                  "it straight into Vulkan memory when it can)");
    cmd->callback([args] { run_render(*args); });
  }
  {
    auto args = std::make_shared<RenderArgs>();
    auto* cmd = app.add_subcommand("view", "Run a scene in a window (keys move the needle)");
    cmd->add_option("SCENE", args->scene, "Scene file or name (mouse_oocyte)")->required();
    cmd->add_option("--set", args->sets, "Override a scene key: key.path=value");
    cmd->add_option("--width", args->width, "Window width [px]")->check(CLI::Range(16, 16384));
    cmd->add_option("--height", args->height, "Window height [px]")->check(CLI::Range(16, 16384));
    cmd->add_option("--color", args->color, "Colour map: displacement, stress or none");
    cmd->add_flag("--validate", args->validate,
                  "Enable the Khronos validation layer; any message fails the command");
    cmd->add_option("--close-after", args->close_after,
                    "Close the window after this many seconds (scripts, screenshots)");
    cmd->callback([args] { run_view(*args); });
  }
}

}  // namespace zona::cli
