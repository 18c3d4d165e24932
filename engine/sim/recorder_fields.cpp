// The fields of a VTU frame (recorder.h's frame_fields): displacement and contact at the
// points; Green strain and von Mises stress per tetrahedron; Cauchy stress, Green strain and von
// Mises stress averaged to the vertices (volume-weighted), with the nodal pressure at the vertex
// under the nodal-pressure neo-Hookean law.
#include <algorithm>
#include <cmath>

#include "engine/fem/fem_element.h"
#include "engine/sim/recorder.h"

namespace zona {
namespace {

double von_mises(const Mat3d& s) {
  const double a = s.m[0][0] - s.m[1][1], b = s.m[1][1] - s.m[2][2], c = s.m[2][2] - s.m[0][0];
  const double shear = s.m[0][1] * s.m[0][1] + s.m[1][2] * s.m[1][2] + s.m[0][2] * s.m[0][2];
  return std::sqrt(0.5 * (a * a + b * b + c * c) + 3.0 * shear);
}

// Cauchy stress [Pa] of tetrahedron t at displacement gradient h, by the model's law: F S F^T / J
// for SVK, P F^T / J for SNH, the small-strain stress for the linear law. An inverted element
// (J <= 0) reports the Kirchhoff stress J sigma (F S F^T, P F^T), which stays defined and
// symmetric (P alone is not symmetric). Under nodal pressure: the element part only (the
// law with lambda_s = mu, snh_first_piola_nodal at zero pressure); the pressure is the vertex's.
Mat3d tet_cauchy_stress(const Model& model, size_t t, const Mat3d& h) {
  const Lame& lame = model.tet_lame(t);
  Mat3d f = h;
  for (int i = 0; i < 3; ++i) f.m[i][i] += 1.0;
  double psi = 0;
  switch (model.constitutive) {
    case ConstitutiveModel::kSvk: {
      const Mat3d s = isotropic_stress(green_strain(h), lame.lambda, lame.mu, &psi);
      const double det = determinant(f);
      const Mat3d tau = f * s * transpose(f);
      return det > 0 ? (1.0 / det) * tau : tau;
    }
    case ConstitutiveModel::kStableNeoHookean: {
      Mat3d p;
      double jm1 = 0;
      if (model.nodal_pressure)
        snh_first_piola_with(h, lame.mu, snh_lambda(model.nodal_stabilisation * lame.lambda, lame.mu),
                             0.0, &p, &jm1);
      else
        snh_first_piola(h, lame.lambda, lame.mu, &p, &jm1);
      const Mat3d tau = p * transpose(f);
      return jm1 > -1.0 ? (1.0 / (1.0 + jm1)) * tau : tau;
    }
    case ConstitutiveModel::kLinear:
      break;
  }
  return isotropic_stress(small_strain(h), lame.lambda, lame.mu, &psi);
}

void store_tensor(const Mat3d& m, std::vector<double>& out, size_t index) {
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c) out[9 * index + static_cast<size_t>(3 * r + c)] = m.m[r][c];
}

VtkField& field(std::vector<VtkField>& fields, size_t i, const char* name, int components,
                size_t count) {
  VtkField& f = fields[i];
  f.name = name;
  f.components = components;
  f.values.assign(count * static_cast<size_t>(components), 0.0);
  return f;
}

}  // namespace

void frame_fields(const Simulation& sim, std::vector<VtkField>* point_data,
                  std::vector<VtkField>* cell_data) {
  frame_fields(sim.model(), sim.state(), point_data, cell_data);
  if (!sim.job_mode()) return;
  // Mark what the tools touch in this state (the needle's load stays at its puncture pose after
  // puncture).
  const JobParams& p = sim.job_setup().params;
  const PunctureRecord& q = sim.puncture();
  const Vec3d tip = q.punctured ? p.needle.start + q.needle_travel * p.needle.direction
                                : sim.report().tip;
  const std::vector<uint8_t> marks =
      job_contact_marks(sim.job_setup(), sim.model(), sim.state(), tip);
  std::vector<double>& contact = (*point_data)[1].values;
  for (size_t v = 0; v < marks.size(); ++v) contact[v] = marks[v];
}

void frame_fields(const Model& model, const State& state, std::vector<VtkField>* point_data,
                  std::vector<VtkField>* cell_data) {
  const size_t nv = model.vertex_count(), nt = model.tet_count();
  point_data->resize(5);
  VtkField& disp = field(*point_data, 0, "displacement", 3, nv);
  for (size_t v = 0; v < nv; ++v) {
    disp.values[3 * v] = state.u[v].x;
    disp.values[3 * v + 1] = state.u[v].y;
    disp.values[3 * v + 2] = state.u[v].z;
  }
  field(*point_data, 1, "contact", 1, nv);  // zeros: the Simulation overload marks the tools
  VtkField& stress = field(*point_data, 2, "stress", 9, nv);
  VtkField& strain = field(*point_data, 3, "strain", 9, nv);
  VtkField& mises = field(*point_data, 4, "von_mises", 1, nv);

  cell_data->resize(2);
  VtkField& cell_strain = field(*cell_data, 0, "green_strain", 6, nt);
  VtkField& cell_mises = field(*cell_data, 1, "von_mises_stress", 1, nt);

  // Per tetrahedron: strain and stress into the cell arrays and, weighted by the rest volume,
  // into the vertex sums (stress and strain hold the sums until the division below).
  std::vector<double> weight(nv, 0.0);
  // Nodal pressure: sum over each vertex's elements of V_e / 4 (J_e - 1), as the force pass
  // forms it (forces_cpu.cpp), recomputed here so that any backend's state gives it.
  std::vector<double> volume_change(model.nodal_pressure ? nv : 0, 0.0);
  for (size_t t = 0; t < nt; ++t) {
    const Tet& e = model.tets[t];
    const Vec3d ue[4] = {state.u[e[0]], state.u[e[1]], state.u[e[2]], state.u[e[3]]};
    const Mat3d h = tet_displacement_gradient(model.tet_shape[t], ue);
    const Mat3d green = green_strain(h);
    const double* g = &green.m[0][0];
    const double comps[6] = {g[0], g[4], g[8], g[1], g[5], g[2]};
    std::copy(comps, comps + 6, cell_strain.values.begin() + static_cast<std::ptrdiff_t>(6 * t));
    const Mat3d sigma = tet_cauchy_stress(model, t, h);
    // The nodal pressure is hydrostatic: the element part alone gives the element's von Mises.
    cell_mises.values[t] = von_mises(sigma);
    const double volume = model.tet_shape[t].volume;
    const double w = std::fabs(volume);
    const double quarter_change = model.nodal_pressure ? 0.25 * volume * snh_volume_change(h) : 0;
    for (int32_t corner : e) {
      const size_t v = static_cast<size_t>(corner);
      weight[v] += w;
      for (int r = 0; r < 3; ++r)
        for (int c = 0; c < 3; ++c) {
          stress.values[9 * v + static_cast<size_t>(3 * r + c)] += w * sigma.m[r][c];
          strain.values[9 * v + static_cast<size_t>(3 * r + c)] += w * green.m[r][c];
        }
      if (model.nodal_pressure) volume_change[v] += quarter_change;
    }
  }

  // Per vertex: the weighted means, the vertex's own pressure lambda_v (Jbar_v - 1) added under
  // nodal pressure, and the von Mises value of the mean tensor.
  for (size_t v = 0; v < nv; ++v) {
    const double inv = weight[v] > 0 ? 1.0 / weight[v] : 0.0;
    Mat3d s;
    for (int r = 0; r < 3; ++r)
      for (int c = 0; c < 3; ++c) {
        const size_t k = 9 * v + static_cast<size_t>(3 * r + c);
        stress.values[k] *= inv;
        strain.values[k] *= inv;
        s.m[r][c] = stress.values[k];
      }
    if (model.nodal_pressure && weight[v] > 0) {
      const double pressure =
          model.vertex_lambda[v] * volume_change[v] * model.vertex_inverse_volume[v];
      for (int i = 0; i < 3; ++i) s.m[i][i] += pressure;
      store_tensor(s, stress.values, v);
    }
    mises.values[v] = von_mises(s);
  }
}

}  // namespace zona
