// The static solver's run (static_run.h).
#include "engine/sim/static_run.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>

#include "engine/core/thread_pool.h"
#include "engine/fem/elastic_energy.h"
#include "engine/solver/inertia_term.h"
#include "engine/solver/multigrid.h"
#include "engine/solver/newton.h"
#include "engine/tools/tool_terms.h"

namespace zona {

Status check_static_scene(const Scene& scene) {
  if (scene.model == ModelKind::kParticles)
    return make_error("solver.method \"static\": the particle model has no energy form; use "
                      "\"explicit\"");
  if (scene.model == ModelKind::kSvk)
    return make_error("solver.method \"static\": the St Venant-Kirchhoff law has spurious "
                      "collapsed equilibria under the tip (its energy falls again past a "
                      "compression of 1/sqrt(3)), so a minimiser can settle in an inverted "
                      "state; use \"model\": \"neohookean\" (or \"linear\")");
  if (!scene.needle.enabled)
    return make_error("solver.method \"static\": nothing loads the cell (no needle)");
  if (scene.puncture.criterion == PunctureCriterion::kStrain)
    return make_error("solver.method \"static\": puncture.criterion 'strain': the static solver "
                      "brackets the puncture on force or energy; use one of those, or "
                      "\"explicit\"");
  if (!scene.needle.trajectory.empty())
    return make_error("solver.method \"static\": needle.trajectory: its load steps are needle "
                      "travel along one axis; a timed path runs with \"explicit\"");
  return {};
}

namespace {

// What a state measures, for a row and for the events (targets, puncture).
struct Measures {
  double travel = 0, deformation = 0;
  double force = 0;  // axial, resistance positive [N]
  Vec3d force_vector{0, 0, 0};
  double holding = 0;  // axial [N]
  int64_t contacts = 0;
  int64_t holding_contacts = 0;  // the rim's contact points
  double depth = 0;
  double elastic = 0;
};

class StaticRun {
 public:
  StaticRun(Simulation& sim, const RunOptions& options, ElasticEnergy elastic)
      : sim_(sim),
        options_(options),
        def_(sim.scene().solver),
        p_(sim.job_setup().params),
        model_(sim.model()),
        elastic_(std::move(elastic)) {}

  RunResult run();

 private:
  void build();
  ToolField needle_field(double travel) const;
  // Solves at needle travel s (after the puncture, with the tip's contact at held_travel_),
  // from the accepted state and the guess in u (updated). False with a reason in failure_.
  bool solve_at(double s, std::vector<Vec3d>& u, NewtonStats* stats);
  Measures measure(std::span<const Vec3d> u, double travel);
  // solver.oracle: the solve just made, again from its start on the direct solver; the
  // difference of the two solutions into the result.
  void compare_with_oracle(std::span<const Vec3d> u);
  // Accepts u at travel s: commit, velocity, lag for the next step, the row.
  void accept(std::vector<Vec3d>& u, double s, const NewtonStats& stats, bool row = true);
  // After a load step that did not converge was shortened to `step` [m]: true where the step is
  // still at least solver.min_travel_step, else false with the run stopped and the reason
  // (`what` did not converge from the accepted travel).
  bool shortened_step_holds(double step, const char* what);
  ForceSample sample(const Measures& m, const NewtonStats& stats) const;
  void emit(const ForceSample& s);
  void stop(const std::string& reason) {
    result_.stopped_early = true;
    result_.stop_reason = reason;
  }
  // The shaft's drag at travel s [N]: shaft_friction x the inserted length.
  double released_ramp(double s) const {
    return p_.puncture.shaft_friction * std::max(0.0, s - punctured_travel_);
  }
  // The convergence tolerance [N]: solver.tolerance x max(E r^2, the needle force), the force
  // of the last accepted state or, while the release seeks a load, of that load.
  double force_tolerance() const {
    const double f = seek_force_ >= 0 ? seek_force_ : std::fabs(accepted_.force);
    return def_.tolerance * std::max(force_scale_, f);
  }
  double wall() const {
    return std::chrono::duration<double>(std::chrono::steady_clock::now() - start_).count();
  }
  void publish(std::span<const Vec3d> u, const Measures& m);
  void frames_up_to(double travel, std::span<const Vec3d> u, const Measures& m);

  Simulation& sim_;
  const RunOptions& options_;
  const SolverDef& def_;
  const JobParams& p_;
  const Model& model_;
  ElasticEnergy elastic_;
  std::unique_ptr<PenaltyContactTerm> needle_, rim_;
  std::unique_ptr<SuctionTerm> suction_;
  // After the puncture: the tip's contact held at held_travel_, where it carries the released
  // load, and the shaft's drag along the axis as a dead load shared by the vertices the tip
  // touched (per newton of drag).
  std::unique_ptr<SuctionTerm> released_;
  std::vector<int32_t> released_vertex_;
  std::vector<Vec3d> released_load_;
  double punctured_travel_ = 0;
  double held_travel_ = 0;  // where the tip's contact is held after the puncture [m]
  double last_force_before_ = 0;  // the needle force of the state at travel_before_ [N]
  double seek_force_ = -1;        // the load the release seeks [N]; < 0: none
  std::unique_ptr<InertiaTerm> inertia_;
  std::unique_ptr<NewtonSolver> newton_;
  std::unique_ptr<NewtonSolver> oracle_;  // solver.oracle: the same solves on the direct solver
  std::vector<int32_t> suction_vertex_;
  std::vector<Vec3d> suction_load_;
  double suction_ramp_ = 0;
  double force_scale_ = 0;  // E_max r_tip^2 [N]
  double speed_ = 0, end_travel_ = 0;
  int export_count_ = 0;
  int all_slid_steps_ = 0;  // load steps running in which every rim contact slid

  std::vector<Vec3d> oracle_start_;

  // The accepted state.
  std::vector<Vec3d> u_, v_, u_before_;
  double travel_ = 0, travel_before_ = -1;
  int64_t step_ = 0;
  Measures accepted_;
  bool punctured_ = false;
  PunctureRecord puncture_;

  RunResult result_;
  std::string failure_;
  FrameSchedule frames_;
  int next_frame_ = 0;
  double next_progress_ = 0;
  std::chrono::steady_clock::time_point start_ = std::chrono::steady_clock::now();
};

void StaticRun::build() {
  const JobSetup& setup = sim_.job_setup();
  const size_t n = model_.vertex_count();
  elastic_.set_barrier(def_.barrier_volume);
  std::span<const Vec3d> rest = model_.rest_positions;
  if (p_.needle.on) {
    std::vector<ContactPoint> points;
    if (p_.needle.on_faces) {
      std::vector<std::array<int32_t, 3>> faces(setup.tool_faces.size());
      for (size_t f = 0; f < faces.size(); ++f)
        for (int c = 0; c < 3; ++c)
          faces[f][static_cast<size_t>(c)] =
              setup.tool_vertices[static_cast<size_t>(setup.tool_faces[f][static_cast<size_t>(c)])];
      points = face_contact_points(faces, setup.tool_face_area);
    } else {
      points = vertex_contact_points(setup.tool_vertices, setup.tool_area);
    }
    needle_ = std::make_unique<PenaltyContactTerm>("needle contact", needle_field(0), rest,
                                                   std::move(points),
                                                   p_.needle.pressure_stiffness,
                                                   p_.needle.friction, p_.needle.stick_length);
  }
  if (p_.rim.on) {
    ToolField rim;
    rim.kind = ToolField::Kind::kRim;
    rim.origin = p_.rim.mouth;
    rim.axis = p_.rim.axis;
    rim.radius = p_.rim.inner_radius;
    rim.outer_radius = p_.rim.outer_radius;
    rim.edge_radius = p_.rim.edge_radius;
    rim_ = std::make_unique<PenaltyContactTerm>("rim contact", rim, rest,
                                                vertex_contact_points(setup.tool_vertices,
                                                                      setup.tool_area),
                                                p_.rim.pressure_stiffness, p_.rim.friction,
                                                p_.rim.stick_length);
    for (size_t i = 0; i < setup.tool_vertices.size(); ++i) {
      const Vec3d f = setup.tool_suction[i];
      if (f.x == 0 && f.y == 0 && f.z == 0) continue;
      suction_vertex_.push_back(setup.tool_vertices[i]);
      suction_load_.push_back(f);
    }
    suction_ = std::make_unique<SuctionTerm>(suction_vertex_, suction_load_);
  }
  // The regulariser: the real mass (density x lumped volume) and Stokes drag 6 pi eta R over
  // the surface by area.
  std::vector<double> mass(n, 0.0), drag(n, 0.0);
  for (size_t t = 0; t < model_.tet_count(); ++t) {
    const double rho =
        model_.materials[static_cast<size_t>(model_.tet_material[t])].density;
    for (int32_t v : model_.tets[t])
      mass[static_cast<size_t>(v)] += 0.25 * rho * model_.tet_shape[t].volume;
  }
  double area = 0;
  for (double a : setup.tool_area) area += a;
  const double stokes = 6.0 * M_PI * def_.medium_viscosity * 0.5 * sim_.cell_diameter();
  for (size_t i = 0; i < setup.tool_vertices.size() && area > 0; ++i)
    drag[static_cast<size_t>(setup.tool_vertices[i])] += stokes * setup.tool_area[i] / area;
  inertia_ = std::make_unique<InertiaTerm>(std::move(mass), std::move(drag));

  std::vector<EnergyTerm*> terms{&elastic_, inertia_.get()};
  if (needle_) terms.push_back(needle_.get());
  if (rim_) terms.push_back(rim_.get());
  if (suction_) terms.push_back(suction_.get());
  std::unique_ptr<LinearSolver> linear =
      def_.linear == LinearSolverKind::kDirect
          ? make_direct_solver()
          : make_cg_solver(resolved_preconditioner(def_, model_.vertex_count()) ==
                                   PreconditionerKind::kMultigrid
                               ? make_multigrid(model_.rest_positions, model_.vertex_fixed)
                               : make_block_jacobi(),
                           20000);
  NewtonOptions newton;
  newton.max_iterations = def_.max_iterations;
  // A quarter of the tip's radius (the rim's bore without a needle) per trial: the contact's
  // length scale.
  newton.max_displacement =
      0.25 * (p_.needle.on ? p_.needle.radius : p_.rim.inner_radius);
  // ZONA_NEWTON_TRACE=1: a line per Newton iteration and per solve on stderr.
  if (const char* t = std::getenv("ZONA_NEWTON_TRACE"); t != nullptr && t[0] != '0')
    newton.trace = stderr;
  if (const char* t = std::getenv("ZONA_KRYLOV_PROBE")) newton.krylov_probe = std::atof(t);
  newton_ = std::make_unique<NewtonSolver>(terms, ElasticEnergy::hessian_pattern(model_),
                                           model_.vertex_fixed, std::move(linear), newton);
  if (def_.oracle) {
    newton.trace = nullptr;
    oracle_ = std::make_unique<NewtonSolver>(terms, ElasticEnergy::hessian_pattern(model_),
                                             model_.vertex_fixed, make_direct_solver(), newton);
  }
  // ZONA_EXPORT_HESSIAN=DIR: every Newton iteration's matrix (Matrix Market), the positions
  // rest + u and the right-hand side, for the preconditioner study (docs/static.md).
  if (const char* dir = std::getenv("ZONA_EXPORT_HESSIAN")) {
    std::string folder = dir;
    newton_->on_hessian = [this, folder](const BlockSparseMatrix& h, std::span<const Vec3d> u,
                                         std::span<const Vec3d> g) {
      char stem[64];
      std::snprintf(stem, sizeof stem, "/step%04lld_iter%03d", static_cast<long long>(step_),
                    export_count_++);
      const std::string base = folder + stem;
      if (Status st = h.write_matrix_market(base + "_H.mtx"); !st) return;
      if (FILE* f = std::fopen((base + "_xg.txt").c_str(), "w")) {
        for (size_t i = 0; i < u.size(); ++i) {
          const Vec3d x = model_.rest_positions[i] + u[i];
          std::fprintf(f, "%.17g %.17g %.17g %.17g %.17g %.17g %d\n", x.x, x.y, x.z, g[i].x,
                       g[i].y, g[i].z, static_cast<int>(model_.vertex_fixed[i]));
        }
        std::fclose(f);
      }
    };
  }
  double e_max = 0;
  for (const Material& m : model_.materials) e_max = std::max(e_max, m.young);
  const double r = p_.needle.on ? p_.needle.radius : p_.rim.inner_radius;
  force_scale_ = e_max * r * r;
  speed_ = p_.needle.on && p_.needle.speed > 0 ? p_.needle.speed : 1e-4;
  end_travel_ = p_.needle.on ? (p_.needle.max_travel > 0 ? p_.needle.max_travel
                                                          : p_.needle.speed * sim_.end_time())
                             : 0.0;
  u_.assign(n, Vec3d{0, 0, 0});
  v_.assign(n, Vec3d{0, 0, 0});
  u_before_ = u_;
}

ToolField StaticRun::needle_field(double travel) const {
  ToolField f;
  f.kind = ToolField::Kind::kNeedle;
  f.origin = p_.needle.start + travel * p_.needle.direction;
  f.axis = p_.needle.direction;
  f.radius = p_.needle.radius;
  f.flat = p_.needle.flat != 0;
  return f;
}

bool StaticRun::solve_at(double s, std::vector<Vec3d>& u, NewtonStats* stats) {
  if (needle_) {
    // After the puncture the tip stays where the membrane gave way (the explicit step's rule).
    needle_->set_field(needle_field(punctured_ ? held_travel_ : s));
  }
  if (suction_) suction_->set_ramp(suction_ramp_);
  if (released_) released_->set_ramp(released_ramp(s));
  const double ds = s - travel_;
  const double h = (ds > 0 ? ds : def_.travel_step) / speed_;
  inertia_->set_step(h, u_, v_);
  if (!std::isfinite(newton_->evaluate(u, {}))) u = u_;  // a guess past the barrier
  if (oracle_) oracle_start_ = u;
  if (newton_->options().trace)
    std::fprintf(newton_->options().trace, "solve travel_um %.6g from_um %.6g suction %.4g\n",
                 s * 1e6, travel_ * 1e6, suction_ramp_);
  *stats = newton_->solve(u, force_tolerance());
  result_.newton_iterations += stats->iterations;
  result_.krylov_iterations += stats->krylov;
  if (!stats->converged) {
    failure_ = stats->failure;
    ++result_.failed_solves;
  }
  if (oracle_ && stats->converged) compare_with_oracle(u);
  return stats->converged;
}

void StaticRun::compare_with_oracle(std::span<const Vec3d> u) {
  std::vector<Vec3d> direct = oracle_start_;
  const auto start = std::chrono::steady_clock::now();
  const NewtonStats st = oracle_->solve(direct, force_tolerance());
  double diff = 0, size = 0;
  for (size_t i = 0; i < u.size(); ++i) {
    diff = std::max(diff, norm(u[i] - direct[i]));
    size = std::max(size, norm(direct[i]));
  }
  if (FILE* trace = newton_->options().trace)
    std::fprintf(trace, "oracle converged %d difference %.3e newton %d cg %lld ms %.1f\n",
                 st.converged ? 1 : 0, size > 0 ? diff / size : 0.0, st.iterations,
                 static_cast<long long>(st.krylov),
                 std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start)
                     .count());
  if (!st.converged) {
    ++result_.oracle_failures;
    return;
  }
  ++result_.oracle_solves;
  result_.oracle_max_difference =
      std::max(result_.oracle_max_difference, size > 0 ? diff / size : 0.0);
}

Measures StaticRun::measure(std::span<const Vec3d> u, double travel) {
  Measures m;
  m.travel = travel;
  const Vec3d dir = p_.needle.direction;
  if (p_.record.has_entry) {
    Vec3d e{0, 0, 0};
    for (int c = 0; c < 3; ++c)
      e += p_.record.entry_weight[c] * u[static_cast<size_t>(p_.record.entry_vertex[c])];
    m.deformation = dot(e, dir);
  }
  if (needle_) {
    needle_->set_field(needle_field(punctured_ ? held_travel_ : travel));  // its pose
    const PenaltyContactTerm::Load l = needle_->load(u);
    m.force_vector = l.force;
    m.force = dot(l.force, dir);
    m.contacts = l.contacts;
    m.depth = l.depth;
  }
  if (released_) {
    const double r = released_ramp(travel);
    for (const Vec3d& f : released_load_) m.force_vector += r * f;
    m.force = dot(m.force_vector, dir);
  }
  if (rim_) {
    const PenaltyContactTerm::Load l = rim_->load(u);
    Vec3d h = l.force;
    m.holding_contacts = l.contacts;
    for (size_t i = 0; i < suction_vertex_.size(); ++i) h += suction_ramp_ * suction_load_[i];
    m.holding = dot(h, dir);
  }
  m.elastic = elastic_.energy(u);
  return m;
}

ForceSample StaticRun::sample(const Measures& m, const NewtonStats& stats) const {
  ForceSample s;
  s.time = m.travel / speed_;
  s.travel = m.travel;
  s.deformation = m.deformation;
  s.force = s.raw_force = m.force;
  s.force_vector = m.force_vector;
  s.holding_force = m.holding;
  s.contacts = static_cast<int32_t>(m.contacts);
  s.holding_contacts = static_cast<int32_t>(m.holding_contacts);
  s.elastic_energy = m.elastic;
  s.punctured = punctured_;
  s.newton_iterations = stats.iterations;
  s.krylov_iterations = stats.krylov;
  s.residual = stats.residual;
  return s;
}

void StaticRun::emit(const ForceSample& s) {
  result_.samples.push_back(s);
  if (options_.on_sample) options_.on_sample(s);
  result_.peak_force = std::max(result_.peak_force, s.force);
  result_.peak_deformation = std::max(result_.peak_deformation, s.deformation);
}

void StaticRun::publish(std::span<const Vec3d> u, const Measures& m) {
  NeedleReport r;
  r.time = m.travel / speed_;
  r.step = step_;
  r.tip = needle_field(m.travel).origin;
  r.travel = m.travel;
  r.deformation = m.deformation;
  r.force = r.raw_force = m.force;
  r.force_vector = m.force_vector;
  r.contacts = static_cast<int32_t>(m.contacts);
  r.elastic_energy = m.elastic;
  r.punctured = punctured_;
  sim_.publish_static_state(u, r, puncture_);
}

void StaticRun::frames_up_to(double travel, std::span<const Vec3d> u, const Measures& m) {
  if (!options_.frame || frames_.count <= 0) return;
  bool published = false;
  while (next_frame_ < frames_.count) {
    const double at = frames_.count > 1 ? end_travel_ * next_frame_ / (frames_.count - 1) : 0.0;
    if (at > travel + 1e-15) break;
    if (!published) publish(u, m);
    published = true;
    options_.frame(sim_, next_frame_++);
  }
}

bool StaticRun::shortened_step_holds(double step, const char* what) {
  if (step >= def_.min_travel_step) return true;
  char line[640];
  std::snprintf(line, sizeof line,
                "%s from %.4g um of travel did not converge down to a step of %.3g um: %s; "
                "nothing after it is a result",
                what, travel_ * 1e6, def_.min_travel_step * 1e6, failure_.c_str());
  stop(line);
  return false;
}

void StaticRun::accept(std::vector<Vec3d>& u, double s, const NewtonStats& stats, bool row) {
  const double ds = s - travel_;
  const double h = (ds > 0 ? ds : def_.travel_step) / speed_;
  for (size_t i = 0; i < u.size(); ++i) v_[i] = (1.0 / h) * (u[i] - u_[i]);
  ++step_;
  // Measured with the friction the state was solved with (before the anchors move).
  if (ds > 0) last_force_before_ = accepted_.force;
  accepted_ = measure(u, s);
  int64_t rim_slid = 0, rim_contacts = 0;
  if (needle_) {
    needle_->commit(u);
    needle_->lag(u, step_);
  }
  if (rim_) {
    rim_contacts = rim_->lagged_contacts();
    rim_slid = rim_->commit(u);
    rim_->lag(u, step_);
  }
  if (ds > 0) {
    u_before_ = u_;
    travel_before_ = travel_;
  }
  u_ = u;
  travel_ = s;
  result_.steps = step_;
  if (row) emit(sample(accepted_, stats));
  frames_up_to(s, u_, accepted_);
  // What ends the run. (An inverted element cannot be accepted: the barrier makes its energy
  // infinite. Checked all the same, as every result is.)
  if (const double j = elastic_.min_volume_ratio(u_); !(j > 0)) {
    char line[160];
    std::snprintf(line, sizeof line,
                  "load step %lld (travel %.4g um): an element inverted (volume ratio %.3g); "
                  "nothing after it is a result",
                  static_cast<long long>(step_), s * 1e6, j);
    stop(line);
    return;
  }
  if (!punctured_ && p_.needle.breach_depth > 0 && accepted_.depth > p_.needle.breach_depth) {
    char line[320];
    std::snprintf(line, sizeof line,
                  "load step %lld (travel %.4g um): the needle went through the cell surface "
                  "without a puncture (a surface point %.3g um inside the tip, at %.3g um of "
                  "deformation and %.3g uN); nothing after it is a result",
                  static_cast<long long>(step_), s * 1e6, accepted_.depth * 1e6,
                  accepted_.deformation * 1e6, accepted_.force * 1e6);
    stop(line);
    result_.status = static_cast<StepStatus>(result_.status | kStepToolBreach);
    return;
  }
  // Every rim contact sliding in one load step happens while the needle seats the cell; in
  // kLostSteps load steps running, the holder has let the cell go.
  constexpr int kLostSteps = 3;
  if (ds > 0) all_slid_steps_ = rim_contacts > 0 && rim_slid == rim_contacts ? all_slid_steps_ + 1 : 0;
  if (all_slid_steps_ >= kLostSteps && accepted_.contacts > 0) {
    char line[240];
    std::snprintf(line, sizeof line,
                  "load step %lld (travel %.4g um): the holder lost the cell: all %lld of its "
                  "rim contacts slid in 3 load steps running (at %.3g uN on the needle)",
                  static_cast<long long>(step_), s * 1e6, static_cast<long long>(rim_contacts),
                  accepted_.force * 1e6);
    stop(line);
  }
}

RunResult StaticRun::run() {
  build();
  frames_ = frame_schedule(sim_.scene(), sim_.end_time());
  result_.samples.push_back(ForceSample{});
  accepted_ = measure(u_, 0);
  frames_up_to(0, u_, accepted_);
  std::vector<Vec3d> u = u_;
  NewtonStats stats;
  // Suction, ramped in with the needle at its start. The seating is a fictitious path to the
  // held state: until the rim's friction has been lagged from a state in contact, the cell can
  // spin on the rim with nothing but the regulariser against it (and the contact's
  // nanometre-deep penalty makes Newton crawl along that spin), so a ramp step that does not
  // converge is taken as it stands (its energy is lower than its start) and its contacts
  // lagged; the full suction is then solved to the tolerance, re-lagged up to
  // kSettleSteps times.
  constexpr int kSettleSteps = 4, kRampIterations = 6;
  // The first release step, as a fraction of the puncture load. Small: as the needle unloads,
  // the friction of its contact points turns round, and on the default scene first steps of
  // 1/8 to 1/128 each ran their 30 Newton iterations before being halved, down to this one (the
  // same path then: the same states, 150 Newton iterations fewer); later steps grow.
  constexpr double kReleaseFirstStep = 1.0 / 256;
  if (suction_) {
    for (int k = 1; k <= def_.suction_steps + kSettleSteps && !result_.stopped_early; ++k) {
      suction_ramp_ = std::min(1.0, static_cast<double>(k) / def_.suction_steps);
      const bool full = k >= def_.suction_steps;
      // A ramp step is a stage of the seating, not a result: a few iterations, then its
      // contacts are lagged.
      const int max_iterations = newton_->options().max_iterations;
      if (!full) newton_->options().max_iterations = kRampIterations;
      const bool converged = solve_at(0, u, &stats);
      newton_->options().max_iterations = max_iterations;
      if (converged && full) {
        accept(u, 0, stats, false);
        break;
      }
      if (!converged && k == def_.suction_steps + kSettleSteps) {
        stop("holding: the full suction did not converge in " + std::to_string(kSettleSteps + 1) +
             " load steps: " + failure_);
        break;
      }
      if (!std::isfinite(newton_->evaluate(u, {}))) u = u_;
      accept(u, 0, stats, false);
    }
  }
  // The travel.
  const double kMicron = 1e-6;
  std::vector<double> targets{10 * kMicron, 20 * kMicron, 30 * kMicron, 40 * kMicron};
  size_t next_target = 0;
  double step = def_.travel_step;
  std::vector<Vec3d> trial;
  const PunctureParams& pp = p_.puncture;
  auto criterion = [&](const Measures& m) {
    return pp.criterion == kJobCriterionForce ? m.force : m.elastic;
  };
  const bool can_puncture =
      pp.criterion == kJobCriterionForce || pp.criterion == kJobCriterionEnergy;
  while (needle_ && !result_.stopped_early && travel_ < end_travel_ * (1 - 1e-12)) {
    if (options_.stop && options_.stop->load(std::memory_order_relaxed)) {
      result_.interrupted = true;
      break;
    }
    const double s = std::min(end_travel_, travel_ + step);
    // Predictor: the last step's displacement per travel, continued.
    trial = u_;
    if (travel_before_ >= 0 && travel_ > travel_before_) {
      const double f = (s - travel_) / (travel_ - travel_before_);
      for (size_t i = 0; i < trial.size(); ++i) trial[i] += f * (u_[i] - u_before_[i]);
    }
    if (!solve_at(s, trial, &stats)) {
      step *= 0.5;
      shortened_step_holds(step, "the load step");
      continue;
    }
    Measures m = measure(trial, s);
    // The first event inside (travel_, s]: a row's deformation, or the puncture.
    double event_target = -1, event_puncture = -1;
    if (next_target < targets.size() && m.deformation >= targets[next_target] &&
        accepted_.deformation < targets[next_target])
      event_target = travel_ + (s - travel_) * (targets[next_target] - accepted_.deformation) /
                                   (m.deformation - accepted_.deformation);
    if (can_puncture && !punctured_ && criterion(m) >= pp.threshold &&
        criterion(accepted_) < pp.threshold)
      event_puncture = travel_ + (s - travel_) * (pp.threshold - criterion(accepted_)) /
                                     (criterion(m) - criterion(accepted_));
    const bool do_target = event_target >= 0 && (event_puncture < 0 || event_target <= event_puncture);
    if (do_target) {
      // Regula falsi (Illinois) in travel on deformation - target.
      const double target = targets[next_target];
      double lo = travel_, hi = s, flo = accepted_.deformation - target,
             fhi = m.deformation - target;
      std::vector<Vec3d> u_hi = trial;
      int side = 0;
      Measures mm = m;
      NewtonStats st = stats;
      for (int it = 0; it < 30 && std::fabs(mm.deformation - target) > 1e-4 * target; ++it) {
        const double x = hi - fhi * (hi - lo) / (fhi - flo);
        std::vector<Vec3d> ux = u_;
        const double w = (x - travel_) / (hi - travel_);
        for (size_t i = 0; i < ux.size(); ++i) ux[i] += w * (u_hi[i] - u_[i]);
        if (!solve_at(x, ux, &st)) break;
        mm = measure(ux, x);
        const double fx = mm.deformation - target;
        if ((fx > 0) == (fhi > 0)) {
          hi = x;
          fhi = fx;
          u_hi = ux;
          if (side == -1) flo *= 0.5;
          side = -1;
        } else {
          lo = x;
          flo = fx;
          if (side == 1) fhi *= 0.5;
          side = 1;
        }
        trial = ux;
        stats = st;
        m = mm;
      }
      if (std::fabs(m.deformation - target) > 1e-4 * target) {
        char line[200];
        std::snprintf(line, sizeof line,
                      "the row at %.4g um of deformation was not found to 1e-4 (%.6g um)",
                      target * 1e6, m.deformation * 1e6);
        stop(line);
        break;
      }
      ++next_target;
      accept(trial, m.travel, stats);
      continue;
    }
    if (event_puncture >= 0) {
      // Bisection in travel: lo below the threshold, hi at or above it. Every midpoint is a
      // load step from the accepted state. One that does not converge is a load step too long
      // for it, as in the travel loop: the bracket's converged state below the threshold is
      // accepted where there is one (a load step like any other), else the step is halved, and
      // the travel loop goes on from there (it stops the run below solver.min_travel_step).
      double lo = travel_, hi = s;
      std::vector<Vec3d> u_hi = trial, u_lo;
      Measures m_hi = m, m_lo;
      NewtonStats st_hi = stats, st_lo;
      bool shortened = false;
      while (hi - lo > def_.puncture_tolerance) {
        const double x = 0.5 * (lo + hi);
        std::vector<Vec3d> ux = u_;
        const double w = (x - travel_) / (hi - travel_);
        for (size_t i = 0; i < ux.size(); ++i) ux[i] += w * (u_hi[i] - u_[i]);
        NewtonStats st;
        if (!solve_at(x, ux, &st)) {
          // (Not past the next row's deformation: the row would be skipped.)
          if (lo > travel_ &&
              (next_target >= targets.size() || m_lo.deformation < targets[next_target])) {
            accept(u_lo, lo, st_lo);
            step = hi - lo;
          } else {
            step = 0.5 * (x - travel_);
          }
          shortened = true;
          break;
        }
        const Measures mx = measure(ux, x);
        if (criterion(mx) >= pp.threshold) {
          hi = x;
          u_hi = ux;
          m_hi = mx;
          st_hi = st;
        } else {
          lo = x;
          u_lo = std::move(ux);
          m_lo = mx;
          st_lo = st;
        }
      }
      if (result_.stopped_early) break;
      if (shortened) {
        if (newton_->options().trace)
          std::fprintf(newton_->options().trace, "shortened bisection: next step %.6g um\n",
                       step * 1e6);
        if (!shortened_step_holds(step, "the puncture's bisection: the load step")) break;
        continue;
      }
      // The vertices the tip loads at the puncture (they share the shaft's drag later).
      std::vector<Vec3d> g_needle(u_hi.size(), Vec3d{0, 0, 0});
      needle_->set_field(needle_field(hi));
      needle_->add_gradient(u_hi, g_needle);
      accept(u_hi, hi, st_hi);
      if (result_.stopped_early) break;
      result_.puncture_wall_seconds = wall();
      punctured_ = true;
      puncture_.punctured = true;
      puncture_.step = step_;
      puncture_.time = hi / speed_;
      puncture_.needle_travel = hi;
      puncture_.deformation = m_hi.deformation;
      puncture_.force = m_hi.force;
      puncture_.energy = m_hi.elastic;
      puncture_.force_vector = m_hi.force_vector;
      punctured_travel_ = hi;
      held_travel_ = hi;
      // The release. The membrane has given way: the needle's load falls by force_drop and
      // stays there while the shaft's drag grows. The explicit step holds the tip and scales its
      // contact down until it carries the released load; here the contact's law is kept and its
      // pose is drawn back along the axis until it carries that load (a secant on the pose
      // against the load, which falls monotonically as it draws back), on the same branch of
      // equilibria the loading came up, so every state on the way is a stable minimum. Holding
      // the contact and scaling it (or replacing it by the dead load it carried, which is the
      // same equilibrium at the puncture but not a stable one) leaves the minimiser to crawl or
      // run away under a point load on a deep indentation.
      {
        const std::vector<Vec3d>& g = g_needle;
        int64_t touched = 0;
        for (const Vec3d& v : g) touched += (v.x != 0 || v.y != 0 || v.z != 0) ? 1 : 0;
        for (size_t v = 0; v < g.size(); ++v)
          if (g[v].x != 0 || g[v].y != 0 || g[v].z != 0) {
            released_vertex_.push_back(static_cast<int32_t>(v));
            released_load_.push_back((1.0 / static_cast<double>(touched)) * p_.needle.direction);
          }
        released_ = std::make_unique<SuctionTerm>(released_vertex_, released_load_,
                                                  "shaft drag");
        newton_->add_term(released_.get());
        if (oracle_) oracle_->add_term(released_.get());
      }
      // Release steps: each draws the pose back by the load the loading branch's slope (then
      // the release's own secant slope) says, from a guess continued from the last release
      // step. A step on the way is a continuation state, not a result: it takes the load it
      // lands on. The last one is matched to the released load by a secant on the pose (to 1e-3
      // of the puncture load). A step that does not converge is halved.
      const double f0 = puncture_.force;
      const double released = 1.0 - pp.force_drop;
      // The loading branch's slope at the puncture [N/m], for the first guess.
      const double slope0 = std::max(
          travel_before_ >= 0 && hi > travel_before_
              ? (f0 - last_force_before_) / (hi - travel_before_) : 0.0,
          std::fabs(f0) / std::max(hi, 1e-9));
      std::vector<Vec3d> ur = u_, ur_prev;
      double pose_prev = 0, fraction = 1, dfraction = kReleaseFirstStep, slope = slope0;
      while (fraction > released * (1 + 1e-9) && !result_.stopped_early) {
        const double next = std::max(released, fraction - dfraction);
        const bool last = next == released;
        const double target = next * f0;
        seek_force_ = std::fabs(target);
        const double held = held_travel_;
        double e = held - (fraction - next) * f0 / slope, force = 0;
        std::vector<Vec3d> trial_r = ur;
        if (!ur_prev.empty() && held != pose_prev) {
          const double w = (e - held) / (held - pose_prev);
          for (size_t i = 0; i < trial_r.size(); ++i) trial_r[i] += w * (ur[i] - ur_prev[i]);
        }
        double e_lo = held, f_lo = fraction * f0;
        bool ok = false;
        for (int it = 0; it < 12; ++it) {
          held_travel_ = e;
          if (!solve_at(hi, trial_r, &stats)) break;
          force = measure(trial_r, hi).force;
          if (!last || std::fabs(force - target) <= 1e-3 * std::fabs(f0)) {
            ok = true;
            break;
          }
          const double s_it = force != f_lo && e != e_lo ? (force - f_lo) / (e - e_lo) : slope;
          e_lo = e;
          f_lo = force;
          e -= (force - target) / (s_it > 0 ? s_it : slope);
        }
        if (ok && force < fraction * f0) {
          if (e != held) slope = std::max((fraction * f0 - force) / (held - e), 1e-3 * slope0);
          fraction = last ? released : force / f0;
          ur_prev.swap(ur);
          ur.swap(trial_r);
          pose_prev = held;
          // A load step of its own: its friction committed and lagged, as the loading's are.
          if (!last) accept(ur, hi, stats, false);
          if (stats.iterations <= 4) dfraction *= 1.5;
        } else {
          held_travel_ = held;
          if ((dfraction *= 0.5) < kReleaseFirstStep / 64)
            stop("the state after the puncture's release did not converge at " +
                 std::to_string(fraction) + " of the puncture load: " +
                 (failure_.empty() ? std::string("the tip's load did not reach its target")
                                   : failure_));
        }
      }
      seek_force_ = -1;
      if (result_.stopped_early) break;
      accept(ur, hi, stats);
      travel_before_ = -1;  // the predictor continues no step across the release
      next_target = targets.size();  // rows at set deformations are the loading branch's
      if (options_.stop_after_puncture >= 0) break;
      continue;
    }
    accept(trial, s, stats);
    if (stats.iterations <= 4) step = std::min(def_.travel_step, 1.5 * step);
    if (options_.progress && wall() >= next_progress_) {
      publish(u_, accepted_);
      options_.progress(RunProgress{travel_ / speed_, end_travel_ / speed_, wall(), &sim_.report()});
      next_progress_ = wall() + options_.progress_interval;
    }
  }
  publish(u_, accepted_);
  if (!result_.stopped_early && !result_.interrupted)
    frames_up_to(end_travel_, u_, accepted_);
  result_.puncture = puncture_;
  result_.simulated_time = travel_ / speed_;
  result_.quasi_limits = sim_.quasi_limits();
  result_.wall_seconds = wall();
  if (options_.progress)
    options_.progress(RunProgress{travel_ / speed_, end_travel_ / speed_, result_.wall_seconds,
                                  &sim_.report()});
  return std::move(result_);
}

}  // namespace

RunResult run_static(Simulation& sim, const RunOptions& options) {
  auto refused = [](const std::string& why) {
    RunResult r;
    r.stopped_early = true;
    r.stop_reason = why;
    return r;
  };
  if (Status st = check_static_scene(sim.scene()); !st) return refused(st.error().message);
  if (sim.backend())
    return refused("solver.method \"static\" runs on the CPU (its GPU path is not built yet)");
  if (!sim.job_mode()) return refused("solver.method \"static\" needs the penalty contact");
  // Every pass of a Newton iteration runs on the shared pool: as many threads as the run asks
  // for (--threads), else every core this process may run on.
  set_shared_pool_threads(options.simulation.threads);
  Result<ElasticEnergy> elastic = ElasticEnergy::create(sim.model());
  if (!elastic.ok()) return refused(elastic.error().message);
  StaticRun run(sim, options, std::move(*elastic));
  return run.run();
}

}  // namespace zona

namespace zona {

void Simulation::publish_static_state(std::span<const Vec3d> u, const NeedleReport& report,
                                      const PunctureRecord& puncture) {
  std::copy(u.begin(), u.end(), state_.u.begin());
  std::copy(u.begin(), u.end(), state_.u_prev.begin());
  state_.time = report.time;
  state_.step_count = report.step;
  report_ = report;
  job_puncture_ = puncture;
}

}  // namespace zona
