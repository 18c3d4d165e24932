// Puncture criterion, force release and shaft drag.
#include "engine/tools/puncture.h"

#include <algorithm>
#include <cmath>

#include "engine/fem/fem_element.h"

namespace zona {

double puncture_release_factor(const PunctureDef& def, double elapsed) {
  const double progress = def.drop_time > 0 ? std::clamp(elapsed / def.drop_time, 0.0, 1.0) : 1.0;
  return 1.0 - def.force_drop * progress;
}

double max_principal_strain_around(const Model& model, std::span<const Vec3d> u,
                                   std::span<const int32_t> vertices,
                                   std::span<const uint8_t> tet_counts) {
  double largest = 0;
  const VertexTetAdjacency& adj = model.adjacency;
  for (int32_t v : vertices) {
    for (int32_t k = adj.offsets[static_cast<size_t>(v)]; k < adj.offsets[static_cast<size_t>(v) + 1]; ++k) {
      const size_t t = static_cast<size_t>(adj.tets[static_cast<size_t>(k)]);
      if (!tet_counts.empty() && !tet_counts[t]) continue;
      const Tet& e = model.tets[t];
      const Vec3d ue[4] = {u[e[0]], u[e[1]], u[e[2]], u[e[3]]};
      const Mat3d strain = green_strain(tet_displacement_gradient(model.tet_shape[t], ue));
      double eig[3];
      Mat3d vectors;
      symmetric_eigen3(strain, eig, &vectors);
      largest = std::max({largest, eig[0], eig[1], eig[2]});
    }
  }
  return largest;
}

Puncture::Puncture(const PunctureDef& def, Vec3d direction, size_t capacity)
    : def_(def), direction_(direction), vertices_(capacity, -1), forces_(capacity, Vec3d{0, 0, 0}) {}

bool Puncture::criterion_met(const PunctureInputs& in) const {
  if (record_.punctured) return false;
  switch (def_.criterion) {
    case PunctureCriterion::kNone: return false;
    case PunctureCriterion::kForce: return in.force >= def_.threshold;
    case PunctureCriterion::kStrain: return in.max_strain >= def_.threshold;
    case PunctureCriterion::kEnergy: return in.energy >= def_.threshold;
  }
  return false;
}

void Puncture::trigger(const PunctureRecord& record, std::span<const Contact> contacts) {
  record_ = record;
  record_.punctured = true;
  count_ = std::min(contacts.size(), vertices_.size());
  released_total_ = Vec3d{0, 0, 0};
  for (size_t i = 0; i < count_; ++i) {
    vertices_[i] = contacts[i].vertex;
    forces_[i] = contacts[i].static_reaction;
    released_total_ += contacts[i].static_reaction;
  }
}

Vec3d Puncture::body_force(double time, double travel) const {
  if (!record_.punctured) return Vec3d{0, 0, 0};
  const double factor = puncture_release_factor(def_, time - record_.time);
  const double inserted = std::max(0.0, travel - record_.needle_travel);
  return factor * released_total_ + (def_.shaft_friction * inserted) * direction_;
}

double Puncture::apply_loads(double time, double travel, std::span<Vec3d> external) const {
  if (!record_.punctured) return 0;
  const double factor = puncture_release_factor(def_, time - record_.time);
  const double inserted = std::max(0.0, travel - record_.needle_travel);
  const double drag = def_.shaft_friction * inserted;
  // The drag pulls the rim of the hole along with the needle: spread it over the released
  // vertices (with none, the needle still feels it; the body's share is dropped).
  const Vec3d drag_each =
      count_ > 0 ? (drag / static_cast<double>(count_)) * direction_ : Vec3d{0, 0, 0};
  for (size_t i = 0; i < count_; ++i)
    external[static_cast<size_t>(vertices_[i])] += factor * forces_[i] + drag_each;
  return factor * dot(released_total_, direction_) + drag;
}

}  // namespace zona
