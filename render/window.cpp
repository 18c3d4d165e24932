// Window mode: GLFW (opened at run time), swapchain, the simulation thread and the draw loop
// (window.h).
#include "render/window.h"

#include <GLFW/glfw3.h>
#include <dlfcn.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <thread>
#include <vector>

#include "render/draw.h"
#include "render/frame_source.h"
#include "render/snapshot.h"

namespace zona {

using namespace render;

namespace {

// The GLFW functions zona uses, resolved from libglfw.so.3 (see window.h for why).
struct Glfw {
  void* library = nullptr;
  decltype(&::glfwInit) init = nullptr;
  decltype(&::glfwTerminate) terminate = nullptr;
  decltype(&::glfwWindowHint) window_hint = nullptr;
  decltype(&::glfwCreateWindow) create_window = nullptr;
  decltype(&::glfwDestroyWindow) destroy_window = nullptr;
  decltype(&::glfwWindowShouldClose) should_close = nullptr;
  decltype(&::glfwSetWindowShouldClose) set_should_close = nullptr;
  decltype(&::glfwPollEvents) poll_events = nullptr;
  decltype(&::glfwWaitEvents) wait_events = nullptr;
  decltype(&::glfwGetFramebufferSize) framebuffer_size = nullptr;
  decltype(&::glfwGetKey) get_key = nullptr;
  decltype(&::glfwGetMouseButton) get_mouse_button = nullptr;
  decltype(&::glfwGetCursorPos) get_cursor_pos = nullptr;
  decltype(&::glfwSetScrollCallback) set_scroll_callback = nullptr;
  decltype(&::glfwSetKeyCallback) set_key_callback = nullptr;
  decltype(&::glfwSetWindowUserPointer) set_user_pointer = nullptr;
  decltype(&::glfwGetWindowUserPointer) get_user_pointer = nullptr;
  decltype(&::glfwVulkanSupported) vulkan_supported = nullptr;
  decltype(&::glfwGetRequiredInstanceExtensions) required_extensions = nullptr;
  decltype(&::glfwGetError) get_error = nullptr;
  VkResult (*create_surface)(VkInstance, GLFWwindow*, const VkAllocationCallbacks*,
                             VkSurfaceKHR*) = nullptr;
};

Status load_glfw(Glfw* g) {
  g->library = dlopen("libglfw.so.3", RTLD_NOW | RTLD_LOCAL);
  if (!g->library) return make_error("view: cannot open libglfw.so.3 (install libglfw3)");
  bool ok = true;
  auto get = [&](auto* fn, const char* name) {
    *fn = reinterpret_cast<std::remove_pointer_t<decltype(fn)>>(dlsym(g->library, name));
    ok = ok && *fn;
  };
  get(&g->init, "glfwInit");
  get(&g->terminate, "glfwTerminate");
  get(&g->window_hint, "glfwWindowHint");
  get(&g->create_window, "glfwCreateWindow");
  get(&g->destroy_window, "glfwDestroyWindow");
  get(&g->should_close, "glfwWindowShouldClose");
  get(&g->set_should_close, "glfwSetWindowShouldClose");
  get(&g->poll_events, "glfwPollEvents");
  get(&g->wait_events, "glfwWaitEvents");
  get(&g->framebuffer_size, "glfwGetFramebufferSize");
  get(&g->get_key, "glfwGetKey");
  get(&g->get_mouse_button, "glfwGetMouseButton");
  get(&g->get_cursor_pos, "glfwGetCursorPos");
  get(&g->set_scroll_callback, "glfwSetScrollCallback");
  get(&g->set_key_callback, "glfwSetKeyCallback");
  get(&g->set_user_pointer, "glfwSetWindowUserPointer");
  get(&g->get_user_pointer, "glfwGetWindowUserPointer");
  get(&g->vulkan_supported, "glfwVulkanSupported");
  get(&g->required_extensions, "glfwGetRequiredInstanceExtensions");
  get(&g->get_error, "glfwGetError");
  get(&g->create_surface, "glfwCreateWindowSurface");
  if (!ok) return make_error("view: libglfw.so.3 lacks a GLFW 3.3 function");
  return {};
}

// Input gathered by callbacks between frames (main thread only).
struct InputState {
  double scroll = 0;
  int cycle_field = 0;
  bool reset_camera = false;
};

constexpr int kFramesInFlight = 2;

// Everything the window owns, destroyed in reverse order by the destructor.
struct WindowState {
  Glfw glfw;
  bool glfw_ready = false;
  GLFWwindow* window = nullptr;
  Context context;
  VkSurfaceKHR surface = VK_NULL_HANDLE;
  VkSwapchainKHR swapchain = VK_NULL_HANDLE;
  VkFormat format = VK_FORMAT_UNDEFINED;
  VkExtent2D extent{0, 0};
  std::vector<VkImage> images;
  std::vector<VkImageView> views;
  std::vector<VkSemaphore> render_done;  // per swapchain image
  VkSemaphore acquired[kFramesInFlight] = {};
  FrameResources frames[kFramesInFlight];
  OverlayState overlay;
  Pipelines pipelines;
  Attachments attachments;
  CpuFrame cpu;
  InputState input;

  void destroy_swapchain() {
    for (VkImageView v : views) vkDestroyImageView(context.device, v, nullptr);
    for (VkSemaphore s : render_done) vkDestroySemaphore(context.device, s, nullptr);
    views.clear();
    render_done.clear();
    images.clear();
    destroy_attachments(context, &attachments);
    if (swapchain) vkDestroySwapchainKHR(context.device, swapchain, nullptr);
    swapchain = VK_NULL_HANDLE;
  }

  ~WindowState() {
    if (context.device) {
      vkDeviceWaitIdle(context.device);
      destroy_swapchain();
      for (int i = 0; i < kFramesInFlight; ++i) {
        destroy_frame_resources(context, &frames[i]);
        if (acquired[i]) vkDestroySemaphore(context.device, acquired[i], nullptr);
      }
      destroy_pipelines(context, &pipelines);
    }
    destroy_overlay(&overlay);
    if (surface) vkDestroySurfaceKHR(context.instance, surface, nullptr);
    destroy_context(&context);
    if (window) glfw.destroy_window(window);
    if (glfw_ready) glfw.terminate();
    // libglfw stays loaded: unloading a library that started X11 threads is not safe.
  }
};

VkSurfaceFormatKHR choose_format(VkPhysicalDevice device, VkSurfaceKHR surface) {
  uint32_t count = 0;
  vkGetPhysicalDeviceSurfaceFormatsKHR(device, surface, &count, nullptr);
  std::vector<VkSurfaceFormatKHR> formats(count);
  vkGetPhysicalDeviceSurfaceFormatsKHR(device, surface, &count, formats.data());
  // An sRGB format keeps the colours the same as the headless PNGs.
  for (const VkSurfaceFormatKHR& f : formats)
    if ((f.format == VK_FORMAT_B8G8R8A8_SRGB || f.format == VK_FORMAT_R8G8B8A8_SRGB) &&
        f.colorSpace == VK_COLOR_SPACE_SRGB_NONLINEAR_KHR)
      return f;
  return formats.empty()
             ? VkSurfaceFormatKHR{VK_FORMAT_B8G8R8A8_SRGB, VK_COLOR_SPACE_SRGB_NONLINEAR_KHR}
             : formats[0];
}

Status create_swapchain(WindowState* w) {
  VkSurfaceCapabilitiesKHR caps;
  ZONA_VK_TRY(
      vkGetPhysicalDeviceSurfaceCapabilitiesKHR(w->context.physical_device, w->surface, &caps));
  int fw = 0, fh = 0;
  w->glfw.framebuffer_size(w->window, &fw, &fh);
  VkExtent2D extent = caps.currentExtent;
  if (extent.width == UINT32_MAX) {
    extent.width =
        std::clamp(static_cast<uint32_t>(fw), caps.minImageExtent.width, caps.maxImageExtent.width);
    extent.height = std::clamp(static_cast<uint32_t>(fh), caps.minImageExtent.height,
                               caps.maxImageExtent.height);
  }
  if (extent.width == 0 || extent.height == 0) return {};  // minimised: draw nothing
  const VkSurfaceFormatKHR format = choose_format(w->context.physical_device, w->surface);
  uint32_t count = caps.minImageCount + 1;
  if (caps.maxImageCount > 0) count = std::min(count, caps.maxImageCount);
  VkSwapchainCreateInfoKHR info{VK_STRUCTURE_TYPE_SWAPCHAIN_CREATE_INFO_KHR};
  info.surface = w->surface;
  info.minImageCount = count;
  info.imageFormat = format.format;
  info.imageColorSpace = format.colorSpace;
  info.imageExtent = extent;
  info.imageArrayLayers = 1;
  info.imageUsage = VK_IMAGE_USAGE_COLOR_ATTACHMENT_BIT;
  info.imageSharingMode = VK_SHARING_MODE_EXCLUSIVE;
  info.preTransform = caps.currentTransform;
  info.compositeAlpha = VK_COMPOSITE_ALPHA_OPAQUE_BIT_KHR;
  info.presentMode = VK_PRESENT_MODE_FIFO_KHR;  // always available; paces to the display
  info.clipped = VK_TRUE;
  ZONA_VK_TRY(vkCreateSwapchainKHR(w->context.device, &info, nullptr, &w->swapchain));
  w->format = format.format;
  w->extent = extent;
  uint32_t n = 0;
  ZONA_VK_TRY(vkGetSwapchainImagesKHR(w->context.device, w->swapchain, &n, nullptr));
  w->images.resize(n);
  ZONA_VK_TRY(vkGetSwapchainImagesKHR(w->context.device, w->swapchain, &n, w->images.data()));
  for (VkImage image : w->images) {
    VkImageViewCreateInfo view{VK_STRUCTURE_TYPE_IMAGE_VIEW_CREATE_INFO};
    view.image = image;
    view.viewType = VK_IMAGE_VIEW_TYPE_2D;
    view.format = w->format;
    view.subresourceRange = {VK_IMAGE_ASPECT_COLOR_BIT, 0, 1, 0, 1};
    VkImageView v = VK_NULL_HANDLE;
    ZONA_VK_TRY(vkCreateImageView(w->context.device, &view, nullptr, &v));
    w->views.push_back(v);
    VkSemaphoreCreateInfo sem{VK_STRUCTURE_TYPE_SEMAPHORE_CREATE_INFO};
    VkSemaphore s = VK_NULL_HANDLE;
    ZONA_VK_TRY(vkCreateSemaphore(w->context.device, &sem, nullptr, &s));
    w->render_done.push_back(s);
  }
  return create_attachments(w->context, w->pipelines, extent, &w->attachments);
}

Status recreate_swapchain(WindowState* w) {
  ZONA_VK_TRY(vkDeviceWaitIdle(w->context.device));
  w->destroy_swapchain();
  return create_swapchain(w);
}

Status open_window(const ViewOptions& options, WindowState* w) {
  if (Status s = load_glfw(&w->glfw); !s.ok()) return s;
  if (!w->glfw.init()) {
    const char* why = nullptr;
    w->glfw.get_error(&why);
    return make_error("view: GLFW cannot start (%s); is there a display? (try xvfb-run)",
                      why ? why : "no reason given");
  }
  w->glfw_ready = true;
  if (!w->glfw.vulkan_supported())
    return make_error("view: GLFW finds no Vulkan loader able to present to a window");
  w->glfw.window_hint(GLFW_CLIENT_API, GLFW_NO_API);
  w->window =
      w->glfw.create_window(options.width, options.height, options.title.c_str(), nullptr, nullptr);
  if (!w->window)
    return make_error("view: cannot create a %dx%d window", options.width, options.height);

  ContextOptions context_options;
  context_options.validation = options.validation;
  context_options.swapchain = true;
  uint32_t count = 0;
  const char** extensions = w->glfw.required_extensions(&count);
  for (uint32_t i = 0; i < count; ++i) context_options.instance_extensions.push_back(extensions[i]);
  if (Status s = create_instance(context_options, &w->context); !s.ok()) return s;
  ZONA_VK_TRY(w->glfw.create_surface(w->context.instance, w->window, nullptr, &w->surface));
  if (Status s = create_device(context_options, w->surface, &w->context); !s.ok()) return s;

  const float font = std::max(13.0f, std::round(static_cast<float>(options.height) / 40.0f));
  if (Status s = create_overlay("", font, &w->overlay); !s.ok()) return s;
  const VkFormat format = choose_format(w->context.physical_device, w->surface).format;
  if (Status s = create_pipelines(w->context, format, pick_samples(w->context, 4), w->overlay,
                                  &w->pipelines);
      !s.ok())
    return s;
  for (int i = 0; i < kFramesInFlight; ++i) {
    if (Status s = create_frame_resources(w->context, &w->frames[i]); !s.ok()) return s;
    VkSemaphoreCreateInfo sem{VK_STRUCTURE_TYPE_SEMAPHORE_CREATE_INFO};
    ZONA_VK_TRY(vkCreateSemaphore(w->context.device, &sem, nullptr, &w->acquired[i]));
  }
  return create_swapchain(w);
}

// Draws one frame; `presented` stays false when the swapchain had to be rebuilt instead.
Status draw_frame(WindowState* w, int slot, const RenderFrame& frame, bool* presented) {
  *presented = false;
  if (!w->swapchain) return recreate_swapchain(w);
  FrameResources& f = w->frames[slot];
  const VkDevice device = w->context.device;
  ZONA_VK_TRY(vkWaitForFences(device, 1, &f.fence, VK_TRUE, UINT64_MAX));
  uint32_t index = 0;
  VkResult r = vkAcquireNextImageKHR(device, w->swapchain, UINT64_MAX, w->acquired[slot],
                                     VK_NULL_HANDLE, &index);
  if (r == VK_ERROR_OUT_OF_DATE_KHR) return recreate_swapchain(w);
  if (r != VK_SUCCESS && r != VK_SUBOPTIMAL_KHR) ZONA_VK_TRY(r);
  if (Status s = prepare_frame(w->context, &w->overlay, frame, w->extent, &w->cpu, &f); !s.ok())
    return s;
  ZONA_VK_TRY(vkResetFences(device, 1, &f.fence));
  ZONA_VK_TRY(vkResetCommandBuffer(f.cmd, 0));
  VkCommandBufferBeginInfo begin{VK_STRUCTURE_TYPE_COMMAND_BUFFER_BEGIN_INFO};
  begin.flags = VK_COMMAND_BUFFER_USAGE_ONE_TIME_SUBMIT_BIT;
  ZONA_VK_TRY(vkBeginCommandBuffer(f.cmd, &begin));
  image_barrier(
      f.cmd, w->images[index], VK_IMAGE_ASPECT_COLOR_BIT, VK_IMAGE_LAYOUT_UNDEFINED,
      VK_IMAGE_LAYOUT_COLOR_ATTACHMENT_OPTIMAL, VK_PIPELINE_STAGE_2_COLOR_ATTACHMENT_OUTPUT_BIT, 0,
      VK_PIPELINE_STAGE_2_COLOR_ATTACHMENT_OUTPUT_BIT, VK_ACCESS_2_COLOR_ATTACHMENT_WRITE_BIT);
  record_frame(f.cmd, w->pipelines, w->attachments, w->cpu, f, w->views[index]);
  image_barrier(f.cmd, w->images[index], VK_IMAGE_ASPECT_COLOR_BIT,
                VK_IMAGE_LAYOUT_COLOR_ATTACHMENT_OPTIMAL, VK_IMAGE_LAYOUT_PRESENT_SRC_KHR,
                VK_PIPELINE_STAGE_2_COLOR_ATTACHMENT_OUTPUT_BIT,
                VK_ACCESS_2_COLOR_ATTACHMENT_WRITE_BIT, VK_PIPELINE_STAGE_2_NONE, 0);
  ZONA_VK_TRY(vkEndCommandBuffer(f.cmd));
  const VkPipelineStageFlags wait_stage = VK_PIPELINE_STAGE_COLOR_ATTACHMENT_OUTPUT_BIT;
  VkSubmitInfo submit{VK_STRUCTURE_TYPE_SUBMIT_INFO};
  submit.waitSemaphoreCount = 1;
  submit.pWaitSemaphores = &w->acquired[slot];
  submit.pWaitDstStageMask = &wait_stage;
  submit.commandBufferCount = 1;
  submit.pCommandBuffers = &f.cmd;
  submit.signalSemaphoreCount = 1;
  submit.pSignalSemaphores = &w->render_done[index];
  ZONA_VK_TRY(vkQueueSubmit(w->context.queue, 1, &submit, f.fence));
  VkPresentInfoKHR present{VK_STRUCTURE_TYPE_PRESENT_INFO_KHR};
  present.waitSemaphoreCount = 1;
  present.pWaitSemaphores = &w->render_done[index];
  present.swapchainCount = 1;
  present.pSwapchains = &w->swapchain;
  present.pImageIndices = &index;
  r = vkQueuePresentKHR(w->context.queue, &present);
  int fw = 0, fh = 0;
  w->glfw.framebuffer_size(w->window, &fw, &fh);
  const bool resized =
      static_cast<uint32_t>(fw) != w->extent.width || static_cast<uint32_t>(fh) != w->extent.height;
  if (r == VK_ERROR_OUT_OF_DATE_KHR || r == VK_SUBOPTIMAL_KHR || resized)
    return recreate_swapchain(w);
  ZONA_VK_TRY(r);
  *presented = true;
  return {};
}

// The simulation thread: steps, takes the needle from the keyboard when asked, publishes.
struct SimulationThread {
  Simulation* simulation = nullptr;
  TripleBuffer<SceneSnapshot>* snapshots = nullptr;
  TripleBuffer<Vec3d>* needle_command = nullptr;  // keyboard target tip [m]
  std::atomic<bool> stop{false};
  std::atomic<bool> manual{false};  // the keyboard drives the needle
  std::atomic<int> field{0};        // ColorField as int
  double publish_interval = 1.0 / 60;

  void run() {
    Simulation& sim = *simulation;
    using clock = std::chrono::steady_clock;
    const auto start = clock::now();
    auto last_publish = start - std::chrono::seconds(1);
    int64_t steps_at_publish = 0;
    double rate = 0;
    Vec3d target{0, 0, 0};
    bool have_target = false;
    const double max_move = std::max(sim.scene().needle.speed, 1e-4) * 20.0 * sim.model().dt;
    Vec3d tip = sim.report().step > 0 ? sim.report().tip : needle_tip_at(sim.needle_script(), 0.0);
    while (!stop.load(std::memory_order_relaxed)) {
      const bool manual_now = manual.load(std::memory_order_relaxed);
      if (!manual_now && sim.finished()) {
        std::this_thread::sleep_for(std::chrono::milliseconds(5));
      } else {
        sim.step1();
        if (manual_now) {
          if (needle_command->acquire()) {
            target = needle_command->read_slot();
            have_target = true;
          }
          if (have_target) {
            // Move towards the keyboard's target no faster than max_move a step, so that the
            // contact search keeps up.
            const Vec3d d = target - tip;
            const double len = norm(d);
            tip = len > max_move ? tip + (max_move / len) * d : target;
          }
          sim.set_needle_tip(tip);
        } else {
          tip = needle_tip_at(sim.needle_script(), sim.report().time + sim.model().dt);
        }
        sim.step2();
        if (!manual_now) tip = sim.report().tip;
      }
      const auto now = clock::now();
      const double since = std::chrono::duration<double>(now - last_publish).count();
      if (since >= publish_interval) {
        rate = since < 1 ? static_cast<double>(sim.report().step - steps_at_publish) / since : 0;
        steps_at_publish = sim.report().step;
        last_publish = now;
        SceneSnapshot& s = snapshots->write_slot();
        const std::vector<Vec3d>& u = sim.state().u;
        std::copy(u.begin(), u.begin() + static_cast<std::ptrdiff_t>(s.displacement.size()),
                  s.displacement.begin());
        const auto f = static_cast<ColorField>(field.load(std::memory_order_relaxed));
        if (f == ColorField::kDisplacement)
          displacement_magnitude(s.displacement, &s.scalar);
        else if (f == ColorField::kStress)
          vertex_von_mises(sim, &s.scalar);
        else
          s.scalar.clear();
        s.report = sim.report();
        s.report.tip = tip;
        s.steps_per_second = rate;
        ++s.sequence;
        snapshots->publish();
      }
    }
  }
};

// GLFW callbacks are plain functions: they find the InputState through the window's user
// pointer, read with this (set once in run_view_window, main thread only).
decltype(&::glfwGetWindowUserPointer) g_get_user_pointer = nullptr;

void on_scroll(GLFWwindow* window, double, double dy) {
  static_cast<InputState*>(g_get_user_pointer(window))->scroll += dy;
}

void on_key(GLFWwindow* window, int key, int, int action, int) {
  if (action != GLFW_PRESS) return;
  auto* input = static_cast<InputState*>(g_get_user_pointer(window));
  if (key == GLFW_KEY_C) ++input->cycle_field;
  if (key == GLFW_KEY_R) input->reset_camera = true;
}

}  // namespace

Status run_view_window(Simulation& simulation, const ViewOptions& options, ViewResult* result) {
  WindowState w;
  if (Status s = open_window(options, &w); !s.ok()) return s;
  Glfw& glfw = w.glfw;
  glfw.set_user_pointer(w.window, &w.input);
  g_get_user_pointer = glfw.get_user_pointer;
  glfw.set_scroll_callback(w.window, on_scroll);
  glfw.set_key_callback(w.window, on_key);

  SceneSnapshot initial;
  initial.displacement.assign(simulation.model().vertex_count(), Vec3d{0, 0, 0});
  initial.scalar.assign(simulation.model().vertex_count(), 0.0f);
  initial.report = simulation.report();
  initial.report.tip = needle_tip_at(simulation.needle_script(), 0.0);
  TripleBuffer<SceneSnapshot> snapshots(initial);
  TripleBuffer<Vec3d> needle_command(initial.report.tip);
  SimulationThread sim_thread;
  sim_thread.simulation = &simulation;
  sim_thread.snapshots = &snapshots;
  sim_thread.needle_command = &needle_command;
  sim_thread.field = static_cast<int>(options.field);
  sim_thread.publish_interval = options.publish_interval;
  std::thread thread([&] { sim_thread.run(); });

  const OrbitCamera home = default_camera(simulation.mesh());
  OrbitCamera camera = home;
  ColorField field = options.field;
  Vec3d needle_target = initial.report.tip;
  const Vec3d axis = simulation.needle_script().direction;
  double last_x = 0, last_y = 0;
  bool dragging = false;
  using clock = std::chrono::steady_clock;
  const auto start = clock::now();
  auto last = start, fps_start = start;
  int64_t fps_frames = 0;
  double fps = 0;
  int slot = 0;
  Status status;
  RenderFrame frame;
  frame.rest = simulation.model().rest_positions;
  frame.triangles = simulation.surface().triangles;
  frame.holding = holding_pose(simulation);

  while (!glfw.should_close(w.window)) {
    glfw.poll_events();
    const auto now = clock::now();
    const double dt = std::chrono::duration<double>(now - last).count();
    last = now;
    if (options.close_after > 0 &&
        std::chrono::duration<double>(now - start).count() > options.close_after)
      break;
    if (glfw.get_key(w.window, GLFW_KEY_ESCAPE) == GLFW_PRESS ||
        glfw.get_key(w.window, GLFW_KEY_Q) == GLFW_PRESS)
      break;
    // Camera: drag to orbit, scroll to zoom.
    double x = 0, y = 0;
    glfw.get_cursor_pos(w.window, &x, &y);
    if (glfw.get_mouse_button(w.window, GLFW_MOUSE_BUTTON_LEFT) == GLFW_PRESS) {
      if (dragging) orbit_camera(&camera, -0.3 * (x - last_x), 0.3 * (y - last_y));
      dragging = true;
    } else {
      dragging = false;
    }
    last_x = x;
    last_y = y;
    if (w.input.scroll != 0) {
      camera.distance *= std::pow(0.9, w.input.scroll);
      w.input.scroll = 0;
    }
    if (w.input.reset_camera) {
      camera = home;
      w.input.reset_camera = false;
    }
    if (w.input.cycle_field) {
      field = static_cast<ColorField>((static_cast<int>(field) + w.input.cycle_field) % 3);
      sim_thread.field = static_cast<int>(field);
      w.input.cycle_field = 0;
    }
    // Needle from the keyboard: the first press takes it from the script.
    const bool shift = glfw.get_key(w.window, GLFW_KEY_LEFT_SHIFT) == GLFW_PRESS;
    const double speed = options.needle_key_speed * (shift ? 5.0 : 1.0);
    int push = 0;
    if (glfw.get_key(w.window, GLFW_KEY_UP) == GLFW_PRESS ||
        glfw.get_key(w.window, GLFW_KEY_W) == GLFW_PRESS)
      push += 1;
    if (glfw.get_key(w.window, GLFW_KEY_DOWN) == GLFW_PRESS ||
        glfw.get_key(w.window, GLFW_KEY_S) == GLFW_PRESS)
      push -= 1;
    if (push != 0) {
      if (!sim_thread.manual.load()) {
        needle_target = snapshots.read_slot().report.tip;
        sim_thread.manual = true;
      }
      needle_target = needle_target + (push * speed * dt) * axis;
      needle_command.write_slot() = needle_target;
      needle_command.publish();
    }

    snapshots.acquire();
    const SceneSnapshot& snap = snapshots.read_slot();
    frame.displacement = snap.displacement;
    frame.scalar = snap.scalar;
    frame.field = snap.scalar.empty() ? ColorField::kNone : field;
    frame.needle = needle_pose(simulation, snap.report.tip);
    frame.camera = camera;
    OverlayRates rates;
    rates.simulation_hz = snap.steps_per_second;
    rates.render_hz = fps;
    frame.overlay_lines = overlay_lines(options.title, snap.report, rates);
    frame.overlay_lines.push_back(sim_thread.manual.load() ? "needle: keyboard (W/S, Shift)"
                                                           : "needle: script (W/S takes it)");
    bool presented = false;
    status = draw_frame(&w, slot, frame, &presented);
    if (!status.ok()) break;
    if (presented) {
      slot = (slot + 1) % kFramesInFlight;
      ++result->frames;
      ++fps_frames;
    }
    const double fps_window = std::chrono::duration<double>(now - fps_start).count();
    if (fps_window > 0.5) {
      fps = static_cast<double>(fps_frames) / fps_window;
      fps_frames = 0;
      fps_start = now;
    }
  }
  sim_thread.stop = true;
  thread.join();
  if (w.context.log) {
    ValidationLog& log = *w.context.log;
    result->validation.enabled = true;
    result->validation.errors = log.errors.load();
    result->validation.warnings = log.warnings.load();
    std::lock_guard<std::mutex> lock(log.mutex);
    result->validation.messages = log.messages;
  }
  return status;
}

}  // namespace zona
