// Headless renderer on whatever Vulkan device exists (lavapipe in CI): the cell is in view and
// shaded, deformation and fields change the picture where they should, validation is clean,
// create / destroy repeats, bad input is an error. Skips when there is no Vulkan at all.
#include "render/renderer.h"

#include <gtest/gtest.h>
#include <unistd.h>

#include <cmath>
#include <filesystem>

#include "engine/mesh/mesh_generate.h"
#include "render/frame_source.h"

namespace zona {
namespace {

constexpr int kWidth = 192, kHeight = 144;

// A coarse 56 um ball (a few hundred vertices: fast on a software rasteriser).
const Mesh& ball() {
  static const Mesh mesh = [] {
    CellMeshSpec spec;
    spec.diameter = 56e-6;
    spec.edge_length = 9e-6;
    Result<Mesh> m = generate_cell_mesh(spec);
    EXPECT_TRUE(m.ok()) << (m.ok() ? "" : m.error().message);
    return m.ok() ? *m : Mesh{};
  }();
  return mesh;
}

const BoundarySurface& ball_surface() {
  static const BoundarySurface surface = extract_boundary(ball());
  return surface;
}

// The renderer or a skip: only "no Vulkan loader / device" skips, any other error fails.
#define ZONA_RENDERER_OR_SKIP(var, options)                                    \
  Result<Renderer> var = create_headless_renderer(kWidth, kHeight, options);   \
  if (!var.ok() && var.error().message.find("no Vulkan") != std::string::npos) \
    GTEST_SKIP() << var.error().message;                                       \
  ASSERT_TRUE(var.ok()) << var.error().message

// The ball seen from +z (yaw 0, pitch 0): +x is to the right of the image.
RenderFrame ball_frame() {
  RenderFrame f;
  f.rest = ball().rest_positions;
  f.triangles = ball_surface().triangles;
  f.camera = fit_camera({0, 0, 0}, 28e-6, 0.7, 0, 0);
  return f;
}

PixelImage render(Renderer& r, const RenderFrame& f) {
  PixelImage image;
  Status s = r.render(f);
  EXPECT_TRUE(s.ok()) << s.error().message;
  s = r.read_pixels(&image);
  EXPECT_TRUE(s.ok()) << s.error().message;
  return image;
}

const uint8_t* pixel(const PixelImage& im, int x, int y) {
  return &im.rgba[4 * (static_cast<size_t>(y) * im.width + x)];
}

bool is_background(const PixelImage& im, int x, int y) {
  const uint8_t* p = pixel(im, x, y);
  const uint8_t* b = pixel(im, 0, im.height - 1);  // a corner: no cell, no overlay there
  return std::abs(p[0] - b[0]) + std::abs(p[1] - b[1]) + std::abs(p[2] - b[2]) < 6;
}

double luminance(const uint8_t* p) {
  return 0.2126 * p[0] + 0.7152 * p[1] + 0.0722 * p[2];
}

TEST(Renderer, CellInViewAndShaded) {
  ZONA_RENDERER_OR_SKIP(r, RendererOptions{});
  const PixelImage im = render(*r, ball_frame());
  ASSERT_EQ(im.width, kWidth);
  // The centre square (a quarter of the ball's projected diameter) is all cell.
  int cell = 0, total = 0;
  double lo = 255, hi = 0;
  for (int y = kHeight / 2 - 15; y < kHeight / 2 + 15; ++y)
    for (int x = kWidth / 2 - 15; x < kWidth / 2 + 15; ++x, ++total) {
      if (is_background(im, x, y)) continue;
      ++cell;
      lo = std::min(lo, luminance(pixel(im, x, y)));
      hi = std::max(hi, luminance(pixel(im, x, y)));
    }
  EXPECT_EQ(cell, total);
  // Smooth shading: brightness varies across the sphere, corners stay background.
  EXPECT_GT(hi - lo, 20.0);
  EXPECT_TRUE(is_background(im, 2, 2 + kHeight / 2));
  EXPECT_TRUE(is_background(im, kWidth - 3, kHeight - 3));
}

TEST(Renderer, DeformedStateDiffersFromRest) {
  ZONA_RENDERER_OR_SKIP(r, RendererOptions{});
  RenderFrame f = ball_frame();
  const PixelImage rest = render(*r, f);
  // A 12 um dimple pushed into the ball's +x side (the right of the image).
  const std::vector<Vec3d> u =
      indentation_field(ball().rest_positions, {28e-6, 0, 0}, {-1, 0, 0}, 12e-6, 20e-6);
  f.displacement = u;
  const PixelImage deformed = render(*r, f);
  int right = 0, left = 0;
  for (int y = 0; y < kHeight; ++y)
    for (int x = 0; x < kWidth; ++x) {
      const uint8_t *a = pixel(rest, x, y), *b = pixel(deformed, x, y);
      if (std::abs(a[0] - b[0]) + std::abs(a[1] - b[1]) + std::abs(a[2] - b[2]) > 12)
        ++(x > kWidth / 2 ? right : left);
    }
  EXPECT_GT(right, 200);        // the dimple's silhouette and shading changed
  EXPECT_LT(left, right / 10);  // far from it nothing moved
}

TEST(Renderer, ColorMapFollowsTheField) {
  ZONA_RENDERER_OR_SKIP(r, RendererOptions{});
  RenderFrame f = ball_frame();
  std::vector<float> field;
  for (const Vec3d& x : ball().rest_positions) field.push_back(static_cast<float>(x.x));
  f.scalar = field;
  f.field = ColorField::kDisplacement;
  const PixelImage im = render(*r, f);
  // Mean red minus blue over the cell left and right of centre (the legend is far right).
  double left = 0, right = 0;
  int nl = 0, nr = 0;
  for (int y = kHeight / 2 - 20; y < kHeight / 2 + 20; ++y)
    for (int x = kWidth / 2 - 45; x < kWidth / 2 + 45; ++x) {
      if (is_background(im, x, y)) continue;
      const double warm = pixel(im, x, y)[0] - pixel(im, x, y)[2];
      if (x < kWidth / 2 - 15) left += warm, ++nl;
      if (x > kWidth / 2 + 15) right += warm, ++nr;
    }
  ASSERT_GT(nl, 100);
  ASSERT_GT(nr, 100);
  EXPECT_GT(right / nr, 60.0);  // high values: warm
  EXPECT_LT(left / nl, -60.0);  // low values: cold
}

TEST(Renderer, ValidationLayerReportsNothing) {
  RendererOptions options;
  options.validation = true;
  Result<Renderer> r = create_headless_renderer(kWidth, kHeight, options);
  if (!r.ok() && (r.error().message.find("no Vulkan") != std::string::npos ||
                  r.error().message.find("not installed") != std::string::npos))
    GTEST_SKIP() << r.error().message;
  ASSERT_TRUE(r.ok()) << r.error().message;
  // Everything the renderer draws: cell with a field, both pipettes, overlay and legend.
  RenderFrame f = ball_frame();
  const std::vector<Vec3d> u =
      indentation_field(ball().rest_positions, {-28e-6, 0, 0}, {1, 0, 0}, 5e-6, 15e-6);
  std::vector<float> field;
  displacement_magnitude(u, &field);
  f.displacement = u;
  f.scalar = field;
  f.field = ColorField::kDisplacement;
  f.needle = {true, {-23e-6, 0, 0}, {1, 0, 0}, 3e-6, false, 0};
  f.holding = {true, {28e-6, 0, 0}, {1, 0, 0}, 10e-6, 12.5e-6, 0};
  f.overlay_lines = {"validation", "needle force 1.000 uN"};
  render(*r, f);
  render(*r, f);  // a second frame reuses every buffer
  const ValidationReport v = r->validation();
  EXPECT_TRUE(v.enabled);
  EXPECT_EQ(v.errors, 0);
  EXPECT_EQ(v.warnings, 0);
  for (const std::string& m : v.messages) ADD_FAILURE() << m;
}

TEST(Renderer, CreateDestroyTwiceGivesTheSameImage) {
  PixelImage first;
  for (int round = 0; round < 2; ++round) {
    ZONA_RENDERER_OR_SKIP(r, RendererOptions{});
    RenderFrame f = ball_frame();
    f.needle = {true, {-30e-6, 0, 0}, {1, 0, 0}, 3e-6, true, 0};
    const PixelImage im = render(*r, f);
    if (round == 0)
      first = im;
    else
      EXPECT_EQ(first.rgba, im.rgba);  // deterministic and nothing left over from round 0
  }
}

TEST(Renderer, InconsistentFrameIsAnError) {
  ZONA_RENDERER_OR_SKIP(r, RendererOptions{});
  RenderFrame f = ball_frame();
  const std::vector<Vec3d> short_u(3, Vec3d{0, 0, 0});
  f.displacement = short_u;
  EXPECT_FALSE(r->render(f).ok());
  f = ball_frame();
  const std::vector<Triangle> bad = {{0, 1, static_cast<int32_t>(ball().vertex_count())}};
  f.triangles = bad;
  const Status s = r->render(f);
  ASSERT_FALSE(s.ok());
  EXPECT_NE(s.error().message.find("triangle 0"), std::string::npos);
  // The renderer still works afterwards.
  EXPECT_TRUE(r->render(ball_frame()).ok());
}

TEST(Renderer, FrameSequenceWritesNumberedPngs) {
  ZONA_RENDERER_OR_SKIP(r, RendererOptions{});
  const std::string dir = ::testing::TempDir() + "/zona_frames_" + std::to_string(::getpid());
  std::filesystem::remove_all(dir);
  FrameSequence sequence(&*r, dir);
  std::string path;
  ASSERT_TRUE(sequence.write(ball_frame(), &path).ok());
  ASSERT_TRUE(sequence.write(ball_frame()).ok());
  EXPECT_EQ(sequence.count(), 2);
  EXPECT_EQ(std::filesystem::path(path).filename(), "frame_00000.png");
  EXPECT_GT(std::filesystem::file_size(dir + "/frame_00001.png"), 1000u);
  std::filesystem::remove_all(dir);
}

TEST(Renderer, SharedSurfaceExportsMemoryAndCompactsLikeTheCopyPath) {
  RendererOptions options;
  options.external_memory = true;
  ZONA_RENDERER_OR_SKIP(r, options);
  const Mesh& mesh = ball();
  Result<SharedSurface> shared =
      r->create_shared_surface(ball_surface().triangles, mesh.vertex_count());
  if (!shared.ok() && shared.error().message.find("lacks VK_KHR_external_memory_fd") !=
                          std::string::npos)
    GTEST_SKIP() << shared.error().message;
  ASSERT_TRUE(shared.ok()) << shared.error().message;
  EXPECT_GE(shared->fd, 0);
  ::close(shared->fd);
  // Every boundary vertex once, in first-use order, and the triangles re-indexed onto them.
  EXPECT_EQ(shared->mesh_vertex.size(), ball_surface().vertices.size());
  ASSERT_EQ(shared->indices.size(), 3 * ball_surface().triangles.size());
  for (size_t t = 0; t < ball_surface().triangles.size(); ++t)
    for (int c = 0; c < 3; ++c)
      EXPECT_EQ(shared->mesh_vertex[shared->indices[3 * t + c]], ball_surface().triangles[t][c]);
  EXPECT_EQ(shared->mesh_vertex[0], ball_surface().triangles[0][0]);
  // Positions then normals, both inside the exported allocation.
  EXPECT_EQ(shared->positions_offset, 0u);
  EXPECT_EQ(shared->normals_offset, shared->mesh_vertex.size() * 16u);
  EXPECT_GE(shared->bytes, 2 * shared->mesh_vertex.size() * 16u);
  // The copy path still draws the same after the shared surface exists.
  const PixelImage image = render(*r, ball_frame());
  EXPECT_GT(image.rgba.size(), 0u);
  EXPECT_TRUE(r->validation().errors == 0);
}

TEST(Renderer, SharedSurfaceErrors) {
  // Without the option, and without a created surface, the errors say why.
  ZONA_RENDERER_OR_SKIP(plain, RendererOptions{});
  Result<SharedSurface> none = plain->create_shared_surface(ball_surface().triangles,
                                                            ball().vertex_count());
  ASSERT_FALSE(none.ok());
  EXPECT_NE(none.error().message.find("external memory not enabled"), std::string::npos);
  RenderFrame frame = ball_frame();
  frame.shared_surface = true;
  Status s = plain->render(frame);
  ASSERT_FALSE(s.ok());
  EXPECT_NE(s.error().message.find("no shared surface"), std::string::npos);
  // A triangle naming a vertex past the end is refused, naming it.
  RendererOptions options;
  options.external_memory = true;
  ZONA_RENDERER_OR_SKIP(r, options);
  std::vector<Triangle> bad = {Triangle{0, 1, 99}};
  Result<SharedSurface> out_of_range = r->create_shared_surface(bad, 10);
  ASSERT_FALSE(out_of_range.ok());
  EXPECT_NE(out_of_range.error().message.find("vertex 99"), std::string::npos);
}

}  // namespace
}  // namespace zona
