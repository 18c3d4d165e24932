// Tool-cell contact: the boundary surface with its adjacency (built once), Ladjal et al.'s
// ray-triangle intersection with a local search from the last hit triangle, and the kinematic
// contact constraint with Coulomb friction used by the needle and the holding pipette's rim.
//
// Contact model (measured choice, docs/injection.md): a surface vertex that enters a rigid tool
// is held on the tool surface as a prescribed vertex of the explicit integrator; the
// integrator's constraint force on it is the contact reaction, and the needle force is minus
// their sum. No penalty stiffness to tune, no penetration, and in quasi-static loading the
// reaction equals the elastic force the body pushes back with. Each step, after the integrator:
//  - a contact whose normal reaction pulls (the body wants to leave) by more than a small
//    tolerance is released (the release rule below);
//  - a contact whose tangential reaction exceeds mu times the normal one slips: its anchor on
//    the tool moves against the excess by the step's compliance dt^2 / M (a return mapping);
//  - free surface vertices found inside the tool (a local search from the last contacts) are
//    added at their projection on the tool surface;
// and every contact's target is its anchor carried along with the tool's next pose.
//
// The release rule, made robust to rounding (issue 9). A release is a discrete decision that
// changes the experiment from then on (the vertex may be re-taken at another anchor, or as a
// face contact that sticks), so it must not be taken on a reaction that is rounding noise:
//  - A contact is not judged (neither released nor slid) until its reaction has been measured
//    on the tool. The reaction is measured with a one-step lag: the first measurement after the
//    take is -(f_el + f_ext) at u_n, the free vertex before it was put on the tool, not the
//    contact's force. On a quiet, unloaded surface that force is zero up to rounding (exactly
//    zero on the CPU, where an unloaded particle membrane has exactly zero forces; +-1e-18 N on
//    the GPU, whose volume sum runs in another order), and its sign decided which of the tip's
//    first contacts survived (docs/particles.md).
//  - A measured contact is released when its normal reaction pulls by more than
//    kContactReleaseTolerance times the mean quasi-static reaction |r| of the set's measured
//    contacts. Rounding noise in a vertex's force is about 1e-16 (float64) to 1e-7 (float32
//    forces on the GPU) of the forces summed into it, far below 1e-3 of a typical contact's
//    load, so noise around zero falls on the keep side. It is not sticky: a kept contact pulls
//    the body by at most 0.1 % of the mean contact load (the whole set by at most 0.1 % of its
//    load), and a contact whose reaction falls through zero at a rate of r per step is released
//    at most 1e-3 mean / r steps late (a step or two when the tool is pulled away; tested).
//  - In the friction test a measured contact's normal reaction counts only where it pushes: a
//    kept contact with rn <= 0 has a cone of zero radius and slides freely.
#pragma once

#include <array>
#include <cstdint>
#include <span>
#include <vector>

#include "engine/tools/holding.h"
#include "engine/mesh/mesh.h"
#include "engine/fem/model.h"
#include "engine/tools/needle.h"
#include "engine/core/vec.h"

namespace zona {

/// The boundary surface with what contact queries need, built once from the rest mesh.
struct ContactSurface {
  std::vector<Triangle> triangles;        ///< outward counter-clockwise, (triangle_count)
  /// Triangle across edge e (corners e, e+1 mod 3) of each triangle, -1 on an open edge.
  std::vector<std::array<int32_t, 3>> triangle_neighbors;
  std::vector<int32_t> vertices;          ///< mesh indices of surface vertices, sorted
  std::vector<int32_t> surface_index;     ///< mesh vertex -> index in `vertices`, -1 if inside
  std::vector<int32_t> neighbor_offsets;  ///< surface vertex graph (CSR), (surface count + 1)
  std::vector<int32_t> neighbors;         ///< surface indices of edge neighbours
  std::vector<double> vertex_area;        ///< rest tributary area, a third of each incident
                                          ///< triangle [m^2], (surface count)
  double max_edge = 0;                    ///< longest surface edge at rest [m]
  double area = 0;                        ///< total rest surface area [m^2]
};

/// Builds the contact surface of a mesh (extract_boundary plus adjacency and areas).
/// Errors: an empty boundary, or an edge shared by more than two triangles.
Result<ContactSurface> build_contact_surface(const Mesh& mesh);

/// Ray-triangle intersection (Moller-Trumbore): the ray origin + t dir meets the triangle
/// (a, b, c) at t with barycentric weights (1 - b1 - b2, b1, b2). Returns false when the ray is
/// parallel to the triangle's plane. The weights are written even when they lie outside [0, 1]
/// (the local search uses them to choose where to walk).
bool ray_triangle(Vec3d origin, Vec3d dir, Vec3d a, Vec3d b, Vec3d c, double* t, double* b1,
                  double* b2);

/// A ray's first hit on the surface.
struct RayHit {
  int32_t triangle = -1;   ///< hit triangle, -1: no hit
  double t = 0;            ///< ray parameter [m] (dir is unit)
  Vec3d point{0, 0, 0};    ///< hit point [m]
  int walk_steps = 0;      ///< triangles visited by the local search
  bool global_scan = false;  ///< the local search failed and every triangle was tested
};

/// Casts the ray origin + t dir (dir unit, t > 0) against the deformed surface (positions
/// rest + u) and returns its first hit on a triangle facing the ray. Ladjal et al.'s method: walk
/// from `start_triangle` (the last hit) across the edge with the most negative barycentric
/// weight until the containing triangle is found (at most `max_walk` steps); if that fails (no
/// start, a silhouette, a fold), test every triangle and keep the nearest hit. Never allocates.
RayHit cast_ray(const ContactSurface& surface, std::span<const Vec3d> rest,
                std::span<const Vec3d> u, Vec3d origin, Vec3d dir, int32_t start_triangle,
                int max_walk = 256);

/// A rigid contact tool: the needle (moving) or the holding pipette's wall (static).
struct ContactTool {
  enum class Kind { kNeedle, kHolding };
  Kind kind = Kind::kNeedle;
  NeedleGeometry needle;      ///< kNeedle
  HoldingGeometry holding;    ///< kHolding (at its fixed pose; origin stays 0)
  double friction = 0.3;      ///< Coulomb coefficient tool-cell [-]
};

/// Signed distance from the tool at pose `origin` [m] (the needle tip; 0 for the holding wall).
ToolDistance tool_distance(const ContactTool& tool, Vec3d origin, Vec3d x);

/// One vertex held on a tool.
struct Contact {
  int32_t vertex = -1;       ///< mesh vertex index
  Vec3d anchor{0, 0, 0};     ///< held point on the tool surface, relative to the tool origin [m]
  Vec3d normal{0, 0, 0};     ///< tool outward normal at the anchor [-]
  Vec3d u_before{0, 0, 0};   ///< displacement at t_{n-1} of the last step [m]
  /// Force the tool applied to the body over the last step, M a + gamma v - f_el - f_ext [N].
  Vec3d reaction{0, 0, 0};
  /// Its quasi-static part, -(f_el + f_ext): what the deformed body pushes the tool with [N].
  /// The inertial rest is mostly fictitious (mass scaling) and jitters with every target
  /// change, so release, friction and the published needle force use this part.
  Vec3d static_reaction{0, 0, 0};
  bool slipping = false;     ///< the last friction check found it sliding
  /// Reaction measurements since the take (saturates at 2). The first is of the free vertex
  /// before it was put on the tool (the one-step lag): the contact is judged from the second.
  int32_t measurements = 0;
  /// Held by Ladjal et al.'s face contact (the tip point pierced a triangle whose corners lie outside
  /// the tool): the anchor is the corner carried with the tip, not a point of the tool surface,
  /// and it sticks.
  bool face = false;
};

/// Release tolerance: a measured contact is released when its normal reaction pulls by more
/// than this fraction of the mean |quasi-static reaction| of the set's measured contacts [-]
/// (the file comment says why 1e-3).
inline constexpr double kContactReleaseTolerance = 1e-3;

/// Counters of one contact update.
struct ContactUpdate {
  int32_t added = 0;
  int32_t released = 0;
  int32_t slipping = 0;
  bool overflow = false;     ///< more vertices touched than the set's capacity
};

/// The contacts of one tool. Capacity fixed at creation; updates never allocate.
class ContactSet {
 public:
  /// A set for `tool` on a mesh of `vertex_count` vertices with boundary `surface`, holding at
  /// most `capacity` contacts.
  ContactSet(const ContactTool& tool, const ContactSurface& surface, size_t vertex_count,
             size_t capacity);

  const ContactTool& tool() const { return tool_; }
  std::span<const Contact> contacts() const { return {contacts_.data(), count_}; }
  size_t size() const { return count_; }
  size_t capacity() const { return contacts_.size(); }

  /// After a step: each contact's reaction from the step's history (call before update()).
  /// `u` holds u_{n+1}, `u_prev` u_n, `force` the elastic force at u_n, `external` the loads.
  void measure_reactions(const Model& model, std::span<const Vec3d> u,
                         std::span<const Vec3d> u_prev, std::span<const Vec3d> force,
                         std::span<const Vec3d> external);

  /// For a step made of several sub-steps with the targets moving linearly: sets each contact's
  /// u_{n-1} to 2 u_n - u_{n+1} (its last sub-step's history). Call before measure_reactions.
  void set_linear_history(std::span<const Vec3d> u, std::span<const Vec3d> u_prev);

  /// Releases pulling contacts (measured ones only, beyond the tolerance: the release rule
  /// above), applies friction, and adds the free vertices found inside the
  /// tool at pose `origin` (configuration rest + u): surface vertices, and interior ones where
  /// the surface layer has been crushed. New contacts are searched breadth-first through the
  /// mesh (vertices sharing a tetrahedron, expanding within `search_margin` [m] of the tool)
  /// from the current contacts and `seeds` (mesh vertex indices), or among all vertices when
  /// `full_scan`. `taken` marks
  /// vertices that are not free (fixed, prescribed by another tool): 1 = skip. `relax` scales
  /// the slip correction (1 = the full return mapping).
  ContactUpdate update(const Model& model, std::span<const Vec3d> u, Vec3d origin,
                       std::span<const int32_t> seeds, std::span<const uint8_t> taken,
                       bool full_scan, double search_margin, double relax = 0.5);

  /// Holds `vertex` at `anchor` (relative to the tool origin, not necessarily on the tool
  /// surface) with contact normal `normal`, sticking (Contact::face). For Ladjal et al.'s face
  /// contact. Returns false when the vertex is already held or the set is full.
  bool hold(int32_t vertex, Vec3d anchor, Vec3d normal, Vec3d u_now);

  /// True when `vertex` is one of the contacts.
  bool holds(int32_t vertex) const { return in_set_[static_cast<size_t>(vertex)] != 0; }

  /// Target displacement of each contact for the tool at its next pose `next_origin` [m],
  /// in contact order, and records u_{n-1} for the next measure_reactions.
  void targets(const Model& model, std::span<const Vec3d> u_prev_step, Vec3d next_origin,
               std::span<Vec3d> out);

  /// Sum of the reactions: the force the tool applies to the body [N].
  Vec3d total_reaction() const;
  /// Sum of the quasi-static reactions [N].
  Vec3d total_static_reaction() const;

  /// Removes every contact (puncture, tool withdrawn).
  void clear() { count_ = 0; }

 private:
  void add(int32_t vertex, Vec3d anchor, Vec3d normal, Vec3d u_now);

  ContactTool tool_;
  const ContactSurface* surface_;
  std::vector<Contact> contacts_;     // storage, (capacity)
  size_t count_ = 0;
  std::vector<uint8_t> in_set_;       // per vertex: 1 if a contact
  std::vector<int32_t> released_at_;  // per vertex: the update that released it
  int32_t update_count_ = 0;
  std::vector<int32_t> visit_stamp_;  // per vertex: last search that visited it
  std::vector<int32_t> queue_;        // breadth-first search queue, (vertex_count)
  int32_t stamp_ = 0;
};

}  // namespace zona
