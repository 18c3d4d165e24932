// The tools' energy terms (engine/core/energy_term.h) on the cell's surface points: a tool's
// penalty contact with its friction (the needle's, the holding rim's), and the suction as a dead
// load. The per-point laws are engine/tools/penalty.h's, the ones the explicit step calls.
//
// Friction is an incremental potential: within a step its normal, its Coulomb cap and its
// anchors are held (lag(), from the last accepted state), so the term is a function of u alone
// and a line search may evaluate it anywhere; commit() moves the anchors of the points that
// slid, once the step is accepted. Evaluated at the lagged state itself, its gradient is the
// explicit step's friction force.
#pragma once

#include <array>
#include <cstdint>
#include <span>
#include <vector>

#include "engine/core/energy_term.h"
#include "engine/tools/penalty.h"
#include "engine/tools/tool_sdf.h"

namespace zona {

/// A tool's surface as a distance field at one pose: the needle (tip, direction, radius, flat
/// tip) or the holding pipette's wall (mouth, axis, inner / outer / edge radii). Lengths [m].
struct ToolField {
  enum class Kind { kNeedle, kRim } kind = Kind::kNeedle;
  Vec3d origin{0, 0, 0};  ///< the needle's tip or the rim's mouth: friction's reference point
  Vec3d axis{1, 0, 0};    ///< the needle's direction or the rim's axis (unit)
  double radius = 0;      ///< needle radius, or the rim's inner radius
  double outer_radius = 0, edge_radius = 0;  ///< the rim's
  bool flat = false;                         ///< the needle's flat tip

  /// Distance, normal and (optionally) Hessian at x.
  ToolSdf eval(Vec3d x, Mat3d* hessian = nullptr) const {
    if (kind == Kind::kNeedle) return needle_sdf(origin, axis, radius, flat, x, hessian);
    return holding_sdf(origin, axis, radius, outer_radius, x, edge_radius, hessian);
  }
};

/// A contact point on the cell's surface: a vertex, or a point of a surface triangle (its
/// corners' barycentric combination), with its share of the rest area.
struct ContactPoint {
  int32_t vertex[3] = {0, 0, 0};  ///< model vertex indices; unused corners have weight 0
  double weight[3] = {1, 0, 0};   ///< barycentric weights [-]
  double area = 0;                ///< rest area the point carries [m^2]
};

/// Contact points at vertices (weight 1 each), of rest areas `area` [m^2].
std::vector<ContactPoint> vertex_contact_points(std::span<const int32_t> vertex,
                                                std::span<const double> area);
/// The needle's face quadrature (penalty.h's kFacePoints per triangle): triangles by model
/// vertex indices and rest areas [m^2].
std::vector<ContactPoint> face_contact_points(std::span<const std::array<int32_t, 3>> faces,
                                              std::span<const double> area);

/// Penalty contact of a tool on surface points, with Coulomb friction as an incremental
/// potential. Per point: energy k phi^2 / 2 inside the tool (k = kappa x area) plus, where the
/// lagged state was in contact, the friction potential about its anchor; a face point's
/// energy is that of its position, so its gradient reaches the corners by their weights.
///
/// (The explicit step's face law pushes along the triangle's normal where the triangle faces
/// away from the tool, which is no gradient; here the load follows the distance field's normal,
/// the one conservative choice: docs/static.md.)
class PenaltyContactTerm final : public EnergyTerm {
 public:
  /// `rest`: rest positions [m], (vertex_count), which must outlive the term; kappa [Pa/m];
  /// mu [-]; stick_length: the friction's stick zone at least this wide [m]
  /// (friction_stiffness).
  PenaltyContactTerm(const char* name, ToolField field, std::span<const Vec3d> rest,
                     std::vector<ContactPoint> points, double kappa, double mu,
                     double stick_length = 0);
  /// At vertices (vertex_contact_points).
  PenaltyContactTerm(const char* name, ToolField field, std::span<const Vec3d> rest,
                     std::span<const int32_t> vertex, std::span<const double> area, double kappa,
                     double mu, double stick_length = 0)
      : PenaltyContactTerm(name, field, rest, vertex_contact_points(vertex, area), kappa, mu,
                           stick_length) {}

  const char* name() const override { return name_; }
  double energy(std::span<const Vec3d> u) override;
  void add_gradient(std::span<const Vec3d> u, std::span<Vec3d> g) override;
  void add_hessian_product(std::span<const Vec3d> u, std::span<const Vec3d> v,
                           std::span<Vec3d> y) override;
  void add_hessian_diagonal(std::span<const Vec3d> u, std::span<Mat3d> d) override;
  void add_hessian(std::span<const Vec3d> u, BlockSparseMatrix& h, bool project) override;

  /// The tool's pose for the coming step.
  void set_field(const ToolField& field) { field_ = field; }
  const ToolField& field() const { return field_; }
  /// Holds the friction's normal, cap and anchor of each point from the accepted state u for
  /// the coming step `step` (a point out of contact there gets none).
  void lag(std::span<const Vec3d> u, int64_t step);
  /// After the step is accepted at u: the anchors of the points that slid follow them. Returns
  /// how many of the lagged contacts slid.
  int64_t commit(std::span<const Vec3d> u);
  /// Points in contact in the lagged state.
  int64_t lagged_contacts() const;

  /// What the tool does at u: the force it applies to the cell [N] (minus the gradient's sum),
  /// the points inside it and the deepest one's depth [m].
  struct Load {
    Vec3d force{0, 0, 0};
    int64_t contacts = 0;
    double depth = 0;
  };
  Load load(std::span<const Vec3d> u) const;

 private:
  struct Lagged {
    Vec3d normal{0, 0, 0};
    double cap = 0;  // mu x normal force [N]; 0: no friction this step
    double kt = 0;   // the friction spring's stiffness (friction_stiffness) [N/m]
    Vec3d anchor{0, 0, 0};
  };
  Vec3d position(std::span<const Vec3d> u, size_t i) const;
  double stiffness(size_t i) const { return kappa_ * points_[i].area; }
  // The point's gradient and Hessian block (normal and friction), unscaled.
  Vec3d point_gradient(std::span<const Vec3d> u, size_t i) const;
  Mat3d point_hessian(std::span<const Vec3d> u, size_t i, bool project) const;

  const char* name_;
  ToolField field_;
  std::span<const Vec3d> rest_;
  std::vector<ContactPoint> points_;
  double kappa_, mu_, stick_length_;
  int64_t step_ = 0;
  std::vector<Lagged> lagged_;       // (point count)
  std::vector<StickAnchor> anchor_;  // committed anchors, (point count)
  // The passes over the points run on the shared pool: each point's gradient or Hessian block
  // into these (added to the vertices after, in point order), the energy per fixed chunk.
  std::vector<Vec3d> point_grad_;
  std::vector<Mat3d> point_hess_;
  std::vector<uint8_t> point_on_;
  std::vector<double> chunk_sum_;
  // Where each point's 3 x 3 corner pairs (a, b) live in the matrix add_hessian was last given
  // (-1: a zero weight), found once per pattern: 9 per point, (a, b) at 9 i + 3 a + b.
  std::vector<int64_t> point_slot_;
  const int32_t* slotted_cols_ = nullptr;
  size_t slotted_blocks_ = 0;
};

/// A dead load: E = -ramp sum_v f_v . u_v, f the full load [N] per vertex, ramp >= 0. The
/// suction on the aspirated patch; in the static solver, the needle's load after a puncture.
class SuctionTerm final : public EnergyTerm {
 public:
  SuctionTerm(std::span<const int32_t> vertex, std::span<const Vec3d> load,
              const char* name = "suction");
  const char* name() const override { return name_; }
  double energy(std::span<const Vec3d> u) override;
  void add_gradient(std::span<const Vec3d> u, std::span<Vec3d> g) override;
  void add_hessian_product(std::span<const Vec3d>, std::span<const Vec3d>,
                           std::span<Vec3d>) override {}
  void add_hessian_diagonal(std::span<const Vec3d>, std::span<Mat3d>) override {}
  void add_hessian(std::span<const Vec3d>, BlockSparseMatrix&, bool) override {}
  void set_ramp(double ramp) { ramp_ = ramp; }

 private:
  std::span<const int32_t> vertex_;
  std::span<const Vec3d> load_;
  double ramp_ = 1;
  const char* name_;
};

}  // namespace zona
