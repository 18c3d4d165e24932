// The holding pipette (Hajiyavand et al. 2019): a rigid tube whose mouth touches the cell opposite the
// needle. Suction mode: the suction pressure acts on the aspirated patch (the surface over the
// opening) as nodal forces, and the cell rests on the rim with Coulomb friction (the rim is a
// contact tool, engine/tools/contact.h). Fixed mode: the surface vertices of that patch never move.
#pragma once

#include <cstdint>
#include <vector>

#include "engine/core/base.h"
#include "engine/tools/needle.h"
#include "engine/scene/scene.h"
#include "engine/core/vec.h"

namespace zona {

struct ContactSurface;

/// The rigid tube: its wall occupies s >= 0 and inner_radius <= rho <= outer_radius, where s is
/// the distance past the mouth plane along `axis` and rho the distance from the axis.
struct HoldingGeometry {
  Vec3d axis{1, 0, 0};     ///< unit vector from the cell centre into the pipette [-]
  Vec3d mouth{0, 0, 0};    ///< centre of the mouth [m]
  double inner_radius = 0; ///< bore radius [m]
  double outer_radius = 0; ///< outer radius of the rim [m] (> inner_radius)
  /// Rounding radius of the mouth's inner and outer edges [m] (0: sharp; below half the rim's
  /// width).
  double edge_radius = 0;
};

/// Signed distance of `x` [m] from the tube wall and the wall's outward normal there.
ToolDistance holding_distance(const HoldingGeometry& holding, Vec3d x);

/// Everything the simulation needs from the holding pipette, computed once from the rest mesh.
struct HoldingSetup {
  HoldingMode mode = HoldingMode::kFixed;
  HoldingGeometry geometry;
  double friction = 0.3;                  ///< Coulomb coefficient rim-cell [-]
  double stick_length = 0;                ///< the friction's stick zone at least this wide [m]
  /// Corners of the surface triangles over the opening (centroid within inner_radius of the
  /// axis, on the pipette side), sorted.
  std::vector<int32_t> patch_vertices;
  /// Suction: the nodal force of the full suction pressure on each patch vertex [N],
  /// (patch_vertices.size()); empty in fixed mode.
  std::vector<Vec3d> suction_force;
  Vec3d suction_total{0, 0, 0};           ///< sum of suction_force [N]
  double aspirated_area = 0;              ///< patch area projected on the axis [m^2]
};

/// Builds the holding pipette for a cell centred at `centre` [m] from the scene's definition.
/// The axis is `def.side`, else `needle_direction`; an automatic mouth sits where the circle of
/// inner_radius meets the rest surface, so the rim touches the cell along that circle. A zero
/// outer radius (thin rim) becomes 1.25 inner_radius so that a coarse surface cannot slip
/// between rim and bore. Errors: a patch with no surface vertex (radius below the mesh size),
/// an axis that misses the surface.
Result<HoldingSetup> make_holding(const HoldingPipetteDef& def, const ContactSurface& surface,
                                  const std::vector<Vec3d>& rest, Vec3d centre,
                                  Vec3d needle_direction);

}  // namespace zona
