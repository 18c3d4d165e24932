// `zona analytic maxwell|membrane|modulus`: Hajiyavand et al. 2019's analytic models (engine/analysis/analytic.h) from
// the command line, values with units in and out, text or --json.
#include <cmath>
#include <cstdio>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "apps/commands.h"
#include "engine/analysis/analytic.h"
#include "engine/core/units.h"

namespace zona::cli {
namespace {

// An option given as "number unit" text, parsed on use.
struct QuantityOption {
  std::string text;
  bool given() const { return !text.empty(); }
};

Result<double> quantity(const QuantityOption& o, const char* name, Dimension dimension) {
  Result<double> v = parse_quantity(o.text, dimension);
  if (!v.ok()) return make_error("%s: %s", name, v.error().message.c_str());
  return *v;
}

// Parses the options in order; the first failure is returned.
struct Parsed {
  Status status;
  void read(double& out, const QuantityOption& o, const char* name, Dimension d) {
    if (!status.ok() || !o.given()) return;
    Result<double> v = quantity(o, name, d);
    if (!v.ok()) status = v.error();
    else out = *v;
  }
};

void print_json_or(bool as_json, const nlohmann::json& j, const std::string& text) {
  if (as_json) std::printf("%s\n", j.dump(2).c_str());
  else std::printf("%s", text.c_str());
}

std::string format_line(const char* format, double a, double b = 0, double c = 0, double d = 0) {
  char line[256];
  std::snprintf(line, sizeof line, format, a, b, c, d);
  return line;
}

// ---- maxwell ----------------------------------------------------------------------------------

struct MaxwellArgs {
  QuantityOption deformation{"300 um"}, speed{"0.1 mm/s"}, time;
  QuantityOption k1, k2, k3, c2, c3;
  bool ramp = false;
  bool json = false;
};

Status run_maxwell(const MaxwellArgs& a) {
  Parsed p;
  double x = 0, v = 0, t = -1;
  p.read(x, a.deformation, "--deformation", dim::kLength);
  p.read(v, a.speed, "--speed", dim::kSpeed);
  p.read(t, a.time, "--time", dim::kTime);
  MaxwellWiechertParams params;
  const bool custom = a.k1.given() || a.k2.given() || a.k3.given() || a.c2.given() || a.c3.given();
  p.read(params.k1, a.k1, "--k1", dim::kStiffness);
  p.read(params.k[0], a.k2, "--k2", dim::kStiffness);
  p.read(params.k[1], a.k3, "--k3", dim::kStiffness);
  p.read(params.c[0], a.c2, "--c2", dim::kDamping);
  p.read(params.c[1], a.c3, "--c3", dim::kDamping);
  if (!p.status.ok()) return p.status;
  if (a.ramp && !custom) return make_error("--ramp needs the solid's --k1 .. --c3 (eq. 8 is eq. 6's form)");
  // Default time: since contact at constant speed, X / V.
  const bool time_auto = !a.time.given();
  if (time_auto) {
    if (!(v > 0)) return make_error("--time is needed when --speed is 0");
    t = x / v;
  }
  const char* law = custom ? (a.ramp ? "maxwell-wiechert ramp (X = V t)" : "eq. 6") : "eq. 8 (Table 2)";
  const double force = custom ? (a.ramp ? maxwell_wiechert_ramp_force(params, v, t)
                                        : maxwell_wiechert_force(params, x, v, t))
                              : seed002_eq8_force(x, v, t);
  nlohmann::json j = {{"model", "maxwell-wiechert"}, {"law", law},
                      {"deformation_m", a.ramp ? v * t : x}, {"speed_m_s", v},
                      {"time_s", t}, {"force_N", force}};
  if (custom)
    j["params"] = {{"k1_N_m", params.k1}, {"k2_N_m", params.k[0]}, {"k3_N_m", params.k[1]},
                   {"c2_N_s_m", params.c[0]}, {"c3_N_s_m", params.c[1]}};
  std::string text = std::string("maxwell-wiechert, ") + law + "\n";
  text += format_line("  deformation %.4g um, speed %.4g mm/s, time %.4g s",
                      (a.ramp ? v * t : x) * 1e6, v * 1e3, t);
  text += time_auto ? " (X / V)\n" : "\n";
  text += format_line("  force %.6g mN (%.6g N)\n", force * 1e3, force);
  print_json_or(a.json, j, text);
  return Status::ok_status();
}

// ---- membrane ---------------------------------------------------------------------------------

struct MembraneArgs {
  QuantityOption thickness{"3 um"}, radius{"400 um"}, load_radius{"30 um"};
  double poisson = 0.5;
  QuantityOption force, deformation, young;
  bool json = false;
};

Status run_membrane(const MembraneArgs& a) {
  Parsed p;
  PointLoadMembrane m;
  m.poisson = a.poisson;
  p.read(m.thickness, a.thickness, "--thickness", dim::kLength);
  p.read(m.radius, a.radius, "--radius", dim::kLength);
  p.read(m.load_radius, a.load_radius, "--load-radius", dim::kLength);
  double f = 0, w = 0, e = 0;
  p.read(f, a.force, "--force", dim::kForce);
  p.read(w, a.deformation, "--deformation", dim::kLength);
  p.read(e, a.young, "--young", dim::kPressure);
  if (!p.status.ok()) return p.status;
  if (Status s = check_point_load_membrane(m); !s) return s;
  const int given = int(a.force.given()) + int(a.deformation.given()) + int(a.young.given());
  if (given != 2)
    return make_error("membrane: give two of --force, --deformation, --young (the third is solved for)");
  const char* solved = "";
  if (!a.young.given()) {
    if (!(w > 0)) return make_error("--deformation must be > 0 m to solve for E");
    e = point_load_modulus(m, f, w);
    solved = "young";
  } else if (!a.force.given()) {
    f = point_load_force(m, e, w);
    solved = "force";
  } else {
    if (!(e > 0) || f < 0) return make_error("--young must be > 0 Pa and --force >= 0 N");
    w = point_load_deformation(m, e, f);
    solved = "deformation";
  }
  const double zeta = m.load_radius / m.radius;
  nlohmann::json j = {{"model", "point-load membrane (eq. 7)"}, {"solved", solved},
                      {"thickness_m", m.thickness}, {"radius_m", m.radius},
                      {"load_radius_m", m.load_radius}, {"poisson", m.poisson},
                      {"zeta", zeta}, {"factor", point_load_factor(zeta)},
                      {"force_N", f}, {"deformation_m", w}, {"young_Pa", e}};
  std::string text = "point-load membrane (Hajiyavand et al. 2019 eq. 7), solved for ";
  text.append(solved).append("\n");
  text += format_line("  h %.4g um, a %.4g um, c %.4g um, nu %.3g\n", m.thickness * 1e6,
                      m.radius * 1e6, m.load_radius * 1e6, m.poisson);
  text += format_line("  zeta %.5g, factor %.6g\n", zeta, point_load_factor(zeta));
  text += format_line("  force %.6g mN, deformation %.6g um, E %.6g MPa\n", f * 1e3, w * 1e6, e * 1e-6);
  print_json_or(a.json, j, text);
  return Status::ok_status();
}

// ---- modulus ----------------------------------------------------------------------------------

struct ModulusArgs {
  std::vector<std::string> speeds;
  QuantityOption speed0{"0.1 mm/s"}, young0{"300 MPa"}, speed1{"1 mm/s"}, young1{"500 MPa"};
  bool json = false;
};

Status run_modulus(const ModulusArgs& a) {
  Parsed p;
  SpeedModulusLaw law;
  p.read(law.speed0, a.speed0, "--speed0", dim::kSpeed);
  p.read(law.young0, a.young0, "--young0", dim::kPressure);
  p.read(law.speed1, a.speed1, "--speed1", dim::kSpeed);
  p.read(law.young1, a.young1, "--young1", dim::kPressure);
  if (!p.status.ok()) return p.status;
  if (law.speed1 == law.speed0) return make_error("--speed0 and --speed1 must differ");
  const std::vector<std::string> speeds =
      a.speeds.empty() ? std::vector<std::string>{"0.05 mm/s", "0.1 mm/s", "0.6 mm/s", "1 mm/s"} : a.speeds;
  nlohmann::json rows = nlohmann::json::array();
  std::string text = format_line("speed-dependent modulus (Hajiyavand et al. 2019 eq. 9): %.4g MPa at %.4g mm/s, "
                                 "%.4g MPa at %.4g mm/s, linear\n",
                                 law.young0 * 1e-6, law.speed0 * 1e3, law.young1 * 1e-6, law.speed1 * 1e3);
  for (const std::string& s : speeds) {
    double v = 0;
    p.read(v, QuantityOption{s}, "--speed", dim::kSpeed);
    if (!p.status.ok()) return p.status;
    const double e = speed_dependent_modulus(v, law);
    rows.push_back({{"speed_m_s", v}, {"young_Pa", e}});
    text += format_line("  %8.4g mm/s  %10.6g MPa\n", v * 1e3, e * 1e-6);
  }
  nlohmann::json j = {{"model", "speed-dependent modulus (eq. 9)"},
                      {"law", {{"speed0_m_s", law.speed0}, {"young0_Pa", law.young0},
                               {"speed1_m_s", law.speed1}, {"young1_Pa", law.young1}}},
                      {"values", rows}};
  print_json_or(a.json, j, text);
  return Status::ok_status();
}

void add_quantity(CLI::App* cmd, const char* name, QuantityOption& o, const char* help) {
  auto* opt = cmd->add_option(name, o.text, help);
  if (o.given()) opt->capture_default_str();
}

}  // namespace

void add_analytic_commands(CLI::App& app) {
  auto* group = app.add_subcommand("analytic", "Hajiyavand et al. 2019's analytic models: maxwell, membrane, modulus");
  // Its subcommand is required: main() lists them when it is missing.
  group->require_subcommand(0, 1);

  auto m = std::make_shared<MaxwellArgs>();
  auto* maxwell = group->add_subcommand(
      "maxwell", "Maxwell-Wiechert injection force: eq. 8 (Table 2), or eq. 6 with --k1..--c3");
  add_quantity(maxwell, "--deformation", m->deformation, "Deformation X (e.g. 300um)");
  add_quantity(maxwell, "--speed", m->speed, "Injection speed V (e.g. 0.1mm/s)");
  add_quantity(maxwell, "--time", m->time, "Time t (default: X / V, since contact)");
  add_quantity(maxwell, "--k1", m->k1, "Parallel spring [N/m] (eq. 6)");
  add_quantity(maxwell, "--k2", m->k2, "Arm 2 spring [N/m]");
  add_quantity(maxwell, "--k3", m->k3, "Arm 3 spring [N/m]");
  add_quantity(maxwell, "--c2", m->c2, "Arm 2 dashpot [N*s/m]");
  add_quantity(maxwell, "--c3", m->c3, "Arm 3 dashpot [N*s/m]");
  maxwell->add_flag("--ramp", m->ramp, "Exact constant-speed response instead of eq. 6 as printed");
  maxwell->add_flag("--json", m->json, "Print JSON");
  maxwell->callback([m] {
    if (Status s = run_maxwell(*m); !s) fail(s.error().message);
  });

  auto b = std::make_shared<MembraneArgs>();
  auto* membrane = group->add_subcommand(
      "membrane", "Point-load membrane (eq. 7): give two of --force, --deformation, --young");
  add_quantity(membrane, "--thickness", b->thickness, "Membrane thickness h");
  add_quantity(membrane, "--radius", b->radius, "Membrane (cell) radius a");
  add_quantity(membrane, "--load-radius", b->load_radius, "Loaded radius c (pipette tip)");
  membrane->add_option("--poisson", b->poisson, "Poisson's ratio")->capture_default_str();
  add_quantity(membrane, "--force", b->force, "Injection force F (e.g. 0.88mN)");
  add_quantity(membrane, "--deformation", b->deformation, "Deformation depth w (e.g. 294um)");
  add_quantity(membrane, "--young", b->young, "Young's modulus E (e.g. 1.32MPa)");
  membrane->add_flag("--json", b->json, "Print JSON");
  membrane->callback([b] {
    if (Status s = run_membrane(*b); !s) fail(s.error().message);
  });

  auto d = std::make_shared<ModulusArgs>();
  auto* modulus = group->add_subcommand("modulus", "Speed-dependent Young's modulus (eq. 9)");
  modulus->add_option("--speed", d->speeds, "Injection speed (repeatable; default 0.05, 0.1, 0.6, 1 mm/s)");
  add_quantity(modulus, "--speed0", d->speed0, "First calibration speed");
  add_quantity(modulus, "--young0", d->young0, "Modulus at --speed0");
  add_quantity(modulus, "--speed1", d->speed1, "Second calibration speed");
  add_quantity(modulus, "--young1", d->young1, "Modulus at --speed1");
  modulus->add_flag("--json", d->json, "Print JSON");
  modulus->callback([d] {
    if (Status s = run_modulus(*d); !s) fail(s.error().message);
  });
}

}  // namespace zona::cli
