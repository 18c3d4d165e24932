// Scenes: the description of one experiment (mesh, materials, tools, outputs) loaded from JSON.
//
// A scene file writes units in its values ("17.9 kPa", "56 um"); load_scene() validates every
// key, converts to SI once and returns plain structs with defaults (like Box2D's b2DefaultBodyDef:
// a default-constructed Scene is a valid starting point). docs/scenes.md lists every key.
// Values that depend on the mesh (the needle's start beside a file mesh, ...) stay std::nullopt
// ("auto") here and are resolved when the model is built.
#pragma once

#include <cstdint>
#include <limits>
#include <nlohmann/json_fwd.hpp>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "engine/core/base.h"
#include "engine/core/vec.h"

namespace zona {

/// Which physics model runs the scene.
enum class ModelKind {
  kSvk,        ///< St Venant-Kirchhoff mass-tensor FEM (Ladjal et al., non-linear)
  kLinear,     ///< linear mass-tensor FEM (Ladjal et al.; valid for small displacements)
  kParticles,  ///< particle membrane model (Asgari et al.)
  /// Stable neo-Hookean FEM (Smith, de Goes and Kim 2018; gradient form): resists the tip's
  /// compression through inversion, no stretch clamp (docs/physics.md).
  kStableNeoHookean,
};

/// Where the mesh comes from.
enum class MeshSource {
  kGenerate,  ///< the cell mesh generator, from MeshGenerateDef
  kFile,      ///< a Gmsh / TetGen / VTU file
};

/// Parameters of the cell mesh generator (mirrors CellMeshSpec in engine/mesh/mesh_generate.h; the
/// generated cell is centred at the origin).
struct MeshGenerateDef {
  double diameter = 56e-6;          ///< cell diameter [m]
  Vec3d radii_scale{1.0, 1.0, 1.0}; ///< ellipsoid: semi-axes = diameter / 2 * radii_scale [-]
  double zona_thickness = 0.0;      ///< outer shell (zona pellucida / chorion) thickness [m]; 0: none
  double nucleus_diameter = 0.0;    ///< nucleus diameter [m]; 0: no nucleus region
  /// About this many vertices; 0: sized by the edge lengths. Alone: a uniform mesh; with the
  /// refinement lengths: the graded mesh scaled as a whole to reach the count.
  int64_t target_vertices = 0;
  double edge_length = 5.6e-6;      ///< edge length away from refinement [m]; 0: uniform by count
  double refine_edge_length = 0.0;  ///< edge length at refine_at [m]; 0: no graded refinement
  double refine_radius = 0.0;       ///< radius of the finely meshed zone around refine_at [m]
  Vec3d refine_at{0.0, 0.0, 0.0};   ///< centre of refinement [m]
  bool refine_at_needle = false;    ///< refine_at was "needle": where the needle axis enters the
                                    ///< cell (refine_at holds that point, resolved on load)
};

/// The mesh of the scene: a file or generator parameters.
struct MeshDef {
  MeshSource source = MeshSource::kGenerate;
  std::string file;            ///< mesh file path (resolved against the scene's folder), kFile only
  double file_unit = 1.0;      ///< length of one file coordinate unit [m] (1e-6 for "um")
  MeshGenerateDef generate;    ///< generator parameters, kGenerate only
};

/// How a material's mass is given; the model builder turns each into lumped vertex masses.
enum class MassSpec {
  kDensity,     ///< density [kg/m^3] times tetrahedron volume
  kTotalMass,   ///< total mass of the tetrahedra this material covers, spread by volume
  kVertexMass,  ///< fixed mass per vertex, split between materials by tetrahedron count
};

/// One point of a speed-dependent Young's modulus table (Hajiyavand et al. 2019 eq. 9).
struct SpeedModulusPoint {
  double speed = 0.0;  ///< needle speed [m/s]
  double young = 0.0;  ///< Young's modulus at that speed [Pa]
};

/// Elastic material of one region. Isotropic; linear or SVK per Scene::model.
struct MaterialDef {
  double young = 0.0;    ///< Young's modulus [Pa] (> 0); from young_by_speed at needle.speed if set
  double poisson = 0.3;  ///< Poisson ratio, [0, 0.5)
  MassSpec mass_spec = MassSpec::kDensity;
  double density = 1000.0;   ///< mass density [kg/m^3], kDensity
  double total_mass = 0.0;   ///< mass of all tetrahedra using this material [kg], kTotalMass
  double vertex_mass = 0.0;  ///< mass of each vertex [kg], kVertexMass
  double damping = 0.0;      ///< mass-proportional damping: gamma = damping * M [1/s]
  /// Speed-dependent modulus (Hajiyavand et al. 2019 eq. 9): Young's modulus linear in needle speed through
  /// these points (extrapolated linearly beyond the ends); empty when `young` is given directly.
  /// Sorted by increasing speed, (point_count >= 2).
  std::vector<SpeedModulusPoint> young_by_speed;
};

/// A material and the region it applies to ("zona", "cytoplasm", "nucleus", a file's physical
/// name or tag as text, or "default" for every region without its own entry).
struct RegionMaterialDef {
  std::string region;
  MaterialDef material;
};

/// How mass scaling reaches `target_dt`.
enum class MassScalingMode {
  kUniform,    ///< every mass times one factor (the slowest modes slow down as much as the fastest)
  kSelective,  ///< each vertex only as much as its smallest element needs (engine/fem/mass_scaling.h)
};

/// How the cell's state follows the needle: explicit dynamics (the integrator section) or
/// static equilibrium per needle position (docs/static.md).
enum class SolverMethod { kExplicit, kStatic };
/// The static solver's linear solves: a sparse direct factorisation (the exact oracle) or CG.
enum class LinearSolverKind { kDirect, kCg };
/// CG's preconditioner: 3 x 3 block Jacobi, the lattice multigrid, or by the mesh's size
/// (docs/static.md).
enum class PreconditionerKind { kAuto, kJacobi, kMultigrid };

/// "auto" takes the multigrid from this many vertices up: block Jacobi's CG count grows with
/// the mesh (1000-1300 per Newton iteration at 1M against the multigrid's 5-20) while a
/// V-cycle costs a few products; measured, a Newton iteration is 9x cheaper with the
/// multigrid at 1M and block Jacobi is ahead at 6k and even at 64k (docs/static.md).
inline constexpr size_t kMultigridFromVertices = 150000;

/// The static solver (solver.method "static"; docs/static.md).
struct SolverDef {
  SolverMethod method = SolverMethod::kExplicit;
  double travel_step = 2e-6;        ///< largest load step in needle travel [m]
  double min_travel_step = 1e-9;    ///< a load step that fails below this ends the run [m]
  /// Converged: the largest vertex force imbalance at most this fraction of the force scale,
  /// max(needle axial force, E_max tip_radius^2) [-].
  double tolerance = 1e-5;
  /// A load step's Newton iterations before it counts as not converged (and is halved).
  int max_iterations = 30;
  LinearSolverKind linear = LinearSolverKind::kCg;
  PreconditionerKind preconditioner = PreconditionerKind::kAuto;
  /// The volume barrier acts below this element volume ratio [-] (docs/physics.md).
  double barrier_volume = 0.1;
  /// The medium's viscosity for the regulariser's drag [Pa s] (water at 25 C).
  double medium_viscosity = 0.89e-3;
  /// The puncture is bracketed in travel to this width [m].
  double puncture_tolerance = 10e-9;
  /// Suction is ramped in over this many load steps before the needle moves.
  int suction_steps = 4;
  /// Verification: every load step that converges with CG is solved again from the same start
  /// by Newton on the direct solver, and the largest difference of the two goes to the summary
  /// (docs/static.md, "The direct oracle"). Slow: for checking, not for results.
  bool oracle = false;
};

/// The preconditioner a static run takes on a mesh of `vertices` ("auto" resolved).
inline PreconditionerKind resolved_preconditioner(const SolverDef& s, size_t vertices) {
  if (s.preconditioner != PreconditionerKind::kAuto) return s.preconditioner;
  return vertices >= kMultigridFromVertices ? PreconditionerKind::kMultigrid
                                            : PreconditionerKind::kJacobi;
}
/// Its name in scenes and outputs.
inline const char* preconditioner_name(PreconditionerKind k) {
  return k == PreconditionerKind::kAuto ? "auto"
         : k == PreconditionerKind::kMultigrid ? "multigrid" : "jacobi";
}
/// The name of the preconditioner a static run on `vertices` takes: "none" with the direct
/// solver (summary.json's static_solver.preconditioner, zona bench --job's column).
inline const char* preconditioner_used(const SolverDef& s, size_t vertices) {
  return s.linear == LinearSolverKind::kDirect
             ? "none"
             : preconditioner_name(resolved_preconditioner(s, vertices));
}

/// Time stepping (explicit centred difference, Ladjal et al. eq. 7).
struct IntegratorDef {
  std::optional<double> dt;   ///< time step [s]; nullopt: auto = dt_safety * critical step
  double dt_safety = 0.9;     ///< fraction of the critical step used by auto dt, (0, 1]
  double mass_scaling = 1.0;  ///< factor on all masses (>= 1) to lengthen the stable step
  /// When set: raise mass_scaling as far as needed for the auto step to reach this [s]
  std::optional<double> target_dt;
  /// How target_dt is reached (uniform or selective scaling).
  MassScalingMode mass_scaling_mode = MassScalingMode::kUniform;
  /// Stiffness-proportional (Kelvin-Voigt) damping coefficient beta [s]: damping force -beta K v,
  /// for the element-scale ringing that mass-proportional damping cannot reach. 0: none.
  double stiffness_damping = 0.0;
  /// Dynamic mass scaling on the penalty-contact step: the fraction of an element's stability
  /// limit (omega dt / 2) that its stiffening may reach before its corners' masses are raised
  /// (engine/fem/mass_scaling.h); 0: off.
  double dynamic_mass_safety = 0.5;
  /// Penalty-contact step: damping rate c [1/s] of the cell's drift, the whole cell's
  /// translation velocity v against its running mean w (time constant drift_window): every
  /// vertex gets -c m (v - w) (engine/sim/job.h). It damps the swing of the mass-scaled cell on
  /// its holder and carries no load while the cell moves steadily. 0: off; nullopt ("auto"):
  /// 2 omega_s, with omega_s the swing's estimated angular frequency (Simulation::prepare_job:
  /// the cell's scaled mass on the held side's stiffness), critical damping of the swing.
  std::optional<double> drift_damping = 0.0;
  /// [s], > 0; nullopt ("auto"): 3 / omega_s (50 ms without a suction holder), so that the
  /// running mean lags the swing and follows the slower loading.
  std::optional<double> drift_window;
  /// Selective scaling with a suction holder and a moving needle: the target step is lowered
  /// from target_dt where the cell's swing on its holder (its scaled mass on the held side's
  /// stiffness, Simulation::holder_swing_omega) would take longer than the needle needs for
  /// this travel [m]; 0: target_dt as given.
  double quasi_static_travel = 0.0;
  /// [m/s] the loading speed quasi_static_travel is timed at: the faster of this and the
  /// needle's speed, so that a slower needle keeps the step (halving the speed tests the rate
  /// at the same discretisation) and a faster one lowers it; 0: the needle's speed.
  double quasi_static_speed = 0.0;
  double duration = 0.0;      ///< simulated time [s]; 0: until the needle has moved max_travel
};

/// Vertices selected by a boundary condition: those meeting every condition that is set.
struct VertexSelect {
  bool surface_only = false;  ///< only boundary-surface vertices
  std::string region;         ///< only vertices of this region's tetrahedra; empty: any
  Vec3d normal{0.0, 0.0, 1.0};  ///< unit normal of the half-space test below / above
  double below = std::numeric_limits<double>::infinity();    ///< keep dot(x, normal) <= below [m]
  double above = -std::numeric_limits<double>::infinity();   ///< keep dot(x, normal) >= above [m]
  std::optional<Vec3d> center;  ///< ball test centre [m]; nullopt: no ball test
  double radius = 0.0;          ///< ball test radius [m]: keep |x - center| <= radius
};

enum class BoundaryKind {
  kFixed,   ///< selected vertices never move
  kIndent,  ///< surface patch pushed along `direction` at `speed` up to `depth`, then held
};

/// One boundary condition.
struct BoundaryDef {
  BoundaryKind type = BoundaryKind::kFixed;
  VertexSelect where;        ///< kFixed: the fixed vertices
  Vec3d center{0.0, 0.0, 0.0};     ///< kIndent: patch centre on the surface [m]
  double radius = 0.0;             ///< kIndent: patch radius (surface vertices within it) [m]
  double depth = 0.0;              ///< kIndent: final indentation depth [m]
  double speed = 0.0;              ///< kIndent: indentation speed [m/s]
  Vec3d direction{0.0, 0.0, -1.0}; ///< kIndent: unit push direction (default: towards the origin)
};

enum class NeedleShape {
  kPoint,   ///< Ladjal et al.: the tip is a point, contact by ray-triangle; load spread over tip_radius
  kSphere,  ///< hemispherical tip of tip_radius
  kFlat,    ///< flat circular end of tip_radius (blunt pipette)
};

/// How the membrane particles of the particle model are placed and joined.
enum class ParticleLayout : int32_t {
  /// Geodesic icosphere (icosahedron subdivided at a frequency n: 10 n^2 + 2 particles), springs
  /// along the triangulation's edges (5 or 6 neighbours). Near-uniform spacing: the default.
  kIcosphere = 0,
  /// Asgari et al.'s latitude-longitude grid: rings of particles, each joined to its four neighbours
  /// (left, right, top, bottom); one particle at each pole joined to its whole first ring.
  kLatLong = 1,
};

/// The particle cell model (Asgari et al.; `"model": "particles"`): the membrane of a sphere of
/// mesh.generate.diameter. engine/particles/particle_model.h says how each value enters.
struct ParticlesDef {
  ParticleLayout layout = ParticleLayout::kIcosphere;
  int64_t particles = 2562;          ///< about this many membrane particles
  Vec3d pole_axis{0.0, 0.0, 1.0};    ///< lat-long: unit axis through the poles [-]
  double membrane_modulus = 1.0;     ///< membrane 2D modulus E h [N/m]
  double membrane_relaxation_time = 0.0;  ///< membrane dashpot / spring [s]
  double radial_stiffness = 0.0;     ///< centre springs per membrane area [N/m^3]
  double radial_damping = 0.0;       ///< centre dashpots per membrane area [N*s/m^3]
  Vec3d damping{0.0, 0.0, 0.0};      ///< eq. 5's diagonal damping per membrane area [N*s/m^3]
  double compressibility = 1e-6;     ///< interior compressibility beta [1/Pa]
  double areal_density = 3e-3;       ///< membrane mass per area [kg/m^2]
  double centre_mass = 0.0;          ///< centre particle mass [kg]; 0: the membrane's mass
};

/// The injection micropipette: a rigid tool driven by a script or, later, the haptic coupling.
struct NeedleDef {
  bool enabled = false;       ///< the scene has a needle
  NeedleShape shape = NeedleShape::kPoint;
  double tip_radius = 1e-6;   ///< tip radius [m]
  Vec3d direction{1.0, 0.0, 0.0};  ///< unit direction of travel (towards the cell)
  std::optional<Vec3d> start;  ///< tip position at t = 0 [m]; nullopt: auto (standoff before the
                               ///< surface on the axis through the origin)
  double standoff = 5e-6;     ///< gap between tip and cell surface for an auto start [m]
  double speed = 1e-4;        ///< insertion speed [m/s]
  double max_travel = 0.0;    ///< travel after which the needle stops [m]; 0: no limit
  double friction = 0.3;      ///< Coulomb coefficient needle-cell [-] (Hajiyavand et al. 2019's contacts: 0.3)
  /// The friction's stick zone at least this wide [m] (HoldingPipetteDef::stick_length); 0 (the
  /// default): the contact's own (mu times the penetration). With 0.1 um the membrane slid
  /// around the tip and the tip went through the 64k-256k fine meshes before 40 um of
  /// deformation (docs/injection.md).
  double stick_length = 0;
  /// Time constant of the first-order low-pass on the published needle force (a load cell's
  /// finite bandwidth; the puncture criterion reads the filtered force) [s]; 0: none.
  double force_filter = 0.0;
  std::string trajectory;     ///< CSV of tip positions over time (path resolved); empty: straight
};

enum class PunctureCriterion {
  kNone,    ///< the membrane never punctures
  kForce,   ///< axial needle force reaches threshold [N]
  kStrain,  ///< largest principal Green strain in the zona at the tip reaches threshold [-]
  kEnergy,  ///< elastic energy stored in the cell reaches threshold [J]
};

/// Membrane puncture: when it happens and what follows.
struct PunctureDef {
  PunctureCriterion criterion = PunctureCriterion::kNone;
  double threshold = 0.0;       ///< [N], [-] or [J] by criterion
  double force_drop = 1.0;      ///< fraction of the tip contact force released at puncture, (0, 1]
  double drop_time = 0.0;       ///< time over which it is released [s]
  double shaft_friction = 0.0;  ///< axial drag on the needle per inserted length [N/m]
};

/// How tools touch the cell (docs/injection.md).
enum class ContactModel {
  /// Penalty pressure on the tools' signed distance fields with Coulomb friction: the same load
  /// at every mesh size; runs on every backend inside the device-resident step (engine/sim/job.h).
  kPenalty,
};

/// Tool-cell contact.
struct ContactDef {
  ContactModel model = ContactModel::kPenalty;
  /// Penalty: contact pressure per penetration as a multiple of E_max / r, with E_max the
  /// stiffest material's Young's modulus and r the needle's tip radius (the holding pipette's
  /// inner radius without a needle) [-]. 1000: the mouse curve moves by under 2 % from 300 to
  /// 1000 (docs/validation.md); at 100 the tip went through the stretched surface at ~24 um.
  double stiffness = 1000.0;
  /// Penalty: the needle's pressure integrated over the surface triangles (true) or lumped at
  /// the surface vertices (false; the tip can then pass between vertices it pushes apart).
  bool needle_on_faces = true;
  /// Penalty: the holding pipette's rim contact gets a normal damper of this fraction of each
  /// contact point's critical damping, at most m / dt (engine/sim/job.h,
  /// rim_damper_coefficient) [-]. Without it the cell, seated on the stiff rim by the suction,
  /// bounced on it: the holding force swung by several uN from one sample to the next. 0: off.
  double rim_damping = 1.0;
};

enum class HoldingMode {
  kSuction,  ///< suction pressure on the aspirated patch, rim contact with Coulomb friction
  kFixed,    ///< the vertices of the aspirated patch are fixed (the simple option)
};

/// The holding pipette that keeps the cell in place by suction (Hajiyavand et al. 2019).
struct HoldingPipetteDef {
  bool enabled = false;       ///< the scene has a holding pipette
  HoldingMode mode = HoldingMode::kSuction;
  double inner_radius = 0.0;  ///< inner (aspiration) radius [m]
  double outer_radius = 0.0;  ///< outer radius of the rim [m]; 0: thin rim at inner_radius
  /// Rounding radius of the mouth's edges [m] (a fire-polished rim); 0: sharp edges.
  double edge_radius = 0.0;
  double suction = 2.5e3;     ///< suction pressure [Pa]
  double friction = 0.3;      ///< Coulomb friction coefficient rim-cell [-]
  /// The rim friction's stick zone is at least this wide [m]: a contact point carries its
  /// tangential load elastically over this much slip before it slides (its stick spring is the
  /// contact's stiffness, or mu f_n / stick_length where that is softer; engine/tools/penalty.h
  /// friction_stiffness). 0 (the default): the contact's stiffness alone, a zone of mu times the
  /// penetration (nanometres), which the static solver's Newton iterations cross back and forth;
  /// 0.1 um takes a fifth of them off the default scene's static run (docs/static.md, "Cost").
  double stick_length = 0;
  std::optional<Vec3d> side;  ///< unit vector from the cell centre to the pipette; nullopt:
                              ///< needle.direction (opposite the needle)
  std::optional<Vec3d> position;  ///< centre of the pipette mouth [m]; nullopt: the cell surface
                                  ///< on `side`
};

enum class HapticDeviceKind {
  kNone,      ///< no haptic thread
  kScripted,  ///< constant-speed insertion or trajectory file
  kEmulated,  ///< a mass-spring-damper operator model
  kReplay,    ///< a recorded session
  kNetwork,   ///< UDP bridge to an external device driver
};

enum class HapticInterpolation {
  kFirstOrderHold,  ///< linear extrapolation from the last two force samples
  kStiffness,       ///< last force plus local stiffness times device motion since the sample
};

/// The haptic channel: device, rate, hand-to-cell scaling, device limits.
struct HapticsDef {
  HapticDeviceKind device = HapticDeviceKind::kNone;
  double rate = 1000.0;              ///< haptic loop rate [Hz]
  double workspace_scale = 5e-3;     ///< tool displacement per device displacement [-]
  double force_scale = 1e5;          ///< device force per tool force [-]
  double max_force = 3.3;            ///< device force limit [N]
  double max_stiffness = 400.0;      ///< device stiffness limit [N/m]
  HapticInterpolation interpolation = HapticInterpolation::kStiffness;
  double stall_timeout = 0.05;       ///< fade the force out after this long without a sample [s]
  /// Fastest the simulated tip follows the hand, in simulated time [m/s]; nullopt: 20x the
  /// needle's insertion speed. A simulation slower than real time always lags the hand, so its
  /// tip runs at this speed: it must be one at which the scene's step is quasi-static.
  std::optional<double> max_tip_speed;
  std::optional<double> coupling_stiffness;  ///< virtual coupling [N/m]; nullopt: auto (Llewellyn)
  std::optional<double> coupling_damping;    ///< virtual coupling [N*s/m]; nullopt: auto
  std::string replay_file;           ///< recorded session for kReplay (path resolved)
  std::string network_host = "127.0.0.1";  ///< UDP peer for kNetwork
  int network_port = 47600;                ///< UDP port for kNetwork
};

/// The files a run's frames go to (docs/outputs.md).
enum class FrameFormat {
  kVtu,          ///< "vtu": frames.pvd + frames_NNNNNN.vtu
  kXdmf,         ///< "xdmf": frames.xdmf + frames.h5 (needs a build with HDF5)
  kVtuAndXdmf,   ///< "vtu+xdmf": both, the same frames
};

/// Whether frames in `format` include VTU files / the XDMF series.
inline bool writes_vtu(FrameFormat format) { return format != FrameFormat::kXdmf; }
inline bool writes_xdmf(FrameFormat format) { return format != FrameFormat::kVtu; }
/// The scene file's name of a format ("vtu", "xdmf", "vtu+xdmf").
const char* frame_format_name(FrameFormat format);

/// What a run writes.
struct OutputDef {
  int frames = 10;               ///< frames over the run (evenly spaced); 0: none
  FrameFormat format = FrameFormat::kVtu;  ///< where the frames go
  std::optional<double> frame_interval;  ///< time between frames [s]; overrides frames when set
  double sample_interval = 1e-5; ///< time between force.csv rows [s]; 0: every step
};

/// What the experiment measures (the scene's "experiment").
enum class Experiment {
  /// The equilibrium curve of a slow injection: every run is checked for being quasi-static
  /// (engine/sim/quasi_static.h); a state that is not gives no puncture and the run an error.
  kQuasiStatic,
  /// Dynamics as such (a haptic session, an impact): measured and reported, never enforced.
  kDynamic,
};

/// Thresholds of the quasi-static check ("quasi_static"; docs/outputs.md says why these).
struct QuasiStaticDef {
  double max_imbalance = 0.2;      ///< largest |needle + holder| / needle force [-]
  /// Largest kinetic / (kinetic + elastic) energy [-]; 1 (the default): recorded, not judged
  /// (docs/outputs.md says why).
  double max_kinetic_share = 1.0;
  /// Needle force from which the check judges [N]; unset ("auto"): 3 E_max r_tip^2, about the
  /// Hertz force of the tip pressed 1.4 radii into the stiffest material (docs/outputs.md).
  std::optional<double> force_floor;
};

/// One experiment, in SI. Default-constructed: a 56 um generated ball with no tools.
struct Scene {
  std::string name;         ///< short name (defaults to the file's stem)
  std::string description;  ///< free text
  std::string source;       ///< file the scene came from ("" when parsed from memory)
  MeshDef mesh;
  ModelKind model = ModelKind::kSvk;
  /// "volumetric": "nodal" (neohookean only): the law's volumetric term averaged at the
  /// vertices (ModelDesc::nodal_pressure); "element" (the default) takes it per element.
  bool nodal_pressure = false;
  /// "volumetric_stabilisation": with nodal pressure, the fraction beta of each element's
  /// lambda kept per element (ModelDesc::nodal_stabilisation); 0 (the default): none. Static
  /// solver only, for now.
  double volumetric_stabilisation = 0;
  ParticlesDef particles;  ///< used when model is kParticles
  std::vector<RegionMaterialDef> materials;  ///< per region, sorted by region name
  IntegratorDef integrator;
  SolverDef solver;
  std::vector<BoundaryDef> boundary;      ///< in file order
  NeedleDef needle;
  PunctureDef puncture;
  HoldingPipetteDef holding_pipette;
  ContactDef contact;
  HapticsDef haptics;
  OutputDef output;
  Experiment experiment = Experiment::kQuasiStatic;
  QuasiStaticDef quasi_static;
};

/// Largest scene file read [bytes]: scenes are a few kilobytes (meshes live in their own files);
/// the bound keeps a wrong path (a log, a device) from being read whole into memory.
inline constexpr std::uintmax_t kMaxSceneFileBytes = std::uintmax_t{64} << 20;
/// Deepest nesting of objects and arrays parsed from a scene file or a --set value. nlohmann's
/// documents are copied and destroyed recursively, so text nested 100,000 deep overflows the
/// stack; scenes nest about four levels.
inline constexpr int kMaxJsonDepth = 64;

/// Checks that JSON text nests objects and arrays at most `max_depth` deep (brackets inside
/// strings do not count), without parsing it. Error: "nested deeper than 64 levels (line L,
/// column C)".
Status check_json_depth(std::string_view text, int max_depth = kMaxJsonDepth);

/// Reads a scene file as JSON, without validating it as a scene: a regular file of at most
/// kMaxSceneFileBytes, nested at most kMaxJsonDepth, with no duplicate keys. Errors are one
/// line naming the file. load_scene reads with it; so does anything else reading a scene's JSON.
Status read_scene_json(const std::string& path, nlohmann::json* out);

/// Loads and validates a scene file. `overrides` are "key.path=value" strings (the CLI's --set)
/// applied to the JSON before validation. Errors are one line: "FILE: key.path: what is wrong".
Result<Scene> load_scene(const std::string& path, const std::vector<std::string>& overrides = {});

/// Validates an already parsed scene. `source_name` prefixes error messages and, when it is a
/// path, relative paths in the scene (mesh file, trajectory) resolve against its folder.
Result<Scene> parse_scene(const nlohmann::json& json, const std::string& source_name,
                          const std::vector<std::string>& overrides = {});

/// Applies one "key.path=value" override to a JSON document. The value is parsed as JSON when it
/// is valid JSON (numbers, true/false, arrays, objects, quoted strings), otherwise taken as a
/// string ("20kPa", "auto"). Missing objects on the path are created; a path through a value
/// that is not an object (or an array with an index in range) is an error.
Status apply_override(nlohmann::json& json, const std::string& assignment);

/// The folders a scene name is looked up in, in this order: ./scenes, $ZONA_SCENES_DIR (when
/// set), `installed_dir` (a relative one is taken from the running program's folder, so that an
/// installed `bin/zona` finds `share/zona/scenes`), then `source_dir` (the source tree's scenes/,
/// for a program run from its build folder). Empty arguments are left out.
std::vector<std::string> scene_search_dirs(const std::string& installed_dir = "",
                                           const std::string& source_dir = "");

/// Resolves a scene argument: a path to an existing file as given; else a name ("mouse_oocyte",
/// with or without ".json") looked up in `search_dirs` in order (scene_search_dirs() when
/// empty). The error names every folder looked in.
Result<std::string> find_scene(const std::string& name,
                               const std::vector<std::string>& search_dirs = {});

/// The material for a region name: its own entry, else "default", else nullptr.
const MaterialDef* find_material(const Scene& scene, const std::string& region);

/// The scene as JSON with every value written in SI units ("1.79e+04 Pa"), which parse_scene
/// reads back to the same Scene; used to record the resolved scene next to a run's results.
nlohmann::json scene_to_json(const Scene& scene);

/// A scene made for the haptic loop gives integrator.duration as long as a hand may need
/// (mouse_oocyte_haptic: 3600 s); scripted, its needle stops after max_travel / speed and the rest
/// would be a resting cell. When the duration is over twice the needle's end and over a second
/// past it, this sets it to 0 (the run ends with the needle's script) and returns the needle's
/// end time [s]; otherwise it changes nothing and returns 0. `zona run` and the Python module
/// call it unless asked for the full duration.
double end_run_with_needle(Scene& scene);

/// Name of a model ("svk", "linear", "neohookean", "particles") as written in scene files.
const char* model_name(ModelKind model);

}  // namespace zona
