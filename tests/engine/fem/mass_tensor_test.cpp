// Precompute: rest geometry of a mesh and the stored tensors, independent of thread count.
#include "engine/fem/mass_tensor.h"

#include <gtest/gtest.h>

#include <cstring>

#include "tests/engine/physics_test_meshes.h"

namespace zona {
namespace {

TEST(MassTensor, ShapesOfABoxMesh) {
  const double l = 4e-6;
  const Mesh mesh = testing::box_mesh({0, 0, 0}, {l, 2 * l, l}, 2, 3, 2);
  std::vector<TetShape<double>> shapes;
  compute_tet_shapes(mesh, shapes);
  ASSERT_EQ(shapes.size(), mesh.tet_count());
  double volume = 0;
  for (size_t t = 0; t < shapes.size(); ++t) {
    EXPECT_GT(shapes[t].volume, 0);
    volume += shapes[t].volume;
    // Linear shape functions reproduce x: sum_j x_j grad_j^T = I.
    Mat3d id = Mat3d::zero();
    for (int j = 0; j < 4; ++j)
      id = id + outer(mesh.rest_positions[mesh.tets[t][j]], shapes[t].grad[j]);
    for (int r = 0; r < 3; ++r)
      for (int c = 0; c < 3; ++c) EXPECT_NEAR(id.m[r][c], r == c ? 1.0 : 0.0, 1e-12);
  }
  EXPECT_NEAR(volume, 2 * l * l * l, 1e-12 * volume);
}

TEST(MassTensor, StoredTensorsMatchTheElementFunctionForAnyThreadCount) {
  const Mesh mesh = testing::box_mesh({0, 0, 0}, {5e-6, 5e-6, 5e-6}, 6, 6, 6);  // 1296 tets
  std::vector<TetShape<double>> shapes;
  compute_tet_shapes(mesh, shapes);
  std::vector<int32_t> material(mesh.tet_count(), 0);
  for (size_t t = 0; t < material.size(); t += 3) material[t] = 1;
  const std::vector<Lame> lame = {lame_from_young_poisson(17.9e3, 0.49),
                                  lame_from_young_poisson(5e3, 0.3)};
  MassTensors serial, threaded;
  compute_mass_tensors(shapes, material, lame, ConstitutiveModel::kSvk, serial, 1);
  compute_mass_tensors(shapes, material, lame, ConstitutiveModel::kSvk, threaded, 3);
  ASSERT_EQ(serial.stride, kSvkTensorSize);
  EXPECT_EQ(serial.bytes(), mesh.tet_count() * kSvkTensorSize * sizeof(double));
  ASSERT_EQ(serial.values.size(), threaded.values.size());
  EXPECT_EQ(std::memcmp(serial.values.data(), threaded.values.data(), serial.bytes()), 0);
  std::vector<double> one(kSvkTensorSize);
  svk_mass_tensors(shapes[3], lame[1].lambda, lame[1].mu, one.data());
  EXPECT_EQ(std::memcmp(one.data(), serial.tet(3), one.size() * sizeof(double)), 0);

  MassTensors linear;
  compute_mass_tensors(shapes, material, lame, ConstitutiveModel::kLinear, linear, 2);
  ASSERT_EQ(linear.stride, kTensorBSize);
  std::vector<double> k(kTensorBSize);
  linear_mass_tensor(shapes[4], lame[0].lambda, lame[0].mu, k.data());
  EXPECT_EQ(std::memcmp(k.data(), linear.tet(4), k.size() * sizeof(double)), 0);
}

}  // namespace
}  // namespace zona
