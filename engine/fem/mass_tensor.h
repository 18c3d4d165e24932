// The off-line phase of Ladjal et al.'s method (its Table II, column 3): per-tetrahedron rest geometry (shape
// gradients and volume, what the gradient form needs) and the stored mass tensors K (linear)
// or B, C, D (SVK), what Ladjal et al.'s contraction needs.
#pragma once

#include <cstdint>
#include <vector>

#include "engine/fem/fem_element.h"
#include "engine/fem/material.h"
#include "engine/mesh/mesh.h"

namespace zona {

/// Computes the rest geometry of every tetrahedron into `shapes` (resized to tet_count):
/// four shape gradients [1/m] and the rest volume [m^3], 13 doubles each. `threads`: ranges of
/// tetrahedra evaluated side by side (the same numbers for any count).
void compute_tet_shapes(const Mesh& mesh, std::vector<TetShape<double>>& shapes, int threads = 1);

/// Stored mass tensors, one block of `stride` doubles per tetrahedron.
struct MassTensors {
  ConstitutiveModel model = ConstitutiveModel::kSvk;
  /// kSvkTensorSize (592: B, C, D) for SVK, kTensorBSize (144: K) for linear.
  int stride = 0;
  /// Tensor entries in the layout of fem_element.h, (tet_count x stride); B and K in
  /// [N/m], C in [N/m^2], D in [N/m^3].
  std::vector<double> values;

  const double* tet(size_t t) const { return values.data() + t * static_cast<size_t>(stride); }
  size_t bytes() const { return values.size() * sizeof(double); }
};

/// Precomputes the stored tensors of every tetrahedron with its Lame coefficients:
/// `tet_lame[tet_material[t]]`. Splits the work over `thread_count` threads (1: serial);
/// the result does not depend on the thread count.
void compute_mass_tensors(const std::vector<TetShape<double>>& shapes,
                          const std::vector<int32_t>& tet_material,
                          const std::vector<Lame>& material_lame, ConstitutiveModel model,
                          MassTensors& tensors, int thread_count = 1);

}  // namespace zona
