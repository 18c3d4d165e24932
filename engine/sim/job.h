// The injection step as one list of stages that either backend runs where the state lives
// (engine/sim/step_stage.h names them; docs/architecture.md, "One step"):
//
//   masses     dynamic mass scaling (every mass_interval steps)
//   loads      stiffness-proportional damping from the change of the elastic forces, and the
//              drift damping's load (job_drift_update)
//   tools      the tool terms' forces on the surface: the needle and the holding pipette's rim
//              as penalty contact on the tools' distance fields with Coulomb friction
//              (engine/tools/penalty.h), suction on the aspirated patch, the released tip load
//              after puncture, the rim contact's damper; the friction anchors are committed in
//              place (every explicit step is accepted)
//   elastic    elastic forces (the backend's element pass)
//   integrate  centred difference with the loads of tools and loads
//   measure    needle force vector, holding force, contacts, deformation at the entry point,
//              energies, the work the tools put in (reductions)
//   record     the step's measures, health verdict (blow-up, the needle through the surface),
//              force filter, local stiffness, quasi-static check
//   commit     release after puncture, the next tool pose
//   puncture   the puncture test on a healthy, quasi-static state; the sample
//
// (record, commit and puncture are job_finish_step, one call per step.)
//
// Every per-vertex and per-step function here is ZONA_HOST_DEVICE: the CPU runner
// (engine/sim/job_runner.cpp) loops over them on its threads, the CUDA runner (kernels/job_kernels.cuh)
// calls the same functions from its kernels, so the two backends cannot drift apart. On the
// GPU only the fixed-size JobRecord crosses to the host (mapped pinned memory, no stream
// synchronisation); vertex arrays cross only for a written frame.
//
// Why penalty contact on the tools' distance fields (and not a kinematic contact that holds the
// touched vertices on the tool, which zona ran first and retired): the load a tool puts on the
// cell is a pressure on the area it covers, so it does not depend on how many vertices the tip
// happens to touch (the mesh-convergence study of docs/validation.md), and every vertex decides
// its own contact from its own position, which is one thread per surface vertex on the GPU with
// no contact set to rebuild. docs/injection.md has
// the stiffness, the stable step and the friction law.
#pragma once

#include <cmath>
#include <cstdint>

#include "engine/core/base.h"
#include "engine/core/vec.h"
#include "engine/sim/quasi_static.h"
#include "engine/tools/penalty.h"
#include "engine/tools/tool_params.h"
#include "engine/tools/tool_sdf.h"

namespace zona {

/// A surface point this far inside the needle, in tip radii, means the surface let the tool
/// through (JobParams::needle_breach_depth). The penalty holds the loaded surface at a few
/// percent of the radius (docs/injection.md); a point half a radius deep is past any pressure
/// the contact was made for, and at a full radius the distance field's normal turns and pushes
/// the surface around the tip instead of ahead of it.
inline constexpr double kNeedleBreachFraction = 0.5;

/// Puncture criteria the step evaluates (PunctureCriterion's values).
enum JobCriterion : int32_t {
  kJobCriterionNone = 0,
  kJobCriterionForce = 1,
  kJobCriterionStrain = 2,  ///< the zona's stretch around the tip (needle_face_strain)
  kJobCriterionEnergy = 3
};

/// Damping of the explicit step.
struct DampingParams {
  /// Stiffness-proportional damping: load k (f(u_{n-1}) - f(u_{n-2})), k = beta / dt [-].
  double stiffness_rate = 0;
  /// Drift damping (job_drift_update): rate [1/s] (0: off) and the running mean's time
  /// constant [s].
  double drift = 0;
  double drift_window = 0;
};

/// The puncture criterion and what follows it.
struct PunctureParams {
  int32_t criterion = kJobCriterionNone;
  double threshold = 0;       ///< [N] or [J]
  double force_drop = 1;      ///< fraction of the tip load released [-]
  double drop_time = 0;       ///< [s]
  double shaft_friction = 0;  ///< axial drag per inserted length [N/m]
};

/// What the record stage measures and publishes.
struct RecordParams {
  int32_t has_entry = 0;                 ///< the needle axis meets the rest surface
  int32_t entry_vertex[3] = {0, 0, 0};   ///< corners of the rest triangle the axis enters
  double entry_weight[3] = {0, 0, 0};    ///< barycentric weights of the entry point [-]
  double force_filter = 0;         ///< low-pass time constant of the published force [s]
  double force_filter_weight = 1;  ///< 1 - exp(-dt / force_filter): the filter's step weight [-]
  double sample_interval = 0;      ///< a sample every this much simulated time [s]; 0: every step
  double stiffness_window = 20e-9; ///< travel over which the local stiffness is taken [m]
};

/// The record stage's health verdict.
struct HealthParams {
  double energy_blowup_factor = 10;  ///< kinetic + elastic above this x the budget is a blow-up
  double energy_floor = 0;           ///< energies below this are noise [J]
};

/// Dynamic mass scaling (engine/fem/mass_scaling.h): every `interval` steps each element's
/// stiffening (tet_stiffening) is measured; where it passes `gate` the element asks its corners
/// for density growth x its rest need (JobSetup::tet_rest_need), and a vertex whose mass falls
/// short is raised to it. Masses only grow. Off when interval is 0.
struct MassScalingParams {
  int32_t interval = 0;  ///< steps between checks; 0: off
  int32_t law = 0;       ///< StiffeningLaw of the model
  double gate = 1;       ///< stiffening that every element's current masses carry [-]
};

/// Everything constant the stages need, by topic, in SI units. Plain data: passed by value to
/// kernels.
struct JobParams {
  double dt = 0;  ///< [s]
  NeedleParams needle;
  RimParams rim;
  DampingParams damping;
  PunctureParams puncture;
  RecordParams record;
  HealthParams health;
  MassScalingParams mass;
  /// Whether the run is quasi-static (engine/sim/quasi_static.h), judged in the record stage.
  QuasiStaticLimits quasi;
};

/// Density [kg/m^3] an element of rest need `rest_need` (JobSetup::tet_rest_need) asks of its
/// corners at stiffening `growth`; 0 while the masses it had at the start carry it.
ZONA_HOST_DEVICE inline double job_mass_need(const JobParams& p, double growth, double rest_need) {
  return growth > p.mass.gate ? growth * rest_need : 0.0;
}

/// u_{n-1} of a vertex whose mass rises from m_old to m_new at u_n: the momentum is kept, so
/// the velocity (u_n - u_{n-1}) / dt scales by m_old / m_new and the kinetic energy falls by the
/// same factor. (Keeping the velocity instead would add (m_new / m_old - 1) of the vertex's
/// kinetic energy from nothing: under a fast tip, where the raises happen, that energy threw the
/// surface through the needle or tripped the blow-up check.)
ZONA_HOST_DEVICE inline double job_raised_prev(double u, double u_prev, double m_old,
                                               double m_new) {
  return u - (m_old / m_new) * (u - u_prev);
}

/// Where a tool vertex is and what it may carry.
struct ToolVertexInput {
  Vec3d x{0, 0, 0};        ///< position rest + u_n [m]
  double area = 0;         ///< rest tributary surface area [m^2]
  Vec3d suction{0, 0, 0};  ///< full-strength suction load [N] (zero off the aspirated patch)
  Vec3d velocity{0, 0, 0}; ///< (u_n - u_{n-1}) / dt [m/s]; read by the rim's damper only
  double mass = 0;         ///< the vertex's (scaled) mass [kg]; read by the rim's damper only
};

/// The tool pose and scalars of one step (JobState's, read by every tool vertex).
struct ToolPose {
  int64_t step = 0;             ///< n, the step that starts at t_n (the anchors' clock)
  Vec3d tip{0, 0, 0};           ///< needle tip at t_n (frozen at puncture) [m]
  double suction_ramp = 0;      ///< [-]
  double needle_scale = 1;      ///< release factor after puncture [-]
  Vec3d drag_per_contact{0, 0, 0};  ///< shaft drag load on each released contact [N]
};

/// What one tool vertex gets.
struct ToolVertexForce {
  Vec3d force{0, 0, 0};   ///< total tool load on the vertex [N]
  Vec3d needle{0, 0, 0};  ///< the needle's part [N]
  Vec3d rim{0, 0, 0};     ///< the rim's and the suction's part [N]
  int32_t needle_contact = 0, rim_contact = 0;
  double needle_depth = 0;  ///< how deep the vertex is inside the needle [m] (0 outside)
};

/// The rim damper's coefficient for a vertex of rest area `area` [m^2] and mass `mass` [kg]:
/// `rim_damping` times the critical damping 2 sqrt(k m) of its contact spring k = kappa area,
/// at most m / dt. The cap keeps the explicit (one step lagged) damper at half its stability
/// limit (c dt / m < 2); the contact's mass raise (m >= k dt^2, Simulation) puts most rim
/// vertices at omega dt = 1, where the cap is the critical damping itself. [kg/s]
ZONA_HOST_DEVICE ZONA_INLINE double rim_damper_coefficient(const RimParams& rim, double dt,
                                                          double area, double mass) {
  if (!(rim.damping > 0) || !(mass > 0)) return 0;
  const double critical = 2.0 * sqrt(rim.pressure_stiffness * area * mass);
  const double c = rim.damping * critical;
  const double cap = mass / dt;
  return c < cap ? c : cap;
}

/// Stage 1 for one surface vertex: needle, rim and suction, with the vertex's stick anchors
/// on the needle (used with NeedleParams::on_faces off) and on the rim; dt [s] for the rim's
/// damper.
ZONA_HOST_DEVICE ZONA_INLINE ToolVertexForce tool_vertex_force(const NeedleParams& needle,
                                                              const RimParams& rim, double dt,
                                                              const ToolPose& pose,
                                                              const ToolVertexInput& in,
                                                              StickAnchor* needle_anchor,
                                                              StickAnchor* rim_anchor) {
  ToolVertexForce out;
  if (needle.on && !needle.on_faces) {
    const ToolSdf sdf = needle_sdf(pose.tip, needle.direction, needle.radius,
                                   needle.flat != 0, in.x);
    if (sdf.distance < 0) {
      out.needle_depth = -sdf.distance;
      out.needle = pose.needle_scale * penalty_contact_force(sdf, needle.pressure_stiffness,
                                                             needle.friction,
                                                             needle.stick_length, in.area,
                                                             in.x - pose.tip, pose.step,
                                                             needle_anchor) +
                   pose.drag_per_contact;
      out.needle_contact = 1;
    }
  }
  if (rim.on) {
    const ToolSdf sdf =
        holding_sdf(rim.mouth, rim.axis, rim.inner_radius, rim.outer_radius, in.x,
                    rim.edge_radius);
    if (sdf.distance < 0) {
      out.rim = penalty_contact_force(sdf, rim.pressure_stiffness, rim.friction,
                                      rim.stick_length, in.area,
                                      in.x - rim.mouth, pose.step, rim_anchor,
                                      rim_damper_coefficient(rim, dt, in.area, in.mass), in.velocity);
      out.rim_contact = 1;
    }
    out.rim += pose.suction_ramp * in.suction;
  }
  out.force = out.needle + out.rim;
  return out;
}

/// One surface triangle of the needle stage: its corners' positions rest + u_n [m] and its rest
/// area [m^2].
struct ToolFaceInput {
  Vec3d x[3] = {};
  double area = 0;
};

/// The needle's load on one triangle, as corner loads [N], and the number of quadrature points
/// inside the needle.
struct ToolFaceForce {
  Vec3d corner[3] = {};
  int32_t contacts = 0;
  double depth = 0;  ///< deepest quadrature point inside the needle [m] (0: none inside)
};

/// Stage 1, needle part, for one surface triangle (JobParams::needle_on_faces; corners counter-
/// clockwise seen from outside the cell): the penalty pressure of each quadrature point's depth
/// inside the needle, along the triangle's inward normal, and friction with a stick anchor per
/// point (penalty_contact_force), over the point's share of the rest area, spread to the
/// corners by the point's barycentric weights (needle_face_force; the GPU evaluates the
/// points of a triangle on a few threads with needle_face_point). A triangle whose centroid lies
/// farther from the needle than from its farthest corner cannot touch it (the distance field is
/// 1-Lipschitz): needle_face_may_touch is false and it is skipped.
ZONA_HOST_DEVICE ZONA_INLINE bool needle_face_may_touch(const NeedleParams& needle,
                                                        const ToolPose& pose,
                                                        const ToolFaceInput& in) {
  const Vec3d centroid = (1.0 / 3.0) * (in.x[0] + in.x[1] + in.x[2]);
  double reach = 0;
  for (int c = 0; c < 3; ++c) {
    const Vec3d d = in.x[c] - centroid;
    reach = reach > dot(d, d) ? reach : dot(d, d);
  }
  return needle_sdf(pose.tip, needle.direction, needle.radius, needle.flat != 0, centroid)
             .distance < std::sqrt(reach);
}

/// The needle's load [N] at quadrature point q of a triangle and how deep the point is inside
/// the needle [m] (false, and nothing written but a void anchor, where the point is outside the
/// needle), and the point's barycentric weights b[3]; `anchor` is the point's stick anchor.
ZONA_HOST_DEVICE ZONA_INLINE bool needle_face_point(const NeedleParams& needle,
                                                    const ToolPose& pose,
                                                    const ToolFaceInput& in, int q, Vec3d* force,
                                                    double* depth, double b[3],
                                                    StickAnchor* anchor) {
  const Vec3d x = face_point(in.x, q, b);
  ToolSdf sdf = needle_sdf(pose.tip, needle.direction, needle.radius, needle.flat != 0, x);
  if (!(sdf.distance < 0)) return false;
  *depth = -sdf.distance;
  // The pressure acts along the triangle's inward normal (the tool's normal where the triangle
  // faces away from it): a flat triangle across the curved tip gets no in-plane load, which
  // along the tool's normals would pull its corners apart and let the tip through.
  const Vec3d n = cross(in.x[1] - in.x[0], in.x[2] - in.x[0]);  // outward (counter-clockwise)
  const double n_len = norm(n);
  if (n_len > 0 && dot(n, sdf.normal) < 0) sdf.normal = (-1.0 / n_len) * n;
  constexpr double w = 1.0 / kFacePoints;
  *force = pose.needle_scale * penalty_contact_force(sdf, needle.pressure_stiffness,
                                                     needle.friction, needle.stick_length,
                                                     w * in.area, x - pose.tip,
                                                     pose.step, anchor) +
           pose.drag_per_contact;
  return true;
}

/// needle_face_point over every point of a triangle; anchors: its kFacePoints stick anchors.
ZONA_HOST_DEVICE ZONA_INLINE ToolFaceForce needle_face_force(const NeedleParams& needle,
                                                            const ToolPose& pose,
                                                            const ToolFaceInput& in,
                                                            StickAnchor* anchors) {
  ToolFaceForce out;
  for (int c = 0; c < 3; ++c) out.corner[c] = Vec3d{0, 0, 0};
  if (!needle_face_may_touch(needle, pose, in)) return out;
  for (int q = 0; q < kFacePoints; ++q) {
    Vec3d f;
    double b[3], depth = 0;
    if (!needle_face_point(needle, pose, in, q, &f, &depth, b, anchors + q)) continue;
    for (int c = 0; c < 3; ++c) out.corner[c] += b[c] * f;
    ++out.contacts;
    out.depth = out.depth > depth ? out.depth : depth;
  }
  return out;
}

/// The membrane's largest principal in-plane Green strain [-] on a surface triangle (rest
/// corners `rest`, deformed corners `x`), 0 if it is only compressed: the eigenvalues of
/// G^-1 (g - G) / 2 with G and g the rest and deformed edge metrics (the 2x2 Green strain in
/// the triangle's own plane). The strain criterion takes its maximum over the triangles around
/// the tip (needle_face_near): the surface under the tip itself is squeezed in its plane (as
/// under any round indenter), and the zona stretches where it wraps the tip, about one tip radius
/// out.
ZONA_HOST_DEVICE ZONA_INLINE double needle_face_strain(const Vec3d rest[3], const Vec3d x[3]) {
  const Vec3d E1 = rest[1] - rest[0], E2 = rest[2] - rest[0];
  const Vec3d e1 = x[1] - x[0], e2 = x[2] - x[0];
  const double G11 = dot(E1, E1), G12 = dot(E1, E2), G22 = dot(E2, E2);
  const double a11 = 0.5 * (dot(e1, e1) - G11), a12 = 0.5 * (dot(e1, e2) - G12),
               a22 = 0.5 * (dot(e2, e2) - G22);
  const double det_g = G11 * G22 - G12 * G12;
  if (!(det_g > 0)) return 0;
  // M = G^-1 A: its trace and determinant give the principal strains.
  const double trace = (G22 * a11 - 2.0 * G12 * a12 + G11 * a22) / det_g;
  const double det = (a11 * a22 - a12 * a12) / det_g;
  const double disc = 0.25 * trace * trace - det;
  const double largest = 0.5 * trace + sqrt(disc > 0 ? disc : 0.0);
  return largest > 0 ? largest : 0.0;
}

/// Whether a triangle lies around the tip for the strain criterion: its centroid within one tip
/// radius of the needle's surface (or inside it). A physical distance, so the region does not
/// shrink with the mesh.
ZONA_HOST_DEVICE ZONA_INLINE bool needle_face_near(const NeedleParams& needle,
                                                   const ToolPose& pose, const Vec3d x[3]) {
  const Vec3d centroid = (1.0 / 3.0) * (x[0] + x[1] + x[2]);
  return needle_sdf(pose.tip, needle.direction, needle.radius, needle.flat != 0, centroid)
             .distance < needle.radius;
}

/// Sums of one step's per-vertex stages (reset every step).
struct JobSums {
  double needle_force[3] = {0, 0, 0};  ///< force the needle applies to the cell [N]
  double rim_force[3] = {0, 0, 0};     ///< force the rim and suction apply to the cell [N]
  double tool_work = 0;                ///< work of the tool loads over the last increment [J]
  int32_t needle_contacts = 0;
  int32_t rim_contacts = 0;
  double needle_depth = 0;  ///< deepest contact point inside the needle [m] (a maximum)
  /// Largest needle_face_strain of a triangle around the tip [-] (a maximum; taken only with
  /// the strain criterion, before the puncture).
  double needle_strain = 0;
};

/// Puncture moment, as recorded on the device or the CPU.
struct JobPuncture {
  int32_t punctured = 0;
  int64_t step = 0;
  double time = 0;           ///< [s]
  double needle_travel = 0;  ///< [m]
  double deformation = 0;    ///< [m]
  double force = 0;          ///< filtered axial force [N]
  double energy = 0;         ///< [J]
  double max_strain = 0;     ///< the zona's stretch around the tip (strain criterion) [-]
  Vec3d force_vector{0, 0, 0};  ///< [N]
};

/// One step's record: what crosses to the host every step (latest) and every sample interval.
struct JobRecord {
  int64_t step = 0;
  double time = 0;              ///< t_{n+1} [s]
  Vec3d tip{0, 0, 0};           ///< needle tip at t_{n+1} [m]
  double travel = 0;            ///< [m]
  double deformation = 0;       ///< membrane advance at the entry point along the axis [m]
  double force = 0;             ///< filtered axial needle force, resistance positive [N]
  double raw_force = 0;         ///< [N]
  Vec3d force_vector{0, 0, 0};  ///< force the needle applies to the cell [N]
  Vec3d holding_force{0, 0, 0}; ///< force the holding pipette applies to the cell [N]
  double stiffness = 0;         ///< local d force / d travel [N/m]
  double elastic_energy = 0;    ///< [J]
  double kinetic_energy = 0;    ///< [J]
  double energy_budget = 0;     ///< initial energy + work of the tools so far [J]
  int32_t contacts = 0;         ///< contact points inside the needle (face quadrature points or vertices)
  double needle_depth = 0;      ///< deepest contact point inside the needle [m]
  double max_strain = 0;        ///< the zona's stretch around the tip (strain criterion only) [-]
  int32_t holding_contacts = 0; ///< vertices inside the rim
  uint32_t status = 0;          ///< StepStatusBits of the step (kStepNonFinite, kStepEnergyBlowUp...)
  int32_t halted = 0;           ///< the state failed its check: no later step was advanced
  int64_t first_bad = -1;       ///< first non-finite vertex or inverted element, -1 if none
  JobPuncture puncture;
  QuasiStaticState quasi;       ///< this step's quasi-static measures and the run's worst
};

/// The mutable scalars of a job (device memory on the GPU).
struct JobState {
  int64_t step = 0;
  double time = 0;            ///< t_n [s]
  ToolPose pose;              ///< tools at t_n
  int32_t external_tip = 0;   ///< the tip comes from set_tip (haptics), not the script
  Vec3d external_tip_value{0, 0, 0};  ///< the handed-in tip [m]
  Vec3d external_tip_now{0, 0, 0};    ///< the tip following it (external_tip_max_speed) [m]
  double filtered_force = 0;  ///< [N]
  /// The holder's axial force on the cell through the needle's force filter [N].
  double filtered_holding = 0;
  int32_t filter_started = 0;
  double next_sample = 0;     ///< [s]
  double energy_budget = 0;   ///< [J]
  int32_t budget_valid = 0;
  int32_t halted = 0;
  double stiffness = 0, stiffness_force = 0, stiffness_travel = 0;
  int32_t stiffness_anchor = 0;
  /// After puncture: the contact points the shaft's drag is shared by (the last step's) [-].
  int32_t released_contacts = 0;
  /// After puncture: the scale on the needle's contact pressure, set each step so that the
  /// contact's axial load follows the release (job_follow_release) [-].
  double release_scale = 1;
  Vec3d drift_mean{0, 0, 0};  ///< running mean of the cell's translation velocity [m/s]
  /// The drift damping's acceleration for the next step: every free vertex gets m times this
  /// as a load [m/s^2] (job_drift_update).
  Vec3d drift_accel{0, 0, 0};
  JobPuncture puncture;
  QuasiStaticState quasi;
};

/// Stiffness-proportional (Kelvin-Voigt) damping's load on a vertex, lagged one step:
/// rate (f(u_{n-1}) - f(u_{n-2})) [N] with rate = beta / dt (JobParams::damping.stiffness_rate);
/// `force_prev` holds f(u_{n-2}) and becomes f(u_{n-1}). The loads stage of the CPU runner and
/// of the prescribed boundary's host step; the GPU's vertex kernel evaluates it in float.
ZONA_HOST_DEVICE ZONA_INLINE Vec3d job_stiffness_damping_load(double rate, Vec3d force,
                                                             Vec3d* force_prev) {
  const Vec3d load = rate * (force - *force_prev);
  *force_prev = force;
  return load;
}

/// Fraction of the tip load still applied `elapsed` [s] after puncture.
ZONA_HOST_DEVICE ZONA_INLINE double job_release_factor(const JobParams& p, double elapsed) {
  const double ramp = p.puncture.drop_time > 0 ? (elapsed < p.puncture.drop_time ? elapsed / p.puncture.drop_time : 1.0) : 1.0;
  return 1.0 - p.puncture.force_drop * ramp;
}

/// After puncture, once per step from the step's needle sums: the contact's scale moves so that
/// its axial load (the needle force less the shaft drag) follows job_release_factor x the force
/// at puncture. Scaling the penalty stiffness by the release factor alone does not release the
/// load: the tip is frozen, the load is displacement-driven, and the cell pushes its surface
/// deeper into the softer contact until it carries nearly the same force (7.5 -> 7.0 uN at
/// force_drop 0.9 on the fine mouse cell). At most a 20 % change per step: the surface answers a
/// step later, and a larger gain rang. A contact that pulls the needle back (a negative axial
/// load: the cell springs back past the frozen tip, whose inside then pushes the surface along
/// -direction) is released by the same 20 % per step: a needle does not pull the cell.
ZONA_HOST_DEVICE ZONA_INLINE void job_follow_release(const JobParams& p, JobState& s,
                                                     const JobSums& sums, double needle_force) {
  const double drag = dot(s.pose.drag_per_contact, p.needle.direction) * sums.needle_contacts;
  const double contact = needle_force - drag;
  if (contact < 0) {
    s.release_scale *= 0.8;
    return;
  }
  if (!(contact > 0)) return;  // nothing touches the tip: nothing to release
  const double target = job_release_factor(p, s.time - s.puncture.time) * s.puncture.force;
  double f = target / contact;
  f = f < 0.8 ? 0.8 : (f > 1.25 ? 1.25 : f);
  const double scale = s.release_scale * f;
  s.release_scale = scale < 1.0 ? scale : 1.0;
}

/// The tip for the step that starts at s.time, once per step before job_set_pose: the
/// script's, or one step of at most external_tip_max_speed dt towards the tip the haptic thread
/// handed in. It starts from where the script had the tip when the first one comes.
ZONA_HOST_DEVICE ZONA_INLINE void job_follow_tip(const JobParams& p, JobState& s) {
  if (!s.external_tip) {
    s.external_tip_now = needle_scripted_tip(p.needle, s.time);
    return;
  }
  const Vec3d d = s.external_tip_value - s.external_tip_now;
  const double len = sqrt(dot(d, d));
  const double max_step = p.needle.external_tip_max_speed * p.dt;
  s.external_tip_now = p.needle.external_tip_max_speed > 0 && len > max_step
                           ? s.external_tip_now + (max_step / len) * d
                           : s.external_tip_value;
}

/// The tool pose for the step s.step, which starts at s.time.
ZONA_HOST_DEVICE ZONA_INLINE void job_set_pose(const JobParams& p, JobState& s) {
  ToolPose& pose = s.pose;
  pose.step = s.step;
  const Vec3d tip = s.external_tip ? s.external_tip_now : needle_scripted_tip(p.needle, s.time);
  const double ramp = p.rim.suction_ramp_time > 0 ? s.time / p.rim.suction_ramp_time : 1.0;
  pose.suction_ramp = ramp < 1.0 ? ramp : 1.0;
  if (s.puncture.punctured) {
    // The needle is inside: the tip load stays where it was, released over drop_time, and the
    // shaft drag pulls the rim of the hole along the axis.
    const double travel = dot(tip, p.needle.direction) -
                          dot(p.needle.start, p.needle.direction);
    const double inserted = travel > s.puncture.needle_travel ? travel - s.puncture.needle_travel : 0;
    pose.needle_scale = s.release_scale;
    pose.drag_per_contact = s.released_contacts > 0
                                ? (p.puncture.shaft_friction * inserted / s.released_contacts) *
                                      p.needle.direction
                                : Vec3d{0, 0, 0};
    return;
  }
  pose.tip = tip;
  pose.needle_scale = 1;
  pose.drag_per_contact = Vec3d{0, 0, 0};
}

/// What the integrator and the reductions report for the step, besides JobSums.
struct JobStepTotals {
  double elastic_energy = 0;  ///< W(u_n) [J]
  double kinetic_energy = 0;  ///< [J]
  uint32_t status = 0;        ///< integrator StepStatusBits
  int64_t first_bad = -1;     ///< first non-finite vertex / inverted element
  double deformation = 0;     ///< [m]
  /// Drift damping only: sum of m (u_{n+1} - u_n) / dt [kg m/s] and of m [kg] over the free
  /// vertices.
  Vec3d momentum{0, 0, 0};
  double mass = 0;
};

/// Steps between drift-damping updates: the momentum is summed (and the load renewed) on steps
/// n with n % kDriftInterval == 0. The swing it damps lasts thousands of steps; summing the
/// momentum every step cost the GPU job 2.4 us per step at 100k vertices (its serial tail).
inline constexpr int kDriftInterval = 8;

/// Drift damping, in the record stage: v = momentum / mass is the cell's translation velocity
/// over the step, w its running mean (exponential, time constant drift_window); the next step
/// loads every free vertex with -c m (v - w). The swing of a mass-scaled cell on its holder
/// (its whole mass on the compliance of the held side: periods of 50-200 ms, as long as the
/// first micrometres of loading) is a translation that changes faster than w follows, so it is
/// damped at the rate c; a steady drift (the cell pushed along at a constant rate) is w itself
/// and carries no load. Mass-proportional damping damps the same swing but also the drift, and
/// on the scaled mass that drag carried several % of the needle force. Explicit (one step
/// lagged): stable for c kDriftInterval dt << 1. A step without sums (tot.mass 0: the steps
/// between updates) keeps the load.
ZONA_HOST_DEVICE ZONA_INLINE void job_drift_update(const JobParams& p, JobState& s,
                                                 const JobStepTotals& tot) {
  if (!(p.damping.drift > 0) || !(tot.mass > 0)) return;
  const Vec3d v = (1.0 / tot.mass) * tot.momentum;
  const double span = kDriftInterval * p.dt;
  const double a = span / (p.damping.drift_window > span ? p.damping.drift_window : span);
  s.drift_mean += a * (v - s.drift_mean);
  s.drift_accel = (-p.damping.drift) * (v - s.drift_mean);
}

/// StepStatusBits (engine/sim/integrator.h) the record stage sets.
inline constexpr uint32_t kJobNonFinite = 1u, kJobBlowUp = 2u, kJobToolBreach = 1u << 6,
                          kJobNotQuasiStatic = 1u << 7;

/// Record, measures: the step count and time advance to t_{n+1}; the step's sums and totals
/// into the record; the drift damping's next load.
ZONA_HOST_DEVICE ZONA_INLINE void job_record_measures(const JobParams& p, JobState& s,
                                                      const JobSums& sums,
                                                      const JobStepTotals& tot, JobRecord& r) {
  r.status = tot.status;
  r.first_bad = tot.first_bad;
  s.step += 1;
  s.time = static_cast<double>(s.step) * p.dt;
  r.step = s.step;
  r.time = s.time;
  r.force_vector = Vec3d{sums.needle_force[0], sums.needle_force[1], sums.needle_force[2]};
  r.holding_force = Vec3d{sums.rim_force[0], sums.rim_force[1], sums.rim_force[2]};
  r.contacts = sums.needle_contacts;
  r.holding_contacts = sums.rim_contacts;
  r.needle_depth = sums.needle_depth;
  r.max_strain = sums.needle_strain;
  r.raw_force = dot(r.force_vector, p.needle.direction);
  r.deformation = tot.deformation;
  r.elastic_energy = tot.elastic_energy;
  r.kinetic_energy = tot.kinetic_energy;
  job_drift_update(p, s, tot);
}

/// Record, health: the state must be finite and its energy explained by the work put in
/// (kinetic + elastic above energy_blowup_factor times the initial energy plus the tools' work
/// is a blow-up: damping only removes energy); before puncture, a contact point deeper than
/// needle_breach_depth inside the needle means the surface let the tool through (it stretched too
/// far for its triangles to wrap the tip): what follows is no contact answer. A failed state
/// halts the job.
ZONA_HOST_DEVICE ZONA_INLINE void job_check_health(const JobParams& p, JobState& s,
                                                   const JobSums& sums, const JobStepTotals& tot,
                                                   JobRecord& r) {
  const double energy = tot.elastic_energy + tot.kinetic_energy;
  if (!(energy - energy == 0) || !(r.raw_force - r.raw_force == 0) ||
      !(tot.deformation - tot.deformation == 0))
    r.status |= kJobNonFinite;
  if (!s.budget_valid) {
    s.energy_budget = energy - energy == 0 ? energy : 0.0;
    s.budget_valid = 1;
  }
  s.energy_budget += sums.tool_work > 0 ? sums.tool_work : 0.0;
  const double floor = s.energy_budget > p.health.energy_floor ? s.energy_budget : p.health.energy_floor;
  if (energy > p.health.energy_blowup_factor * floor) r.status |= kJobBlowUp;
  r.energy_budget = s.energy_budget;
  if (p.needle.breach_depth > 0 && !s.puncture.punctured &&
      sums.needle_depth > p.needle.breach_depth)
    r.status |= kJobToolBreach;
  if (r.status & (kJobNonFinite | kJobBlowUp | kJobToolBreach)) s.halted = 1;
  r.halted = s.halted;
}

/// Record, force filter (exact for a constant input over the step), on the needle's force and on
/// the holder's, which the quasi-static check compares.
ZONA_HOST_DEVICE ZONA_INLINE void job_filter_forces(const JobParams& p, JobState& s,
                                                    JobRecord& r) {
  const double holding_axial = dot(r.holding_force, p.needle.direction);
  if (p.record.force_filter > 0 && s.filter_started) {
    const double a = p.record.force_filter_weight;
    s.filtered_force += a * (r.raw_force - s.filtered_force);
    s.filtered_holding += a * (holding_axial - s.filtered_holding);
  } else {
    s.filtered_force = r.raw_force;
    s.filtered_holding = holding_axial;
  }
  s.filter_started = 1;
  r.force = s.filtered_force;
}

/// Commit, tool poses: after puncture the release follows the step's load; the tip of the next
/// step (t_{n+1}); the record reports the tip the step ended at.
ZONA_HOST_DEVICE ZONA_INLINE void job_commit_pose(const JobParams& p, JobState& s,
                                                  const JobSums& sums, JobRecord& r) {
  if (s.puncture.punctured) {
    job_follow_release(p, s, sums, r.raw_force);
    // The shaft's drag is shared by the points the frozen tip touches now: the cell springs
    // back onto it as the load is released (4 points at the small cell's puncture, 60 a
    // millisecond later), and a share fixed at the puncture's count multiplied the drag by 15.
    if (sums.needle_contacts > 0) s.released_contacts = sums.needle_contacts;
  }
  job_follow_tip(p, s);
  job_set_pose(p, s);
  r.tip = s.puncture.punctured ? (s.external_tip ? s.external_tip_now : needle_scripted_tip(p.needle, s.time))
                               : s.pose.tip;
  r.travel = dot(r.tip - p.needle.start, p.needle.direction);
}

/// Record, local stiffness for the haptic thread: the slope of force over at least
/// stiffness_window of travel.
ZONA_HOST_DEVICE ZONA_INLINE void job_local_stiffness(const JobParams& p, JobState& s,
                                                      JobRecord& r) {
  if (!s.stiffness_anchor) {
    s.stiffness_anchor = 1;
    s.stiffness_force = r.force;
    s.stiffness_travel = r.travel;
  } else {
    const double dtr = r.travel - s.stiffness_travel;
    if (dtr >= p.record.stiffness_window || dtr <= -p.record.stiffness_window) {
      s.stiffness = (r.force - s.stiffness_force) / dtr;
      s.stiffness_force = r.force;
      s.stiffness_travel = r.travel;
    }
  }
  r.stiffness = s.stiffness;
}

/// Record, quasi-static check while the needle loads the cell (engine/sim/quasi_static.h): a
/// state whose load the holder does not carry (inertia, damping) is never taken as a puncture.
/// True when this state fails it.
ZONA_HOST_DEVICE ZONA_INLINE bool job_check_quasi_static(const JobParams& p, JobState& s,
                                                         const JobStepTotals& tot, JobRecord& r) {
  const bool not_static = quasi_static_step(
      p.quasi, s.quasi, p.needle.on && !s.puncture.punctured && !s.halted, r.force,
      s.filtered_holding, tot.kinetic_energy, tot.elastic_energy, s.step, s.time, r.deformation);
  if (not_static) r.status |= kJobNotQuasiStatic;
  return not_static;
}

/// Puncture: only from a healthy, quasi-static state, once; the tip load then stays at the pose
/// `tip_before` the step had. After it the stiffness the haptic thread extrapolates with is the
/// shaft's drag per metre inserted, not the slope from before (which would keep pushing the hand).
ZONA_HOST_DEVICE ZONA_INLINE void job_puncture_test(const JobParams& p, JobState& s,
                                                    const JobSums& sums, const JobStepTotals& tot,
                                                    bool not_static, Vec3d tip_before,
                                                    JobRecord& r) {
  if (!s.halted && !not_static && p.needle.on && !s.puncture.punctured) {
    const bool met =
        (p.puncture.criterion == kJobCriterionForce && r.force >= p.puncture.threshold) ||
        (p.puncture.criterion == kJobCriterionStrain && r.max_strain >= p.puncture.threshold) ||
        (p.puncture.criterion == kJobCriterionEnergy && tot.elastic_energy >= p.puncture.threshold);
    if (met) {
      JobPuncture& q = s.puncture;
      q.punctured = 1;
      q.step = s.step;
      q.time = s.time;
      q.needle_travel = r.travel;
      q.deformation = r.deformation;
      q.force = r.force;
      q.energy = tot.elastic_energy;
      q.max_strain = r.max_strain;
      q.force_vector = r.force_vector;
      s.released_contacts = sums.needle_contacts;
      s.pose.tip = tip_before;
      job_set_pose(p, s);
    }
  }
  if (s.puncture.punctured) {
    s.stiffness = p.puncture.shaft_friction;
    s.stiffness_force = r.force;
    s.stiffness_travel = r.travel;
    r.stiffness = s.stiffness;
  }
  r.puncture = s.puncture;
  r.quasi = s.quasi;
}

/// Whether a sample is due (every sample_interval of simulated time, and on a halt).
ZONA_HOST_DEVICE ZONA_INLINE bool job_sample_due(const JobParams& p, JobState& s) {
  if (s.time >= s.next_sample - 0.5 * p.dt || s.halted) {
    s.next_sample += p.record.sample_interval > 0 ? p.record.sample_interval : p.dt;
    if (s.next_sample < s.time) s.next_sample = s.time + p.record.sample_interval;
    return true;
  }
  return false;
}

/// The record, commit and puncture stages of the step that took s from t_n to t_{n+1}
/// (StepStage::kRecord, kCommit, kPuncture), in order; one call per step on either backend (the
/// CPU runner, the CUDA record kernel). Returns true when a sample is due.
ZONA_HOST_DEVICE ZONA_INLINE bool job_finish_step(const JobParams& p, JobState& s,
                                                 const JobSums& sums, const JobStepTotals& tot,
                                                 JobRecord* out) {
  JobRecord& r = *out;
  const Vec3d tip_before = s.pose.tip;
  job_record_measures(p, s, sums, tot, r);
  job_check_health(p, s, sums, tot, r);
  job_filter_forces(p, s, r);
  job_commit_pose(p, s, sums, r);
  job_local_stiffness(p, s, r);
  const bool not_static = job_check_quasi_static(p, s, tot, r);
  job_puncture_test(p, s, sums, tot, not_static, tip_before, r);
  return job_sample_due(p, s);
}

/// Deformation at the entry point: the advance of the material point where the needle axis
/// entered the rest surface, along the axis [m]. u0..u2: displacements of the entry triangle's
/// corners [m].
ZONA_HOST_DEVICE ZONA_INLINE double job_entry_deformation(const JobParams& p, Vec3d u0, Vec3d u1,
                                                        Vec3d u2) {
  if (!p.record.has_entry) return 0;
  const Vec3d u = p.record.entry_weight[0] * u0 + p.record.entry_weight[1] * u1 + p.record.entry_weight[2] * u2;
  return dot(u, p.needle.direction);
}

}  // namespace zona
