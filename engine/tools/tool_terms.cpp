// The tools' energy terms (tool_terms.h): penalty.h's per-point laws summed over surface points.
#include "engine/tools/tool_terms.h"

namespace zona {

PenaltyContactTerm::PenaltyContactTerm(const char* name, ToolField field,
                                       std::span<const Vec3d> rest,
                                       std::span<const int32_t> vertex,
                                       std::span<const double> area, double kappa, double mu)
    : name_(name),
      field_(field),
      rest_(rest),
      vertex_(vertex),
      area_(area),
      kappa_(kappa),
      mu_(mu),
      lagged_(vertex.size()),
      anchor_(vertex.size()) {
  ZONA_ASSERT(vertex.size() == area.size());
}

Vec3d PenaltyContactTerm::position(std::span<const Vec3d> u, size_t i) const {
  const size_t v = static_cast<size_t>(vertex_[i]);
  return rest_[v] + u[v];
}

double PenaltyContactTerm::energy(std::span<const Vec3d> u) {
  double e = 0;
  for (size_t i = 0; i < vertex_.size(); ++i) {
    const Vec3d x = position(u, i);
    const double k = stiffness(i);
    e += penalty_energy(k, field_.eval(x).distance);
    const Lagged& l = lagged_[i];
    if (l.cap > 0) e += friction_energy(k, l.cap, l.normal, x - field_.origin - l.anchor);
  }
  return e;
}

void PenaltyContactTerm::add_gradient(std::span<const Vec3d> u, std::span<Vec3d> g) {
  for (size_t i = 0; i < vertex_.size(); ++i) {
    const Vec3d x = position(u, i);
    const double k = stiffness(i);
    Vec3d gi = penalty_gradient(k, field_.eval(x));
    const Lagged& l = lagged_[i];
    if (l.cap > 0) gi += friction_gradient(k, l.cap, l.normal, x - field_.origin - l.anchor);
    g[static_cast<size_t>(vertex_[i])] += gi;
  }
}

Mat3d PenaltyContactTerm::point_hessian(std::span<const Vec3d> u, size_t i) const {
  const Vec3d x = position(u, i);
  const double k = stiffness(i);
  Mat3d hess_phi;
  const ToolSdf sdf = field_.eval(x, &hess_phi);
  Mat3d h = penalty_hessian(k, sdf, hess_phi);
  const Lagged& l = lagged_[i];
  if (l.cap > 0) h = h + friction_hessian(k, l.cap, l.normal, x - field_.origin - l.anchor);
  return h;
}

void PenaltyContactTerm::add_hessian_product(std::span<const Vec3d> u, std::span<const Vec3d> v,
                                             std::span<Vec3d> y) {
  for (size_t i = 0; i < vertex_.size(); ++i) {
    const size_t w = static_cast<size_t>(vertex_[i]);
    y[w] += point_hessian(u, i) * v[w];
  }
}

void PenaltyContactTerm::add_hessian_diagonal(std::span<const Vec3d> u, std::span<Mat3d> d) {
  for (size_t i = 0; i < vertex_.size(); ++i) {
    Mat3d& block = d[static_cast<size_t>(vertex_[i])];
    block = block + point_hessian(u, i);
  }
}

void PenaltyContactTerm::lag(std::span<const Vec3d> u, int64_t step) {
  step_ = step;
  for (size_t i = 0; i < vertex_.size(); ++i) {
    const Vec3d x = position(u, i);
    const ToolSdf sdf = field_.eval(x);
    Lagged& l = lagged_[i];
    if (!(sdf.distance < 0) || !(mu_ > 0)) {
      l = Lagged{};
      continue;
    }
    l.normal = sdf.normal;
    l.cap = mu_ * stiffness(i) * (-sdf.distance);
    l.anchor = stick_anchor_in_step(anchor_[i], step, x - field_.origin);
  }
}

void PenaltyContactTerm::commit(std::span<const Vec3d> u) {
  for (size_t i = 0; i < vertex_.size(); ++i) {
    const Lagged& l = lagged_[i];
    if (!(l.cap > 0)) continue;
    const Vec3d rel = position(u, i) - field_.origin;
    anchor_[i] = stick_anchor_commit(
        penalty_anchor_after(stiffness(i), l.cap, l.normal, rel, l.anchor), step_);
  }
}

int64_t PenaltyContactTerm::lagged_contacts() const {
  int64_t n = 0;
  for (const Lagged& l : lagged_) n += l.cap > 0 ? 1 : 0;
  return n;
}

SuctionTerm::SuctionTerm(std::span<const int32_t> vertex, std::span<const Vec3d> load)
    : vertex_(vertex), load_(load) {
  ZONA_ASSERT(vertex.size() == load.size());
}

double SuctionTerm::energy(std::span<const Vec3d> u) {
  double e = 0;
  for (size_t i = 0; i < vertex_.size(); ++i)
    e -= ramp_ * dot(load_[i], u[static_cast<size_t>(vertex_[i])]);
  return e;
}

void SuctionTerm::add_gradient(std::span<const Vec3d> u, std::span<Vec3d> g) {
  (void)u;
  for (size_t i = 0; i < vertex_.size(); ++i)
    g[static_cast<size_t>(vertex_[i])] -= ramp_ * load_[i];
}

}  // namespace zona
