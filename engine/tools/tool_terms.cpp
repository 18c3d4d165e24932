// The tools' energy terms (tool_terms.h): penalty.h's per-point laws summed over surface points.
#include "engine/tools/tool_terms.h"

#include <algorithm>

#include "engine/core/parallel.h"
#include "engine/fem/fem_element.h"

namespace zona {
namespace {
// Points per chunk of the passes over the contact points (pooled_chunks).
constexpr size_t kPointChunk = 2048;
}  // namespace

std::vector<ContactPoint> vertex_contact_points(std::span<const int32_t> vertex,
                                                std::span<const double> area) {
  ZONA_ASSERT(vertex.size() == area.size());
  std::vector<ContactPoint> points(vertex.size());
  for (size_t i = 0; i < vertex.size(); ++i) {
    points[i].vertex[0] = points[i].vertex[1] = points[i].vertex[2] = vertex[i];
    points[i].area = area[i];
  }
  return points;
}

std::vector<ContactPoint> face_contact_points(std::span<const std::array<int32_t, 3>> faces,
                                              std::span<const double> area) {
  ZONA_ASSERT(faces.size() == area.size());
  std::vector<ContactPoint> points;
  points.reserve(faces.size() * kFacePoints);
  for (size_t f = 0; f < faces.size(); ++f)
    for (int q = 0; q < kFacePoints; ++q) {
      ContactPoint p;
      face_point_weights(q, &p.weight[1], &p.weight[2]);
      p.weight[0] = 1.0 - p.weight[1] - p.weight[2];
      for (int c = 0; c < 3; ++c) p.vertex[c] = faces[f][static_cast<size_t>(c)];
      p.area = area[f] / kFacePoints;
      points.push_back(p);
    }
  return points;
}

PenaltyContactTerm::PenaltyContactTerm(const char* name, ToolField field,
                                       std::span<const Vec3d> rest,
                                       std::vector<ContactPoint> points, double kappa, double mu,
                                       double stick_length)
    : name_(name),
      field_(field),
      rest_(rest),
      points_(std::move(points)),
      kappa_(kappa),
      mu_(mu),
      stick_length_(stick_length),
      lagged_(points_.size()),
      anchor_(points_.size()),
      point_grad_(points_.size()),
      point_hess_(points_.size()),
      point_on_(points_.size(), 0) {}

Vec3d PenaltyContactTerm::position(std::span<const Vec3d> u, size_t i) const {
  const ContactPoint& p = points_[i];
  Vec3d x{0, 0, 0};
  for (int c = 0; c < 3; ++c) {
    if (p.weight[c] == 0) continue;
    const size_t v = static_cast<size_t>(p.vertex[c]);
    x += p.weight[c] * (rest_[v] + u[v]);
  }
  return x;
}

double PenaltyContactTerm::energy(std::span<const Vec3d> u) {
  return pooled_chunk_sum(points_.size(), kPointChunk, chunk_sum_, [&](size_t begin, size_t end) {
    double e = 0;
    for (size_t i = begin; i < end; ++i) {
      const Vec3d x = position(u, i);
      const double k = stiffness(i);
      e += penalty_energy(k, field_.eval(x).distance);
      const Lagged& l = lagged_[i];
      if (l.cap > 0) e += friction_energy(l.kt, l.cap, l.normal, x - field_.origin - l.anchor);
    }
    return e;
  });
}

Vec3d PenaltyContactTerm::point_gradient(std::span<const Vec3d> u, size_t i) const {
  const Vec3d x = position(u, i);
  const double k = stiffness(i);
  Vec3d g = penalty_gradient(k, field_.eval(x));
  const Lagged& l = lagged_[i];
  if (l.cap > 0) g += friction_gradient(l.kt, l.cap, l.normal, x - field_.origin - l.anchor);
  return g;
}

void PenaltyContactTerm::add_gradient(std::span<const Vec3d> u, std::span<Vec3d> g) {
  pooled_chunks(points_.size(), kPointChunk, [&](size_t, size_t begin, size_t end) {
    for (size_t i = begin; i < end; ++i) point_grad_[i] = point_gradient(u, i);
  });
  for (size_t i = 0; i < points_.size(); ++i) {
    const Vec3d gi = point_grad_[i];
    if (gi.x == 0 && gi.y == 0 && gi.z == 0) continue;
    const ContactPoint& p = points_[i];
    for (int c = 0; c < 3; ++c)
      if (p.weight[c] != 0) g[static_cast<size_t>(p.vertex[c])] += p.weight[c] * gi;
  }
}

Mat3d PenaltyContactTerm::point_hessian(std::span<const Vec3d> u, size_t i, bool project) const {
  const Vec3d x = position(u, i);
  const double k = stiffness(i);
  Mat3d hess_phi;
  const ToolSdf sdf = field_.eval(x, &hess_phi);
  Mat3d h = penalty_hessian(k, sdf, hess_phi);
  if (project && sdf.distance < 0) {
    // phi hess(phi) bends with the tool's surface: negative semi-definite on a convex tool.
    double ev[3];
    Mat3d q;
    symmetric_eigen3(h, ev, &q);
    Mat3d d = Mat3d::zero();
    for (int a = 0; a < 3; ++a) d.m[a][a] = ev[a] > 0 ? ev[a] : 0.0;
    h = q * d * transpose(q);
  }
  const Lagged& l = lagged_[i];
  if (l.cap > 0) h = h + friction_hessian(l.kt, l.cap, l.normal, x - field_.origin - l.anchor);
  return h;
}

void PenaltyContactTerm::add_hessian_product(std::span<const Vec3d> u, std::span<const Vec3d> v,
                                             std::span<Vec3d> y) {
  for (size_t i = 0; i < points_.size(); ++i) {
    const ContactPoint& p = points_[i];
    Vec3d vp{0, 0, 0};
    for (int c = 0; c < 3; ++c)
      if (p.weight[c] != 0) vp += p.weight[c] * v[static_cast<size_t>(p.vertex[c])];
    const Vec3d hv = point_hessian(u, i, false) * vp;
    for (int c = 0; c < 3; ++c)
      if (p.weight[c] != 0) y[static_cast<size_t>(p.vertex[c])] += p.weight[c] * hv;
  }
}

void PenaltyContactTerm::add_hessian_diagonal(std::span<const Vec3d> u, std::span<Mat3d> d) {
  for (size_t i = 0; i < points_.size(); ++i) {
    const ContactPoint& p = points_[i];
    const Mat3d h = point_hessian(u, i, false);
    // Corners that name the same vertex (a vertex point) add their weights' products.
    for (int a = 0; a < 3; ++a)
      for (int b = 0; b < 3; ++b) {
        if (p.weight[a] == 0 || p.weight[b] == 0 || p.vertex[a] != p.vertex[b]) continue;
        Mat3d& block = d[static_cast<size_t>(p.vertex[a])];
        block = block + (p.weight[a] * p.weight[b]) * h;
      }
  }
}

void PenaltyContactTerm::add_hessian(std::span<const Vec3d> u, BlockSparseMatrix& hm,
                                     bool project) {
  pooled_chunks(points_.size(), kPointChunk, [&](size_t, size_t begin, size_t end) {
    for (size_t i = begin; i < end; ++i) {
      point_on_[i] = field_.eval(position(u, i)).distance < 0 || lagged_[i].cap > 0 ? 1 : 0;
      if (point_on_[i]) point_hess_[i] = point_hessian(u, i, project);
    }
  });
  if (slotted_cols_ != hm.cols().data() || slotted_blocks_ != hm.block_count()) {
    point_slot_.assign(9 * points_.size(), -1);
    for (size_t i = 0; i < points_.size(); ++i) {
      const ContactPoint& p = points_[i];
      for (int a = 0; a < 3; ++a)
        for (int b = 0; b < 3; ++b) {
          if (p.weight[a] == 0 || p.weight[b] == 0) continue;
          point_slot_[9 * i + static_cast<size_t>(3 * a + b)] =
              hm.block_index(p.vertex[a], p.vertex[b]);
        }
    }
    slotted_cols_ = hm.cols().data();
    slotted_blocks_ = hm.block_count();
  }
  // Into the blocks in point order (points share blocks).
  std::span<Mat3d> values = hm.values();
  for (size_t i = 0; i < points_.size(); ++i) {
    const ContactPoint& p = points_[i];
    if (!point_on_[i]) continue;
    const Mat3d& h = point_hess_[i];
    for (int a = 0; a < 3; ++a)
      for (int b = 0; b < 3; ++b)
        if (p.weight[a] != 0 && p.weight[b] != 0) {
          Mat3d& block =
              values[static_cast<size_t>(point_slot_[9 * i + static_cast<size_t>(3 * a + b)])];
          block = block + (p.weight[a] * p.weight[b]) * h;
        }
  }
}

void PenaltyContactTerm::lag(std::span<const Vec3d> u, int64_t step) {
  step_ = step;
  for (size_t i = 0; i < points_.size(); ++i) {
    const Vec3d x = position(u, i);
    const ToolSdf sdf = field_.eval(x);
    Lagged& l = lagged_[i];
    if (!(sdf.distance < 0) || !(mu_ > 0)) {
      l = Lagged{};
      continue;
    }
    l.normal = sdf.normal;
    l.cap = mu_ * stiffness(i) * (-sdf.distance);
    l.kt = friction_stiffness(stiffness(i), l.cap, stick_length_);
    l.anchor = stick_anchor_in_step(anchor_[i], step, x - field_.origin);
  }
}

int64_t PenaltyContactTerm::commit(std::span<const Vec3d> u) {
  int64_t slid = 0;
  for (size_t i = 0; i < points_.size(); ++i) {
    const Lagged& l = lagged_[i];
    if (!(l.cap > 0)) continue;
    const Vec3d rel = position(u, i) - field_.origin;
    const Vec3d after = penalty_anchor_after(l.kt, l.cap, l.normal, rel, l.anchor);
    if (!(after.x == l.anchor.x && after.y == l.anchor.y && after.z == l.anchor.z)) ++slid;
    anchor_[i] = stick_anchor_commit(after, step_);
  }
  return slid;
}

int64_t PenaltyContactTerm::lagged_contacts() const {
  int64_t n = 0;
  for (const Lagged& l : lagged_) n += l.cap > 0 ? 1 : 0;
  return n;
}

PenaltyContactTerm::Load PenaltyContactTerm::load(std::span<const Vec3d> u) const {
  Load out;
  for (size_t i = 0; i < points_.size(); ++i) {
    const Vec3d x = position(u, i);
    const double phi = field_.eval(x).distance;
    if (phi < 0) {
      ++out.contacts;
      out.depth = std::max(out.depth, -phi);
    }
    out.force -= point_gradient(u, i);
  }
  return out;
}

SuctionTerm::SuctionTerm(std::span<const int32_t> vertex, std::span<const Vec3d> load,
                         const char* name)
    : vertex_(vertex), load_(load), name_(name) {
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
