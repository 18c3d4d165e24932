// Membrane puncture: the criterion (needle force, membrane strain at the tip, stored energy),
// the record of the moment it happens, and what follows: the tip's contact force is released
// over drop_time (down to 1 - force_drop of its value) and the needle moves on inside the cell
// against a shaft drag proportional to the inserted length.
//
// After puncture the needle no longer collides with the mesh (the mesh has no hole): the last
// contact reactions become nodal loads on the same vertices, scaled by the release factor, and
// the shaft drag is spread over them too, so the body still feels what the needle feels.
#pragma once

#include <cstdint>
#include <span>
#include <vector>

#include "engine/tools/contact.h"
#include "engine/fem/model.h"
#include "engine/scene/scene.h"
#include "engine/core/vec.h"

namespace zona {

/// What the puncture criterion looks at, measured after a step.
struct PunctureInputs {
  double force = 0;       ///< axial needle force [N]
  double max_strain = 0;  ///< largest principal Green strain in the membrane at the tip [-]
  double energy = 0;      ///< elastic energy stored in the cell [J]
};

/// The moment of puncture.
struct PunctureRecord {
  bool punctured = false;
  int64_t step = 0;             ///< step count at puncture
  double time = 0;              ///< [s]
  double needle_travel = 0;     ///< tip travel from its start [m]
  double deformation = 0;       ///< membrane indentation at the tip [m]
  double force = 0;             ///< axial needle force [N]
  double max_strain = 0;        ///< membrane strain at the tip [-]
  double energy = 0;            ///< stored elastic energy [J]
  Vec3d force_vector{0, 0, 0};  ///< force the needle applied to the cell [N]
};

/// Fraction of the tip force still applied `elapsed` [s] after puncture: 1 - force_drop *
/// min(1, elapsed / drop_time) (a step at elapsed 0 when drop_time is 0).
double puncture_release_factor(const PunctureDef& def, double elapsed);

/// Largest principal Green strain [-] of the tetrahedra around `vertices` (mesh indices) at
/// displacements u [m], counting only tetrahedra whose flag in `tet_counts` is 1 (e.g. the
/// zona region; an empty span counts every one). 0 when none is counted. Does not allocate.
double max_principal_strain_around(const Model& model, std::span<const Vec3d> u,
                                   std::span<const int32_t> vertices,
                                   std::span<const uint8_t> tet_counts);

/// The puncture state machine of one run. Capacity fixed at creation; no allocation after.
class Puncture {
 public:
  /// `capacity`: the most contact vertices whose force can be released (the needle's contact
  /// set capacity).
  Puncture(const PunctureDef& def, Vec3d direction, size_t capacity);

  const PunctureDef& def() const { return def_; }
  const PunctureRecord& record() const { return record_; }
  bool punctured() const { return record_.punctured; }

  /// True when the criterion is met (never for kNone, never twice).
  bool criterion_met(const PunctureInputs& in) const;

  /// Records the puncture and takes over the needle's contacts: their reactions become the
  /// released loads. `record` carries time, travel, deformation, force and the inputs.
  void trigger(const PunctureRecord& record, std::span<const Contact> contacts);

  /// Adds the loads on the body at `time` [s] with the needle at `travel` [m] (released tip
  /// force and shaft drag) to `external` [N], (vertex_count), and returns the axial force on
  /// the needle [N] (resistance positive). 0 before puncture.
  double apply_loads(double time, double travel, std::span<Vec3d> external) const;

  /// The vertices that carry the released loads (the needle's contacts at puncture).
  std::span<const int32_t> released_vertices() const { return {vertices_.data(), count_}; }

  /// Force the needle applies to the body after puncture [N] (what apply_loads adds).
  Vec3d body_force(double time, double travel) const;

 private:
  PunctureDef def_;
  Vec3d direction_;
  PunctureRecord record_;
  std::vector<int32_t> vertices_;  // released vertices, (capacity)
  std::vector<Vec3d> forces_;      // their quasi-static reactions at puncture [N], (capacity)
  size_t count_ = 0;
  Vec3d released_total_{0, 0, 0};
};

}  // namespace zona
