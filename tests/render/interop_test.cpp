// CUDA-Vulkan interop (kernels/surface_interop.h with Renderer::create_shared_surface): the
// CUDA backend's surface written straight into Vulkan memory must be the copy path's surface
// (positions, normals, colour range) and draw the same image. Skips without a CUDA device or
// without a Vulkan device exporting memory (CI, lavapipe-only machines); runs on the H100.
#include "kernels/surface_interop.h"

#include <gtest/gtest.h>

#include <cmath>

#include "engine/mesh/mesh_generate.h"
#include "engine/fem/state.h"
#include "kernels/backend_factory.h"
#include "kernels/cuda_backend.h"
#include "render/frame_source.h"
#include "render/geometry.h"
#include "render/interop.h"
#include "render/renderer.h"

namespace zona {
namespace {

constexpr int kWidth = 320, kHeight = 240;

struct Fixture {
  Mesh mesh;
  BoundarySurface surface;
  Model model;
  std::vector<Vec3d> u;  // a dimple pressed into the top [m]
};

const Fixture& fixture() {
  static const Fixture f = [] {
    Fixture x;
    CellMeshSpec spec;
    spec.diameter = 80e-6;
    spec.target_vertices = 3000;
    Result<Mesh> m = generate_cell_mesh(spec);
    EXPECT_TRUE(m.ok()) << (m.ok() ? "" : m.error().message);
    if (!m.ok()) return x;
    x.mesh = *m;
    x.surface = extract_boundary(x.mesh);
    ModelDesc desc;
    Result<Model> model = build_model(x.mesh, desc);
    EXPECT_TRUE(model.ok()) << (model.ok() ? "" : model.error().message);
    if (model.ok()) x.model = std::move(model).value();
    x.u = indentation_field(x.mesh.rest_positions, {0, 0, 40e-6}, {0, 0, -1}, 12e-6, 30e-6);
    return x;
  }();
  return f;
}

// The CUDA backend holding the fixture's deformed state, or a skip reason.
Result<std::unique_ptr<Backend>> deformed_backend() {
  const Fixture& f = fixture();
  Result<std::unique_ptr<Backend>> backend = make_cuda_backend(BackendOptions{});
  if (!backend) return backend.error();
  State state = make_state(f.model, 1);
  state.u = f.u;
  state.u_prev = f.u;
  if (Status s = (*backend)->upload(f.model, state); !s) return s.error();
  return backend;
}

// The deformed CUDA backend, a renderer on the NVIDIA device and the writer into its shared
// surface; skips where any of them cannot be had.
#define ZONA_INTEROP_OR_SKIP(renderer, backend, shared, writer)                               \
  Result<std::unique_ptr<Backend>> backend = deformed_backend();                              \
  if (!backend) GTEST_SKIP() << backend.error().message;                                      \
  RendererOptions renderer##_options;                                                         \
  renderer##_options.external_memory = true;                                                  \
  renderer##_options.device_name = "NVIDIA";                                                  \
  Result<Renderer> renderer = create_headless_renderer(kWidth, kHeight, renderer##_options);  \
  if (!renderer.ok()) GTEST_SKIP() << renderer.error().message;                               \
  Result<SharedSurface> shared = renderer->create_shared_surface(                             \
      fixture().surface.triangles, fixture().mesh.vertex_count());                            \
  if (!shared.ok()) GTEST_SKIP() << shared.error().message;                                   \
  Result<std::unique_ptr<SurfaceWriter>> writer =                                             \
      make_surface_writer(**backend, fixture().model, shared_surface_target(*shared));        \
  ASSERT_TRUE(writer.ok()) << writer.error().message

RenderFrame copy_frame(const Fixture& f, std::vector<float>* scalar) {
  RenderFrame frame;
  frame.rest = f.mesh.rest_positions;
  frame.displacement = f.u;
  frame.triangles = f.surface.triangles;
  displacement_magnitude(f.u, scalar);
  frame.scalar = *scalar;
  frame.field = ColorField::kDisplacement;
  frame.camera = default_camera(f.mesh);
  return frame;
}

TEST(CudaInterop, GpuSurfaceEqualsTheCopyPathsSurface) {
  ZONA_INTEROP_OR_SKIP(renderer, backend, shared, writer);
  const Fixture& f = fixture();

  std::vector<float> scalar;
  RenderFrame frame = copy_frame(f, &scalar);
  Vec3d origin;
  double scale = 0;
  camera_render_space(frame.camera, &origin, &scale);
  Result<SurfaceWriteResult> written =
      (*writer)->write(**backend, origin, scale, SurfaceScalar::kDisplacement);
  ASSERT_TRUE(written.ok()) << written.error().message;

  // The CPU surface pass on the same data.
  render::SurfaceGeometry cpu;
  render::RenderSpace space;
  space.origin = origin;
  space.scale = scale;
  ASSERT_TRUE(render::update_surface(frame, space, &cpu).ok());
  std::vector<std::array<float, 4>> positions, normals;
  ASSERT_TRUE((*writer)->read_back(&positions, &normals).ok());
  ASSERT_EQ(positions.size(), cpu.mesh.positions.size());
  double max_position = 0, max_normal = 0;
  for (size_t i = 0; i < positions.size(); ++i) {
    for (int c = 0; c < 4; ++c) {
      max_position = std::max(
          max_position, std::abs(static_cast<double>(positions[i][c]) - cpu.mesh.positions[i][c]));
      max_normal = std::max(
          max_normal, std::abs(static_cast<double>(normals[i][c]) - cpu.mesh.normals[i][c]));
    }
  }
  // The kernels repeat the CPU's operations in its order without fused multiply-adds: the
  // positions (render space, order 1) agree to float rounding, the normals to a few ulps.
  EXPECT_LE(max_position, 1e-6);
  EXPECT_LE(max_normal, 1e-5);
  EXPECT_NEAR(written->scalar_max, cpu.scalar_max, 1e-6 * cpu.scalar_max);
  EXPECT_NEAR(written->scalar_min, cpu.scalar_min, 1e-12);
  EXPECT_GT(written->scalar_max, 10e-6);  // the dimple is there

  // Both paths draw the same picture.
  ASSERT_TRUE(renderer->render(frame).ok());
  PixelImage copy_image, shared_image;
  ASSERT_TRUE(renderer->read_pixels(&copy_image).ok());
  RenderFrame shared_frame = frame;
  shared_frame.shared_surface = true;
  shared_frame.scalar_min = written->scalar_min;
  shared_frame.scalar_max = written->scalar_max;
  ASSERT_TRUE(renderer->render(shared_frame).ok());
  ASSERT_TRUE(renderer->read_pixels(&shared_image).ok());
  ASSERT_EQ(copy_image.rgba.size(), shared_image.rgba.size());
  // Pixels of the cell: unlike the background (the top-left corner's colour).
  size_t differing = 0, cell = 0;
  for (size_t p = 0; p < copy_image.rgba.size(); p += 4) {
    int d = 0, from_background = 0;
    for (int c = 0; c < 3; ++c) {
      d = std::max(d, std::abs(int(copy_image.rgba[p + c]) - int(shared_image.rgba[p + c])));
      from_background =
          std::max(from_background, std::abs(int(copy_image.rgba[p + c]) - int(copy_image.rgba[c])));
    }
    differing += d > 2;
    cell += from_background > 10;
  }
  EXPECT_GT(cell, copy_image.rgba.size() / 4 / 50);  // the cell fills part of the view
  EXPECT_LE(differing, copy_image.rgba.size() / 4 / 1000);
}

TEST(CudaInterop, WriterFollowsTheBackendAfterSteps) {
  ZONA_INTEROP_OR_SKIP(renderer, backend, shared, writer);
  const Fixture& f = fixture();
  // The released dimple springs back: after steps the written surface is the downloaded state's.
  const StepReport r = (*backend)->step(50);
  ASSERT_EQ(r.status & kStepNonFinite, 0u);
  State state = make_state(f.model, 1);
  ASSERT_TRUE((*backend)->download(state).ok());
  Result<SurfaceWriteResult> written =
      (*writer)->write(**backend, Vec3d{0, 0, 0}, 1e4, SurfaceScalar::kDisplacement);
  ASSERT_TRUE(written.ok()) << written.error().message;
  std::vector<std::array<float, 4>> positions, normals;
  ASSERT_TRUE((*writer)->read_back(&positions, &normals).ok());
  double worst = 0, moved = 0;
  for (size_t i = 0; i < positions.size(); ++i) {
    const size_t v = static_cast<size_t>(shared->mesh_vertex[i]);
    const Vec3d x = f.mesh.rest_positions[v] + state.u[v];
    worst = std::max(worst, std::abs(positions[i][0] - x.x * 1e4));
    worst = std::max(worst, std::abs(positions[i][2] - x.z * 1e4));
    moved = std::max(moved, norm(state.u[v] - f.u[v]));
  }
  EXPECT_GT(moved, 1e-9);      // the state did change
  EXPECT_LE(worst, 1e-5);      // and the writer saw the new one (render units, |x| ~ 0.4)
  // A writer refuses a backend it was not made for, and the CPU backend has no device state.
  Result<std::unique_ptr<Backend>> cpu = make_backend(BackendKind::kCpu, BackendOptions{});
  ASSERT_TRUE(cpu.ok());
  EXPECT_FALSE((*writer)->write(**cpu, Vec3d{0, 0, 0}, 1.0, SurfaceScalar::kNone).ok());
  SharedSurfaceTarget none;
  Result<std::unique_ptr<SurfaceWriter>> refused = make_surface_writer(**cpu, f.model, none);
  ASSERT_FALSE(refused.ok());
  EXPECT_NE(refused.error().message.find("keeps no state on a GPU"), std::string::npos);
}

}  // namespace
}  // namespace zona
