// CUDA-Vulkan interop against the copy path, per rendered frame of a deformed cell on the
// CUDA backend (issue 8: "measure both on the device"):
//   copy:    backend download (device -> host) + |u| on the CPU + the renderer's CPU surface pass
//            (positions, normals) + upload into host-visible vertex buffers + draw + readback;
//   interop: the surface writer's two kernels into the exported Vulkan memory + draw + readback.
// Both draw the same image (compared pixel by pixel); `draw_only` renders the shared frame
// again without writing, the cost common to both. Medians over --frames frames per size.
//
//   interop_bench [--vertices 10000,100000,1000000] [--frames 30] [--width 1280 --height 720]
//                 [--out FILE.csv]
// Needs CUDA and the Vulkan renderer on the same GPU (ZONA_VK_DEVICE picks it); says why not
// and exits 1 otherwise.
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <ctime>
#include <memory>
#include <sstream>
#include <string>
#include <vector>

#include "engine/mesh/mesh_generate.h"
#include "engine/fem/state.h"
#include "kernels/cuda_backend.h"
#include "kernels/surface_interop.h"
#include "render/frame_source.h"
#include "render/interop.h"
#include "render/renderer.h"

namespace zona {
namespace {

using Clock = std::chrono::steady_clock;

double ms_since(Clock::time_point t0) {
  return std::chrono::duration<double, std::milli>(Clock::now() - t0).count();
}

double median(std::vector<double> v) {
  if (v.empty()) return 0;
  std::sort(v.begin(), v.end());
  return v[v.size() / 2];
}

int fail(const std::string& what) {
  std::fprintf(stderr, "interop_bench: %s\n", what.c_str());
  return 1;
}

int run(int argc, char** argv) {
  std::vector<int64_t> sizes = {10000, 100000, 1000000};
  int frames = 30, width = 1280, height = 720;
  std::string out_path;
  for (int i = 1; i + 1 < argc; i += 2) {
    const std::string k = argv[i], v = argv[i + 1];
    if (k == "--vertices") {
      sizes.clear();
      std::stringstream ss(v);
      for (std::string item; std::getline(ss, item, ',');) sizes.push_back(std::atoll(item.c_str()));
    } else if (k == "--frames") {
      frames = std::max(3, std::atoi(v.c_str()));
    } else if (k == "--width") {
      width = std::atoi(v.c_str());
    } else if (k == "--height") {
      height = std::atoi(v.c_str());
    } else if (k == "--out") {
      out_path = v;
    } else {
      return fail("unknown option " + k);
    }
  }

  RendererOptions options;
  options.external_memory = true;
  Result<Renderer> renderer = create_headless_renderer(width, height, options);
  if (!renderer.ok()) return fail(renderer.error().message);
  char date[32];
  const std::time_t now = std::time(nullptr);
  std::strftime(date, sizeof(date), "%Y-%m-%d", std::gmtime(&now));
  std::fprintf(stderr, "# %s, %dx%d, %d frames per size\n", renderer->device_name().c_str(), width,
               height, frames);
  FILE* csv = out_path.empty() ? nullptr : std::fopen(out_path.c_str(), "w");
  if (!out_path.empty() && !csv) return fail("cannot write " + out_path);
  const char* header =
      "device,date,width,height,vertices,surface_vertices,triangles,copy_frame_ms,"
      "interop_frame_ms,frame_speedup,download_ms,cpu_surface_upload_ms,write_ms,draw_only_ms,"
      "surface_speedup,pixels_differing\n";
  std::printf("%s", header);
  if (csv) std::fprintf(csv, "%s", header);

  for (int64_t target : sizes) {
    CellMeshSpec spec;
    spec.target_vertices = target;
    Result<Mesh> mesh = generate_cell_mesh(spec);
    if (!mesh) return fail(mesh.error().message);
    const BoundarySurface surface = extract_boundary(*mesh);
    ModelDesc desc;
    Result<Model> model = build_model(*mesh, desc);
    if (!model) return fail(model.error().message);
    const double r = 0.5 * spec.diameter;
    State state = make_state(*model, 1);
    state.u = indentation_field(mesh->rest_positions, {0, 0, r}, {0, 0, -1}, 0.3 * r, 0.7 * r);
    state.u_prev = state.u;
    Result<std::unique_ptr<Backend>> backend = make_cuda_backend(BackendOptions{});
    if (!backend) return fail(backend.error().message);
    if (Status s = (*backend)->upload(*model, state); !s) return fail(s.error().message);

    Result<SharedSurface> shared =
        renderer->create_shared_surface(surface.triangles, mesh->vertex_count());
    if (!shared) return fail(shared.error().message);
    const SharedSurfaceTarget target_memory = shared_surface_target(*shared);
    Result<std::unique_ptr<SurfaceWriter>> writer =
        make_surface_writer(**backend, *model, target_memory);
    if (!writer) return fail(writer.error().message);

    RenderFrame frame;
    frame.rest = mesh->rest_positions;
    frame.triangles = surface.triangles;
    frame.field = ColorField::kDisplacement;
    frame.camera = default_camera(*mesh);
    Vec3d origin;
    double scale = 1;
    camera_render_space(frame.camera, &origin, &scale);
    State host = make_state(*model, 1);
    std::vector<float> scalar;

    std::vector<double> copy_ms, interop_ms, download_ms, cpu_upload_ms, write_ms, draw_ms;
    PixelImage copy_image, shared_image;
    for (int f = 0; f < frames + 1; ++f) {  // frame 0 warms up
      // Copy path.
      const auto c0 = Clock::now();
      if (Status s = (*backend)->download(host); !s) return fail(s.error().message);
      displacement_magnitude(host.u, &scalar);
      const double download = ms_since(c0);
      frame.shared_surface = false;
      frame.auto_range = true;
      frame.displacement = host.u;
      frame.scalar = scalar;
      const auto c1 = Clock::now();
      if (Status s = renderer->render(frame); !s) return fail(s.error().message);
      const double copy_render = ms_since(c1);
      const double copy = ms_since(c0);
      if (f == frames) (void)renderer->read_pixels(&copy_image);
      // Interop path.
      const auto i0 = Clock::now();
      Result<SurfaceWriteResult> w =
          (*writer)->write(**backend, origin, scale, SurfaceScalar::kDisplacement);
      if (!w) return fail(w.error().message);
      const double write = ms_since(i0);
      frame.shared_surface = true;
      frame.scalar_min = w->scalar_min;
      frame.scalar_max = w->scalar_max;
      if (Status s = renderer->render(frame); !s) return fail(s.error().message);
      const double interop = ms_since(i0);
      if (f == frames) (void)renderer->read_pixels(&shared_image);
      // The draw alone (shared frame again, nothing written).
      const auto d0 = Clock::now();
      if (Status s = renderer->render(frame); !s) return fail(s.error().message);
      const double draw = ms_since(d0);
      if (f == 0) continue;
      copy_ms.push_back(copy);
      interop_ms.push_back(interop);
      download_ms.push_back(download);
      cpu_upload_ms.push_back(copy_render - draw);
      write_ms.push_back(write);
      draw_ms.push_back(draw);
    }
    size_t differing = 0;
    for (size_t p = 0; p + 3 < copy_image.rgba.size() && p < shared_image.rgba.size(); p += 4) {
      int d = 0;
      for (int c = 0; c < 3; ++c)
        d = std::max(d, std::abs(int(copy_image.rgba[p + c]) - int(shared_image.rgba[p + c])));
      differing += d > 2;
    }
    const double copy = median(copy_ms), interop = median(interop_ms);
    const double surface_copy = median(download_ms) + median(cpu_upload_ms);
    char line[512];
    std::snprintf(line, sizeof(line),
                  "\"%s\",%s,%d,%d,%zu,%zu,%zu,%.4f,%.4f,%.2f,%.4f,%.4f,%.4f,%.4f,%.1f,%zu\n",
                  renderer->device_name().c_str(), date, width, height, mesh->vertex_count(),
                  shared->mesh_vertex.size(), surface.triangles.size(), copy, interop,
                  copy / interop, median(download_ms), median(cpu_upload_ms), median(write_ms),
                  median(draw_ms), surface_copy / std::max(1e-6, median(write_ms)), differing);
    std::printf("%s", line);
    if (csv) std::fprintf(csv, "%s", line);
    std::fflush(stdout);
  }
  if (csv) std::fclose(csv);
  return 0;
}

}  // namespace
}  // namespace zona

int main(int argc, char** argv) {
  return zona::run(argc, argv);
}
