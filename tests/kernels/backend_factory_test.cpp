// Tests for kernels/backend_factory and engine/sim/backend_cpu: backend names, the auto/cpu/cuda
// choice with and without a GPU, and the CPU backend against the integrator it wraps.
#include "kernels/backend_factory.h"

#include <gtest/gtest.h>

#include <cstring>

#include "engine/sim/backend_cpu.h"
#include "engine/sim/integrator.h"
#include "engine/mesh/mesh_generate.h"
#include "kernels/cuda_backend.h"

namespace zona {
namespace {

TEST(BackendFactory, ParsesTheThreeNames) {
  EXPECT_EQ(*parse_backend_kind("auto"), BackendKind::kAuto);
  EXPECT_EQ(*parse_backend_kind("cpu"), BackendKind::kCpu);
  EXPECT_EQ(*parse_backend_kind("cuda"), BackendKind::kCuda);
  Result<BackendKind> bad = parse_backend_kind("gpu");
  ASSERT_FALSE(bad.ok());
  EXPECT_NE(bad.error().message.find("auto, cpu or cuda"), std::string::npos);
  EXPECT_STREQ(backend_kind_name(BackendKind::kCuda), "cuda");
  EXPECT_EQ(*parse_assembly("gather_stored"), Assembly::kGatherStored);
  EXPECT_FALSE(parse_assembly("colour").ok());
}

TEST(BackendFactory, CpuIsAlwaysThere) {
  std::string notice = "stale";
  Result<std::unique_ptr<Backend>> b = make_backend(BackendKind::kCpu, BackendOptions{}, &notice);
  ASSERT_TRUE(b.ok());
  EXPECT_STREQ((*b)->name(), "cpu");
  EXPECT_TRUE(notice.empty());
}

// Both branches assert: on a machine with a GPU, cuda and auto give the CUDA backend; without
// one (or built without CUDA), cuda is a one-line error and auto falls back with a notice.
TEST(BackendFactory, CudaOrAClearErrorAndAutoFallsBack) {
  const bool gpu = make_cuda_backend(BackendOptions{}).ok();
  std::string notice;
  Result<std::unique_ptr<Backend>> cuda = make_backend(BackendKind::kCuda, BackendOptions{});
  Result<std::unique_ptr<Backend>> automatic =
      make_backend(BackendKind::kAuto, BackendOptions{}, &notice);
  ASSERT_TRUE(automatic.ok());
  if (gpu) {
    ASSERT_TRUE(cuda.ok());
    EXPECT_STREQ((*cuda)->name(), "cuda");
    EXPECT_STREQ((*automatic)->name(), "cuda");
    EXPECT_TRUE(notice.empty());
  } else {
    ASSERT_FALSE(cuda.ok());
    const std::string& m = cuda.error().message;
    EXPECT_EQ(m.find('\n'), std::string::npos);
    EXPECT_TRUE(m.find("without CUDA") != std::string::npos ||
                m.find("CUDA device") != std::string::npos)
        << m;
    EXPECT_STREQ((*automatic)->name(), "cpu");
    EXPECT_NE(notice.find("using the CPU backend"), std::string::npos) << notice;
  }
}

// The CPU backend is the integrator: N sub-steps of one call equal N calls of step() with the
// same prescribed targets, to the bit.
TEST(BackendCpu, SubStepsEqualTheIntegratorStepByStep) {
  const Mesh mesh = generate_box_mesh(Vec3d{0, 0, 0}, Vec3d{4e-6, 4e-6, 4e-6}, 3, 3, 3);
  ModelDesc desc;
  desc.material.damping = 100;
  for (int32_t v = 0; v < 16; ++v) desc.fixed_vertices.push_back(v);  // the z = 0 face
  Result<Model> model = build_model(mesh, desc);
  ASSERT_TRUE(model.ok()) << model.error().message;
  State direct = make_state(*model, 1);
  const std::vector<int32_t> top = {48, 49, 50, 51, 52, 53, 54, 55, 56, 57, 58, 59, 60, 61, 62, 63};
  ASSERT_TRUE(set_prescribed_vertices(*model, direct, top).ok());
  std::unique_ptr<Backend> backend = make_cpu_backend(BackendOptions{1});
  ASSERT_TRUE(backend->upload(*model, direct).ok());
  const Vec3d push{0, 0, -2e-7};
  std::vector<Vec3d> targets(top.size(), push);
  ASSERT_TRUE(backend->set_prescribed_targets(targets).ok());
  const int n = 20;
  const StepReport r = backend->step(n);
  EXPECT_EQ(r.steps, n);
  EXPECT_EQ(r.status, kStepOk);
  const Vec3d delta = push / static_cast<double>(n);
  for (int i = 0; i < n; ++i) {
    for (size_t k = 0; k < top.size(); ++k)
      direct.prescribed_displacement[k] = static_cast<double>(i + 1) * delta;
    ASSERT_EQ(step(*model, direct), kStepOk);
  }
  State out = make_state(*model, 1);
  ASSERT_TRUE(backend->download(out).ok());
  EXPECT_EQ(std::memcmp(out.u.data(), direct.u.data(), out.u.size() * sizeof(Vec3d)), 0);
  EXPECT_EQ(out.step_count, n);
  EXPECT_GT(norm(r.constraint_force), 0);
  EXPECT_EQ(r.constraint_force.z, direct.diag.constraint_force.z);
  EXPECT_FALSE(backend->set_prescribed_targets(std::vector<Vec3d>(3)).ok());
}

}  // namespace
}  // namespace zona
