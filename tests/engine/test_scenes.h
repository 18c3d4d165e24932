// Scenes shared by the simulation tests on the CPU (tests/engine) and their GPU counterparts
// (tests/kernels), so that both run the same experiment.
#pragma once

#include <cstdio>
#include <string>

#include <nlohmann/json.hpp>

namespace zona::test {

/// A 24 um cell of 250 vertices, held on the far side, pushed 6.5 um by a 3 um needle at
/// 0.2 mm/s, with stiffness damping (a load that changes every step).
inline nlohmann::json small_cell_scene() {
  return nlohmann::json{
      {"mesh", {{"generate", {{"diameter", "24 um"}, {"vertices", 250}}}}},
      {"model", "svk"},
      {"materials",
       {{"default", {{"young", "17.9 kPa"}, {"poisson", 0.45}, {"damping", "50 1/s"}}}}},
      {"integrator",
       {{"target_dt", "10 us"}, {"mass_scaling_mode", "selective"}, {"dt_safety", 0.25},
        {"stiffness_damping", "50 us"}}},
      {"needle",
       {{"tip_radius", "3 um"}, {"standoff", "0.5 um"}, {"speed", "0.2 mm/s"},
        {"max_travel", "6.5 um"}}},
      {"holding_pipette", {{"mode", "fixed"}, {"inner_radius", "6 um"}}},
      {"output", {{"frames", 0}, {"sample_interval", "0.1 ms"}}}};
}

/// The particle model (Asgari et al.) of an 800 um cell, 642 particles (48-66 um apart), pushed
/// along +x by a 60 um sphere at `speed` [m/s] up to 250 um of travel. (The shipped scene's 30 um
/// tip needs its 2562 particles: on 642 the penalty contact lets it through between them.)
inline nlohmann::json particle_scene(double speed = 2e-3) {
  char speed_text[32];
  std::snprintf(speed_text, sizeof speed_text, "%g m/s", speed);
  return nlohmann::json{
      {"mesh", {{"generate", {{"diameter", "800 um"}}}}},
      {"model", "particles"},
      {"particles",
       {{"particles", 642},
        {"membrane_modulus", "20 N/m"},
        {"radial_stiffness", "1000 N/m^3"},
        {"radial_damping", "3e4 N*s/m^3"},
        {"damping", {"1e4 N*s/m^3", "1e4 N*s/m^3", "2e4 N*s/m^3"}},
        {"compressibility", "1e-6 1/Pa"}}},
      {"integrator", {{"target_dt", "20 us"}}},
      {"needle",
       {{"shape", "sphere"},
        {"tip_radius", "60 um"},
        {"direction", "+x"},
        {"standoff", "10 um"},
        {"speed", std::string(speed_text)},
        {"max_travel", "250 um"}}},
      {"holding_pipette", {{"mode", "fixed"}, {"inner_radius", "150 um"}}},
      {"output", {{"frames", 0}, {"sample_interval", "1 ms"}}}};
}

}  // namespace zona::test
