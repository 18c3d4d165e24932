// Engine data to RenderFrame: fields, poses, overlay text, default camera (frame_source.h).
#include "render/frame_source.h"

#include <algorithm>
#include <cmath>
#include <cstdio>

#include "engine/sim/recorder.h"

namespace zona {

void displacement_magnitude(std::span<const Vec3d> u, std::vector<float>* out) {
  out->resize(u.size());
  for (size_t i = 0; i < u.size(); ++i) (*out)[i] = static_cast<float>(norm(u[i]));
}

void vertex_von_mises(const Simulation& simulation, std::vector<float>* out) {
  std::vector<VtkField> point_data, cell_data;
  frame_fields(simulation, &point_data, &cell_data);
  const Model& model = simulation.model();
  const std::vector<double>* mises = nullptr;
  for (const VtkField& f : cell_data)
    if (f.name == "von_mises_stress") mises = &f.values;
  out->assign(model.vertex_count(), 0.0f);
  if (!mises) return;
  std::vector<double> sum(model.vertex_count(), 0.0), weight(model.vertex_count(), 0.0);
  for (size_t t = 0; t < model.tet_count(); ++t) {
    const double w = std::abs(model.tet_shape[t].volume);
    for (int32_t v : model.tets[t]) {
      sum[v] += w * (*mises)[t];
      weight[v] += w;
    }
  }
  for (size_t v = 0; v < sum.size(); ++v)
    (*out)[v] = weight[v] > 0 ? static_cast<float>(sum[v] / weight[v]) : 0.0f;
}

OrbitCamera default_camera(const Mesh& mesh, double fill) {
  const Aabb box = mesh_bounds(mesh);
  const Vec3d centre = 0.5 * (box.lo + box.hi);
  // The bounding sphere about the box centre (the box's half diagonal overstates a ball's).
  double radius = 0;
  for (const Vec3d& x : mesh.rest_positions) radius = std::max(radius, norm(x - centre));
  return fit_camera(centre, radius > 0 ? radius : 1e-6, fill);
}

Result<ColorField> parse_color_field(const std::string& name) {
  if (name == "displacement") return ColorField::kDisplacement;
  if (name == "stress") return ColorField::kStress;
  if (name == "none") return ColorField::kNone;
  return make_error("colour field '%s': expected displacement, stress or none", name.c_str());
}

std::vector<std::string> overlay_lines(const std::string& title, const NeedleReport& report,
                                       const OverlayRates& rates) {
  std::vector<std::string> lines;
  char text[160];
  if (!title.empty()) lines.push_back(title);
  std::snprintf(text, sizeof(text), "t = %.2f ms   step %lld", report.time * 1e3,
                static_cast<long long>(report.step));
  lines.push_back(text);
  std::snprintf(text, sizeof(text), "needle force %.3f uN   stiffness %.3g N/m", report.force * 1e6,
                report.stiffness);
  lines.push_back(text);
  std::snprintf(text, sizeof(text), "travel %.1f um   deformation %.1f um", report.travel * 1e6,
                report.deformation * 1e6);
  lines.push_back(text);
  std::string rate_line;
  if (rates.simulation_hz > 0) {
    std::snprintf(text, sizeof(text), "sim %.0f steps/s", rates.simulation_hz);
    rate_line += text;
  }
  if (rates.haptic_hz > 0) {
    std::snprintf(text, sizeof(text), "%shaptic %.0f Hz", rate_line.empty() ? "" : "   ",
                  rates.haptic_hz);
  } else {
    std::snprintf(text, sizeof(text), "%shaptic: no device", rate_line.empty() ? "" : "   ");
  }
  rate_line += text;
  if (rates.render_hz > 0) {
    std::snprintf(text, sizeof(text), "   render %.0f fps", rates.render_hz);
    rate_line += text;
  }
  lines.push_back(rate_line);
  lines.push_back(report.punctured ? "membrane PUNCTURED" : "membrane intact");
  return lines;
}

NeedlePose needle_pose(const Simulation& simulation, Vec3d tip) {
  NeedlePose pose;
  const Scene& scene = simulation.scene();
  pose.visible = scene.needle.enabled;
  pose.tip = tip;
  pose.direction = simulation.needle_script().direction;
  pose.tip_radius = scene.needle.tip_radius;
  pose.flat_tip = scene.needle.shape == NeedleShape::kFlat;
  return pose;
}

HoldingPose holding_pose(const Simulation& simulation) {
  HoldingPose pose;
  const auto& holding = simulation.holding();
  if (!holding) return pose;
  pose.visible = true;
  pose.mouth = holding->geometry.mouth;
  pose.axis = holding->geometry.axis;
  pose.inner_radius = holding->geometry.inner_radius;
  pose.outer_radius = holding->geometry.outer_radius;
  return pose;
}

void frame_from_simulation(const Simulation& simulation, ColorField field,
                           SimulationFrameData* data, RenderFrame* frame) {
  const Model& model = simulation.model();
  data->displacement.assign(
      simulation.state().u.begin(),
      simulation.state().u.begin() + static_cast<std::ptrdiff_t>(model.vertex_count()));
  if (field == ColorField::kDisplacement)
    displacement_magnitude(data->displacement, &data->scalar);
  else if (field == ColorField::kStress)
    vertex_von_mises(simulation, &data->scalar);
  else
    data->scalar.clear();
  frame->rest = model.rest_positions;
  frame->displacement = data->displacement;
  frame->triangles = simulation.surface().triangles;
  frame->scalar = data->scalar;
  frame->field = field;
  // Before the first step the report holds no pose yet: the script's start is the tip.
  const Vec3d tip = simulation.report().step > 0 ? simulation.report().tip
                                                 : needle_tip_at(simulation.needle_script(), 0.0);
  frame->needle = needle_pose(simulation, tip);
  frame->holding = holding_pose(simulation);
}

std::vector<Vec3d> indentation_field(std::span<const Vec3d> rest, Vec3d centre, Vec3d direction,
                                     double depth, double radius) {
  std::vector<Vec3d> u(rest.size(), Vec3d{0, 0, 0});
  for (size_t i = 0; i < rest.size(); ++i) {
    const double d = norm(rest[i] - centre) / radius;
    if (d < 1) u[i] = (depth * (1 - d * d) * (1 - d * d)) * direction;
  }
  return u;
}

}  // namespace zona
