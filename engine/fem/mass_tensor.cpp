// Rest geometry and stored mass-tensor precompute.
#include "engine/fem/mass_tensor.h"

#include <algorithm>

#include "engine/core/parallel.h"

namespace zona {

void compute_tet_shapes(const Mesh& mesh, std::vector<TetShape<double>>& shapes, int threads) {
  shapes.resize(mesh.tet_count());
  const Vec3d* x = mesh.rest_positions.data();
  parallel_ranges(mesh.tet_count(), threads, 4096, [&](size_t, size_t begin, size_t end) {
    for (size_t t = begin; t < end; ++t) {
      const Tet& e = mesh.tets[t];
      shapes[t] = tet_shape_from_rest(x[e[0]], x[e[1]], x[e[2]], x[e[3]]);
    }
  });
}

void compute_mass_tensors(const std::vector<TetShape<double>>& shapes,
                          const std::vector<int32_t>& tet_material,
                          const std::vector<Lame>& material_lame, ConstitutiveModel model,
                          MassTensors& tensors, int thread_count) {
  const size_t nt = shapes.size();
  tensors.model = model;
  tensors.stride = model == ConstitutiveModel::kSvk ? kSvkTensorSize : kTensorBSize;
  tensors.values.resize(nt * static_cast<size_t>(tensors.stride));
  // Each tetrahedron's block is independent: a plain static split is deterministic.
  auto work = [&](size_t begin, size_t end) {
    for (size_t t = begin; t < end; ++t) {
      const Lame& l = material_lame[static_cast<size_t>(tet_material[t])];
      double* out = tensors.values.data() + t * static_cast<size_t>(tensors.stride);
      if (model == ConstitutiveModel::kSvk)
        svk_mass_tensors(shapes[t], l.lambda, l.mu, out);
      else
        linear_mass_tensor(shapes[t], l.lambda, l.mu, out);
    }
  };
  parallel_ranges(nt, thread_count, 256,
                  [&](size_t, size_t begin, size_t end) { work(begin, end); });
}

}  // namespace zona
