// The particle cell model of Asgari et al.: membrane particles on a sphere, each joined to its
// neighbours and to a centre particle by spring-dashpots (eqs. 1-4), diagonal anisotropic
// damping (eq. 5), a hydraulic pressure from the enclosed volume and the interior's
// compressibility beta (eq. 6) applied as forces on the membrane, integrated explicitly (eq. 7).
//
// How it joins the FEM engine (docs/particles.md, "The seam"): the membrane triangulation plus
// the centre particle form a "body mesh" whose tetrahedra are the fans from the centre to each
// membrane triangle. That mesh gives the shared Model (rest positions, masses, fixed vertices,
// dt, contact search adjacency) and the ContactSurface, so the needle, holding pipette,
// puncture, measurement and recording stages of the job's step (engine/sim/) run unchanged; only
// the internal forces and the update differ: particle_step() replaces zona::step() (same State,
// same prescribed-vertex and status semantics; engine/sim/particle_body.h), in place or on a
// particle Backend (engine/sim/backend_cpu.h's make_particle_cpu_backend,
// kernels/particle_backend.h). This
// folder sits below engine/sim/: it knows the Model, the State and the step's status flags
// (engine/fem/), not the simulation or its Backend interface.
#pragma once

#include <array>
#include <cstdint>
#include <memory>
#include <span>
#include <string>
#include <vector>

#include "engine/core/base.h"
#include "engine/core/vec.h"
#include "engine/fem/model.h"
#include "engine/fem/state.h"
#include "engine/fem/step_status.h"
#include "engine/mesh/mesh.h"
#include "engine/scene/scene.h"

namespace zona {

/// Everything the particle model is built from. SI units. Defaults: a 800 um zebrafish embryo.
struct ParticleModelDesc {
  double radius = 400e-6;            ///< cell radius at rest [m]
  ParticleLayout layout = ParticleLayout::kIcosphere;
  int64_t target_particles = 2562;   ///< about this many membrane particles (the nearest layout)
  Vec3d pole_axis{0, 0, 1};          ///< lat-long: unit axis through the poles [-]
  /// Membrane 2D modulus Y = E h [N/m]. Spring constants k_ij = kappa Y (A_i/deg_i + A_j/deg_j)
  /// / L_ij^2, kappa = 3 on a triangulation (exact for an equilateral lattice), 2 on the
  /// four-neighbour grid (exact along the axes of a square lattice).
  double membrane_modulus = 1.0;
  /// Membrane dashpots: c_ij = membrane_relaxation_time * k_ij [s].
  double membrane_relaxation_time = 0.0;
  /// Centre springs per unit membrane area: k_c,i = radial_stiffness * A_i [N/m^3].
  double radial_stiffness = 0.0;
  /// Centre dashpots per unit membrane area: c_c,i = radial_damping * A_i [N*s/m^3].
  double radial_damping = 0.0;
  /// Eq. 5's diagonal damping per unit area: B_i = diag(damping) A_i [N*s/m^3], (x, y, z).
  Vec3d damping{0, 0, 0};
  /// Interior compressibility beta = -(1/V) dV/dP [1/Pa] (eq. 6).
  double compressibility = 1e-6;
  /// Membrane mass per area [kg/m^2] (chorion: 1000 kg/m^3 x 3 um).
  double areal_density = 3e-3;
  /// Mass of the centre particle [kg]; 0: the membrane's total mass.
  double centre_mass = 0.0;
  /// Time stepping: dt (0: dt_safety x critical step), factor on every mass (>= 1), and
  /// target_dt (> 0: raise the mass scaling until the automatic step reaches it) [s].
  double dt = 0.0;
  double dt_safety = 0.9;
  double mass_scaling = 1.0;
  double target_dt = 0.0;
};

/// The immutable particle model. Particle p < membrane_count is on the membrane; the centre
/// particle is the last one (index membrane_count).
struct ParticleModel {
  ParticleLayout layout = ParticleLayout::kIcosphere;
  int32_t membrane_count = 0;  ///< membrane particles N
  int32_t centre = 0;          ///< index of the centre particle (= N)

  std::vector<Vec3d> rest_positions;  ///< rest positions, centre at the origin [m], (N + 1)
  std::vector<Triangle> triangles;    ///< membrane triangulation, outward CCW, (triangle_count)
  std::vector<std::array<int32_t, 2>> springs;  ///< membrane springs i < j, (spring_count)

  // Per membrane particle, CSR over its springs (both directions stored, ascending neighbour).
  std::vector<int32_t> neighbor_offsets;       ///< (N + 1)
  std::vector<int32_t> neighbor_index;         ///< the other particle, (2 spring_count)
  std::vector<double> neighbor_rest_length;    ///< free length L0 [m], (2 spring_count)
  std::vector<double> neighbor_stiffness;      ///< k [N/m], (2 spring_count)
  std::vector<double> neighbor_damping;        ///< dashpot c [N*s/m], (2 spring_count)
  // Per membrane particle: its centre spring-dashpot.
  std::vector<double> centre_rest_length;      ///< [m], (N)
  std::vector<double> centre_stiffness;        ///< [N/m], (N)
  std::vector<double> centre_damping;          ///< [N*s/m], (N)
  // Per membrane particle, CSR over the triangles around it (for dV/dx, the pressure force).
  std::vector<int32_t> triangle_offsets;       ///< (N + 1)
  std::vector<int32_t> particle_triangles;     ///< triangle indices, ascending, (3 triangle_count)

  std::vector<double> area;      ///< rest tributary area, a third of each triangle [m^2], (N)
  std::vector<double> mass;      ///< scaled mass [kg], (N + 1)
  std::vector<Vec3d> damping;    ///< eq. 5's diagonal B [N*s/m], (N + 1) (centre: zero)

  double compressibility = 0;   ///< beta [1/Pa]
  double rest_volume = 0;       ///< enclosed volume of the triangulation at rest [m^3]
  double rest_area = 0;         ///< membrane area at rest [m^2]
  double radius = 0;            ///< [m]
  double membrane_modulus = 0;  ///< [N/m]

  double dt = 0;            ///< time step [s]
  double dt_critical = 0;   ///< stability bound (particle_critical_step) [s]
  double mass_scaling = 1;  ///< factor applied to every mass [-]
  double min_spring_length = 0;  ///< shortest free length [m]
  double max_spring_length = 0;  ///< longest free length [m]

  size_t particle_count() const { return rest_positions.size(); }
  size_t spring_count() const { return springs.size(); }
};

/// Builds a particle model. Errors (one line, naming the parameter): non-positive radius,
/// modulus, compressibility or density; negative damping; too few or too many particles; a zero
/// pole axis; dt_safety outside (0, 1]; mass_scaling < 1; dt above the critical step.
Result<ParticleModel> build_particle_model(const ParticleModelDesc& desc);

/// The description of a scene with `"model": "particles"`: radius from mesh.generate.diameter,
/// the particles block, the integrator's dt, dt_safety, mass_scaling and target_dt. Errors: a
/// file mesh (the particle model generates its own sphere), an ellipsoid.
Result<ParticleModelDesc> particle_desc_from_scene(const Scene& scene);

/// Bounds of the stable step, from Gershgorin on the linearised spring and dashpot matrices (the
/// smaller of the particle-row and the spring-row forms; the latter is far tighter at the centre
/// particle, which has N springs) plus
/// the exact eigenvalue of the rank-one hydraulic stiffness, (1/(beta V0)) sum |dV/dx_i|^2 / m_i:
/// dt_crit solves G_k dt^2 + 2 G_c dt = 4 (the centred-difference limit with lagged dashpots).
struct ParticleStepBound {
  double spring_omega_sq = 0;     ///< G_k from the springs [1/s^2]
  double hydraulic_omega_sq = 0;  ///< the hydraulic mode [1/s^2]
  double dashpot_rate = 0;        ///< G_c [1/s]
  double dt_critical = 0;         ///< [s]
};
/// The bound for masses `mass` [kg], (N + 1).
ParticleStepBound particle_critical_step(const ParticleModel& model, std::span<const double> mass);

/// The body mesh: rest positions of all particles and the fan tetrahedra (centre, a, b, c) of
/// the membrane triangles, one region "membrane". Its boundary is the membrane triangulation.
Mesh particle_body_mesh(const ParticleModel& model);

/// The shared Model of the body mesh: the particle masses and time step, eq. 5's damping as its
/// mean per particle (vertex_damping, used by contact measurement only), `fixed` vertices.
/// The FEM fields are filled for a linear placeholder material and never evaluated.
Result<Model> particle_body_model(const ParticleModel& model, const Mesh& mesh,
                                  std::span<const int32_t> fixed);

/// What particle_step and particle_forces report besides State::diag.
struct ParticleStepInfo {
  double volume = 0;    ///< enclosed volume at u_n [m^3]
  double pressure = 0;  ///< hydraulic pressure at u_n [Pa]
  double elastic_energy = 0;  ///< springs + interior [J]
};

/// Enclosed volume of the membrane at displacements u [m], (N + 1) [m^3]. Serial, fixed order.
double particle_volume(const ParticleModel& model, std::span<const Vec3d> u);

/// Internal forces [N], (N + 1): springs, dashpots with velocities (u - u_prev) * inv_dt
/// (inv_dt = 0: none, the static forces) and the hydraulic pressure on the membrane. Never
/// allocates. Returns volume, pressure and stored energy at u.
ParticleStepInfo particle_forces(const ParticleModel& model, std::span<const Vec3d> u,
                                 std::span<const Vec3d> u_prev, double inv_dt,
                                 std::span<Vec3d> force);

/// One explicit step of length body.dt with zona::step's contract (free particles updated,
/// fixed at zero, prescribed at state.prescribed_displacement, loads from state.external_force,
/// state.diag filled, the state not advanced on a non-finite update, kStepDtAboveCritical
/// refused). `body` is particle_body_model's Model. Never allocates. `info` may be null.
StepStatus particle_step(const ParticleModel& model, const Model& body, State& state,
                         ParticleStepInfo* info);

/// One line: layout, particle and spring counts, spacing, dt and its bound, mass scaling.
std::string describe_particle_model(const ParticleModel& model);

}  // namespace zona
