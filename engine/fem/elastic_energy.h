// The elastic energy of the whole model as an energy term (host, float64): value, gradient,
// Hessian-vector product and the Hessian's diagonal blocks, from elastic_term.h's element
// functions, with nodal pressure's vertex sums done in the force's two-pass shape. The explicit
// step's element passes (forces_cpu.cpp, kernels/) evaluate the same laws; tests hold the
// gradient here to their forces and the Hessian to finite differences of the gradient.
#pragma once

#include <span>
#include <vector>

#include "engine/core/base.h"
#include "engine/core/energy_term.h"
#include "engine/core/vec.h"
#include "engine/fem/elastic_term.h"
#include "engine/fem/model.h"

namespace zona {

/// The elastic energy term over a model. Holds the per-vertex scratch of nodal pressure (no
/// allocation after construction); every displacement array is (vertex_count), every vertex
/// counted, fixed ones included (a solver masks them).
class ElasticEnergy final : public EnergyTerm {
 public:
  /// Checks the model's law: the clamped SVK (InversionHandling::kClampStretch) has no energy
  /// of its own and is refused.
  static Result<ElasticEnergy> create(const Model& model);

  const char* name() const override { return "elastic"; }
  /// W(u) [J], u [m].
  double energy(std::span<const Vec3d> u) override;
  /// Adds dW/du at u to g [N] (the negated elastic forces).
  void add_gradient(std::span<const Vec3d> u, std::span<Vec3d> g) override {
    add_gradient_energy(u, g);
  }
  /// add_gradient, returning W(u) [J] from the same pass.
  double add_gradient_energy(std::span<const Vec3d> u, std::span<Vec3d> g);
  /// Adds (d^2 W / du^2) v to y [N], v [m].
  void add_hessian_product(std::span<const Vec3d> u, std::span<const Vec3d> v,
                           std::span<Vec3d> y) override;
  /// Adds the Hessian's 3 x 3 diagonal blocks to d [N/m].
  void add_hessian_diagonal(std::span<const Vec3d> u, std::span<Mat3d> d) override;
  /// The element parts' 12 x 12 Hessians, each exact or projected to positive semi-definite
  /// (its 9 x 9 d^2 Psi / dF^2 clamped at zero eigenvalues), assembled element colour by
  /// element colour over the machine's threads; plus nodal pressure's rank-one vertex terms
  /// exact (they are positive semi-definite), as the matrix's rank-one part (one term per
  /// vertex, its vector over the vertex's star).
  void add_hessian(std::span<const Vec3d> u, BlockSparseMatrix& h, bool project) override;
  /// The pattern of the Hessian: vertices sharing an element; with nodal pressure, the
  /// rank-one part's pattern (each vertex's star, in this term's order).
  static BlockSparseMatrix hessian_pattern(const Model& model);
  /// The volume barrier (elastic_term.h's volume_barrier) below volume ratio j0, of stiffness mu
  /// per element, on the stable neo-Hookean law; 0: off.
  void set_barrier(double j0) { barrier_volume_ = j0; }
  /// The smallest element volume ratio J at u (inf on an empty model).
  double min_volume_ratio(std::span<const Vec3d> u) const;

 private:
  explicit ElasticEnergy(const Model& model);
  // Nodal pressure: each vertex's lambda_v (Jbar_v - 1) [Pa] into pressure_, and returns the
  // vertices' volumetric energy sum_v V_v lambda_v / 2 (Jbar_v - 1)^2 [J].
  double vertex_pressures(std::span<const Vec3d> u);
  // The law of element t, with the corner mean of pressure_ under nodal pressure.
  ElementLaw<double> law(size_t t) const;
  void corners(std::span<const Vec3d> x, size_t t, Vec3d out[4]) const;

  const Model* model_;
  std::vector<double> pressure_;  // [Pa], (vertex_count)
  std::vector<double> scratch_;   // nodal sums [m^3] / [Pa], (vertex_count)
  double barrier_volume_ = 0;
  // Nodal pressure: each vertex's star (its elements' corners, first seen first) from
  // star_offsets_; star_gradient writes g_v over it to out (star size).
  void star_gradient(size_t v, std::span<const Vec3d> u, Vec3d* out) const;
  // Where add_hessian's blocks live in the matrix it was last given (found once per pattern):
  // 16 per element, (a, b) at 16 t + 4 a + b.
  void index_blocks(const BlockSparseMatrix& h);
  // Runs of kRun consecutive elements by colour (no two runs of a colour share a vertex),
  // colour c's from colour_offsets_[c] in colour_runs_; built once.
  void colour_runs();
  // f(t) on every element, colour by colour, each colour's runs side by side on the shared
  // pool (f may add into per-vertex arrays: no two runs of a colour share a vertex, and each
  // vertex takes its elements in colour order); returns the sum of f's values, summed per run
  // and the runs in order (the same bits for any thread count).
  template <class F>
  double coloured_sum(const F& f);
  std::vector<double> run_sum_;  // coloured_sum's per run, (run count)
  std::vector<double> chunk_sum_;  // vertex_pressures' energy per vertex chunk
  const int32_t* indexed_cols_ = nullptr;
  size_t indexed_blocks_ = 0;
  std::vector<int64_t> element_slot_;
  std::vector<int64_t> star_offsets_;
  std::vector<int32_t> star_;
  std::vector<uint8_t> star_slot_;  // corner c of adjacency entry k: its star position, at 4 k + c
  std::vector<Vec3d> element_dj_;   // add_hessian's V_e / 4 dJ_e/du per corner, (4 tet_count)
  std::vector<Vec3d> star_part_;
  std::vector<int64_t> colour_offsets_;
  static constexpr size_t kRun = 64;
  std::vector<int32_t> colour_runs_;
};

}  // namespace zona
