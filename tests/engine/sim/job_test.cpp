// The injection step's stages (engine/sim/job.h): tool distance fields, penalty contact and
// friction, the needle's face quadrature, the record stage's blow-up verdict and puncture. The
// CPU runner over whole injections is tests/engine/sim/job_runner_test.cpp.
#include "engine/sim/job.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <utility>

#include "engine/fem/step_status.h"

namespace zona {
namespace {

constexpr Vec3d kX{1, 0, 0};

TEST(NeedleSdf, HemisphereTipAndShaft) {
  const Vec3d tip{0, 0, 0};
  // Ahead of the apex on the axis: the distance is the gap, the normal points ahead.
  ToolSdf s = needle_sdf(tip, kX, 2.0, false, Vec3d{3, 0, 0});
  EXPECT_NEAR(s.distance, 3.0, 1e-12);
  EXPECT_NEAR(s.normal.x, 1.0, 1e-12);
  // Inside the hemisphere, 0.5 behind the apex on the axis.
  s = needle_sdf(tip, kX, 2.0, false, Vec3d{-0.5, 0, 0});
  EXPECT_NEAR(s.distance, -0.5, 1e-12);
  // Beside the shaft, far behind the tip: radial distance minus the radius.
  s = needle_sdf(tip, kX, 2.0, false, Vec3d{-10, 5, 0});
  EXPECT_NEAR(s.distance, 3.0, 1e-12);
  EXPECT_NEAR(s.normal.y, 1.0, 1e-12);
  // On the hemisphere's rim circle, 45 degrees: exactly on the surface.
  const double r = 2.0 / std::sqrt(2.0);
  s = needle_sdf(tip, kX, 2.0, false, Vec3d{-2.0 + r, r, 0});
  EXPECT_NEAR(s.distance, 0.0, 1e-12);
}

TEST(NeedleSdf, FlatTip) {
  const Vec3d tip{0, 0, 0};
  ToolSdf s = needle_sdf(tip, kX, 2.0, true, Vec3d{0.5, 1.0, 0});
  EXPECT_NEAR(s.distance, 0.5, 1e-12);  // in front of the disk
  s = needle_sdf(tip, kX, 2.0, true, Vec3d{-0.25, 0.5, 0});
  EXPECT_NEAR(s.distance, -0.25, 1e-12);  // just behind the end face
  s = needle_sdf(tip, kX, 2.0, true, Vec3d{3.0, 6.0, 0});
  EXPECT_NEAR(s.distance, 5.0, 1e-12);  // off the rim: (3, 4) to the rim circle
}

TEST(HoldingSdf, WallFacesAndOutside) {
  const Vec3d mouth{10, 0, 0};
  // In the bore on the axis: outside the wall, nearest the mouth's inner rim.
  ToolSdf s = holding_sdf(mouth, kX, 2.0, 5.0, Vec3d{12, 0, 0});
  EXPECT_NEAR(s.distance, 2.0, 1e-12);
  // Just into the wall through the mouth face.
  s = holding_sdf(mouth, kX, 2.0, 5.0, Vec3d{10.1, 3.5, 0});
  EXPECT_NEAR(s.distance, -0.1, 1e-12);
  EXPECT_NEAR(s.normal.x, -1.0, 1e-12);
  // In front of the mouth over the rim.
  s = holding_sdf(mouth, kX, 2.0, 5.0, Vec3d{9.0, 3.0, 0});
  EXPECT_NEAR(s.distance, 1.0, 1e-12);
}

ToolVertexInput vertex_at(Vec3d x, double area = 1.0) {
  ToolVertexInput in;
  in.x = x;
  in.area = area;
  return in;
}

TEST(PenaltyContact, PressureTimesAreaAlongTheNormal) {
  ToolSdf sdf;
  sdf.distance = -0.2;
  sdf.normal = kX;
  StickAnchor anchor;
  const Vec3d f = penalty_contact_force(sdf, 10.0, 0.3, 0.0, 0.5, Vec3d{0, 0, 0}, 0, &anchor);
  EXPECT_NEAR(f.x, 10.0 * 0.2 * 0.5, 1e-12);
  EXPECT_EQ(f.y, 0.0);
  EXPECT_EQ(f.z, 0.0);
}

TEST(PenaltyContact, FrictionSticksBelowTheConeAndSlidesOnIt) {
  // Normal force 10 x 1 x 1 = 10, Coulomb limit 3; the tangential spring is kappa area = 10.
  ToolSdf sdf;
  sdf.distance = -1.0;
  sdf.normal = kX;
  StickAnchor anchor;
  // First contact: it sticks where it touched, no tangential load.
  Vec3d f = penalty_contact_force(sdf, 10.0, 0.3, 0.0, 1.0, Vec3d{0, 0, 0}, 0, &anchor);
  EXPECT_NEAR(f.y, 0.0, 1e-12);
  // Displaced 0.2 along y relative to the tool: the spring pulls it back with 2 < 3, and keeps
  // doing so at rest (a step later, same place): a stuck point carries its load statically.
  f = penalty_contact_force(sdf, 10.0, 0.3, 0.0, 1.0, Vec3d{0, 0.2, 0}, 1, &anchor);
  EXPECT_NEAR(f.y, -2.0, 1e-12);
  f = penalty_contact_force(sdf, 10.0, 0.3, 0.0, 1.0, Vec3d{0, 0.2, 0}, 2, &anchor);
  EXPECT_NEAR(f.y, -2.0, 1e-12);
  // The normal part of the offset is not friction.
  f = penalty_contact_force(sdf, 10.0, 0.3, 0.0, 1.0, Vec3d{0.1, 0.2, 0}, 3, &anchor);
  EXPECT_NEAR(f.y, -2.0, 1e-12);
  EXPECT_NEAR(f.x, 10.0, 1e-12);
  // Pulled past the cone (0.5 along z): the Coulomb limit against the slip, and the anchor
  // slides so that it stays at the limit; moving back by 0.3 then unloads it to zero.
  f = penalty_contact_force(sdf, 10.0, 0.3, 0.0, 1.0, Vec3d{0, 0, 0.5}, 4, &anchor);
  EXPECT_NEAR(f.z, -3.0, 1e-12);
  EXPECT_NEAR(norm(Vec3d{0, f.y, f.z}), 3.0, 1e-12);
  f = penalty_contact_force(sdf, 10.0, 0.3, 0.0, 1.0, Vec3d{0, 0, 0.5}, 5, &anchor);
  EXPECT_NEAR(norm(Vec3d{0, f.y, f.z}), 3.0, 1e-12);
  f = penalty_contact_force(sdf, 10.0, 0.3, 0.0, 1.0, Vec3d{0, 0, 0.2}, 6, &anchor);
  EXPECT_NEAR(norm(Vec3d{0, f.y, f.z}), 0.0, 1e-12);
  // A point that left the tool (no contact at step 7) starts afresh where it touches again.
  f = penalty_contact_force(sdf, 10.0, 0.3, 0.0, 1.0, Vec3d{0, 5.0, 0}, 8, &anchor);
  EXPECT_NEAR(f.y, 0.0, 1e-12);
  EXPECT_NEAR(f.z, 0.0, 1e-12);
  // Without friction there is no tangential load at all.
  StickAnchor other;
  penalty_contact_force(sdf, 10.0, 0.0, 0.0, 1.0, Vec3d{0, 0, 0}, 0, &other);
  f = penalty_contact_force(sdf, 10.0, 0.0, 0.0, 1.0, Vec3d{0, 1.0, 0}, 1, &other);
  EXPECT_NEAR(f.y, 0.0, 1e-12);
}

TEST(PenaltyContact, DamperResistsApproachAndReboundButNeverPulls) {
  // Spring force 10 x 0.2 x 0.5 = 1 along +x (out of the tool); damper 2 kg/s.
  ToolSdf sdf;
  sdf.distance = -0.2;
  sdf.normal = kX;
  StickAnchor a0, a1, a2, a3;
  // Moving into the tool at 0.25 m/s: 1 + 2 x 0.25.
  Vec3d f = penalty_contact_force(sdf, 10.0, 0.0, 0.0, 0.5, Vec3d{0, 0, 0}, 0, &a0, 2.0,
                                  Vec3d{-0.25, 0, 0});
  EXPECT_NEAR(f.x, 1.5, 1e-12);
  // Leaving at 0.25 m/s: 1 - 0.5; leaving at 1 m/s: the pull is cut at zero.
  f = penalty_contact_force(sdf, 10.0, 0.0, 0.0, 0.5, Vec3d{0, 0, 0}, 0, &a1, 2.0, Vec3d{0.25, 0, 0});
  EXPECT_NEAR(f.x, 0.5, 1e-12);
  f = penalty_contact_force(sdf, 10.0, 0.0, 0.0, 0.5, Vec3d{0, 0, 0}, 0, &a2, 2.0, Vec3d{1.0, 0, 0});
  EXPECT_EQ(f.x, 0.0);
  // Sliding along the tool is not the normal damper's business; at rest it carries nothing.
  f = penalty_contact_force(sdf, 10.0, 0.0, 0.0, 0.5, Vec3d{0, 0, 0}, 0, &a3, 2.0, Vec3d{0, 3.0, 0});
  EXPECT_NEAR(f.x, 1.0, 1e-12);
  EXPECT_NEAR(f.y, 0.0, 1e-12);
}

TEST(PenaltyContact, RimDamperIsAFractionOfCriticalCappedAtMassOverStep) {
  JobParams p;
  p.rim.pressure_stiffness = 100.0;
  p.dt = 0.01;
  const double area = 0.5, k = 100.0 * 0.5;
  // A heavy vertex (omega dt = sqrt(k / m) dt = 0.05): the ratio times 2 sqrt(k m).
  const double heavy = 20.0;
  EXPECT_EQ(rim_damper_coefficient(p.rim, p.dt, area, heavy), 0.0);  // rim_damping 0: off
  p.rim.damping = 0.5;
  EXPECT_NEAR(rim_damper_coefficient(p.rim, p.dt, area, heavy), 0.5 * 2.0 * std::sqrt(k * heavy), 1e-9);
  // A vertex at the contact's mass raise (m = k dt^2, omega dt = 1): critical would be 2 m / dt,
  // at the explicit damper's stability limit; the cap holds it at m / dt.
  p.rim.damping = 1.0;
  const double raised = k * p.dt * p.dt;
  EXPECT_NEAR(rim_damper_coefficient(p.rim, p.dt, area, raised), raised / p.dt, 1e-12);
}

JobParams needle_params() {
  JobParams p;
  p.needle.on = 1;
  p.needle.direction = kX;
  p.needle.radius = 1.0;
  p.needle.pressure_stiffness = 100.0;
  p.needle.friction = 0.0;
  p.needle.speed = 1.0;
  p.dt = 0.01;
  p.health.energy_blowup_factor = 10;
  p.health.energy_floor = 1e-12;
  return p;
}

TEST(ToolVertexForce, NeedleLoadAndSuctionRamp) {
  JobParams p = needle_params();
  p.rim.on = 1;
  p.rim.mouth = Vec3d{100, 0, 0};
  p.rim.axis = kX;
  p.rim.inner_radius = 1;
  p.rim.outer_radius = 2;
  ToolPose pose;
  pose.tip = Vec3d{0.5, 0, 0};  // the vertex at the origin is 0.5 inside the hemisphere
  pose.suction_ramp = 0.25;
  ToolVertexInput in = vertex_at({0, 0, 0}, 2.0);
  in.suction = Vec3d{0, 0, 4.0};
  StickAnchor anchors[2];
  const ToolVertexForce f = tool_vertex_force(p.needle, p.rim, p.dt, pose, in, &anchors[0], &anchors[1]);
  EXPECT_EQ(f.needle_contact, 1);
  EXPECT_EQ(f.rim_contact, 0);
  EXPECT_NEAR(f.needle.x, 100.0 * 0.5 * 2.0, 1e-9);
  EXPECT_NEAR(f.rim.z, 1.0, 1e-12);
  EXPECT_NEAR(f.force.x, f.needle.x, 1e-12);
}

TEST(JobFinishStep, BlowUpHaltsAndRecordsNoPuncture) {
  JobParams p = needle_params();
  p.puncture.criterion = kJobCriterionEnergy;
  p.puncture.threshold = 1.0;  // met by the runaway energy below
  JobState s;
  JobSums sums;
  sums.tool_work = 0.01;
  JobStepTotals tot;
  tot.elastic_energy = 0.001;
  JobRecord r;
  job_finish_step(p, s, sums, tot, &r);
  EXPECT_EQ(r.halted, 0);
  // The energy jumps far above the work put in: the state is not a result.
  tot.elastic_energy = 5.0;
  sums.tool_work = 0.0;
  job_finish_step(p, s, sums, tot, &r);
  EXPECT_EQ(r.halted, 1);
  EXPECT_TRUE(r.status & 2u);  // kStepEnergyBlowUp
  EXPECT_EQ(r.puncture.punctured, 0);
}

TEST(JobFinishStep, NonFiniteHalts) {
  JobParams p = needle_params();
  JobState s;
  JobSums sums;
  JobStepTotals tot;
  tot.kinetic_energy = std::nan("");
  JobRecord r;
  job_finish_step(p, s, sums, tot, &r);
  EXPECT_EQ(r.halted, 1);
  EXPECT_TRUE(r.status & 1u);  // kStepNonFinite
}

TEST(JobFinishStep, NeedleThroughTheSurfaceHaltsBeforePunctureOnly) {
  JobParams p = needle_params();
  p.needle.breach_depth = 0.5;
  p.puncture.criterion = kJobCriterionForce;
  p.puncture.threshold = 1e9;  // not met
  JobState s;
  JobSums sums;
  JobStepTotals tot;
  JobRecord r;
  // Penetration within the penalty's range: a healthy step.
  sums.needle_depth = 0.4;
  job_finish_step(p, s, sums, tot, &r);
  EXPECT_EQ(r.halted, 0);
  EXPECT_EQ(r.needle_depth, 0.4);
  // A surface point past half the radius inside the tip: the surface let the needle through.
  sums.needle_depth = 0.6;
  job_finish_step(p, s, sums, tot, &r);
  EXPECT_EQ(r.halted, 1);
  EXPECT_TRUE(r.status & kStepToolBreach);
  EXPECT_EQ(r.puncture.punctured, 0);
  // After a puncture the needle is meant to be inside: no breach.
  JobState punctured;
  punctured.puncture.punctured = 1;
  job_finish_step(p, punctured, sums, tot, &r);
  EXPECT_EQ(r.halted, 0);
}

TEST(JobFinishStep, ForcePunctureFreezesTheTipAndReleasesTheLoad) {
  JobParams p = needle_params();
  p.puncture.criterion = kJobCriterionForce;
  p.puncture.threshold = 2.0;
  p.puncture.force_drop = 0.9;
  p.puncture.drop_time = 0.1;
  JobState s;
  job_set_pose(p, s);
  JobSums sums;
  JobStepTotals tot;
  JobRecord r;
  sums.needle_force[0] = 1.0;
  sums.needle_contacts = 3;
  job_finish_step(p, s, sums, tot, &r);
  EXPECT_EQ(r.puncture.punctured, 0);
  const Vec3d tip_at_puncture = s.pose.tip;
  sums.needle_force[0] = 2.5;
  job_finish_step(p, s, sums, tot, &r);
  ASSERT_EQ(r.puncture.punctured, 1);
  EXPECT_NEAR(r.puncture.force, 2.5, 1e-12);
  EXPECT_EQ(s.released_contacts, 3);
  // The tip load stays where it was; the tip itself moves on.
  EXPECT_EQ(s.pose.tip.x, tip_at_puncture.x);
  EXPECT_GT(r.tip.x, tip_at_puncture.x);
  EXPECT_NEAR(s.pose.needle_scale, 1.0, 1e-12);
  // The contact's scale follows the release of the load: where the load answers the scale (a
  // surface that stays put), it reaches 1 - force_drop of the force at puncture once drop_time
  // has passed, and stays there.
  for (int i = 0; i < 40; ++i) {
    sums.needle_force[0] = 2.5 * s.pose.needle_scale;
    job_finish_step(p, s, sums, tot, &r);
    EXPECT_LE(s.pose.needle_scale, 1.0);
  }
  EXPECT_NEAR(2.5 * s.pose.needle_scale, 0.1 * 2.5, 1e-9);
  // A load that does not answer (the surface pushed deeper into the softer contact) drives the
  // scale down further, at most 20 % a step.
  const double before = s.pose.needle_scale;
  sums.needle_force[0] = 2.5;
  job_finish_step(p, s, sums, tot, &r);
  EXPECT_NEAR(s.pose.needle_scale, 0.8 * before, 1e-12);
}

// The needle's normal load on a flat plate z in [-10, 10]^2 at z = 0, triangulated n x n, with
// the hemispherical tip (radius 1 in needle_params, pointing -z) pressed `depth` into it: by the
// face quadrature, or lumped at the vertices (each with a third of its triangles' areas).
double plate_load(int n, double depth, bool faces) {
  JobParams p = needle_params();
  p.needle.direction = Vec3d{0, 0, -1};
  p.needle.on_faces = faces ? 1 : 0;
  ToolPose pose;
  // The tip a little off the grid's symmetry, as a real tip is.
  pose.tip = Vec3d{0.013, -0.021, -depth};
  const double h = 4.0 / n;  // the plate spans [-2, 2]^2: twice the contact radius and more
  auto at = [&](int i, int j) { return Vec3d{-2.0 + h * i, -2.0 + h * j, 0.0}; };
  double total = 0;
  if (faces) {
    for (int i = 0; i < n; ++i)
      for (int j = 0; j < n; ++j)
        for (int t = 0; t < 2; ++t) {
          ToolFaceInput in;
          in.x[0] = at(i, j);
          in.x[1] = t ? at(i + 1, j + 1) : at(i + 1, j);
          in.x[2] = t ? at(i, j + 1) : at(i + 1, j + 1);
          in.area = 0.5 * h * h;
          StickAnchor anchors[kFacePoints];
          const ToolFaceForce f = needle_face_force(p.needle, pose, in, anchors);
          for (int c = 0; c < 3; ++c) total += f.corner[c].z;
        }
  } else {
    for (int i = 0; i <= n; ++i)
      for (int j = 0; j <= n; ++j) {
        ToolVertexInput in;
        in.x = at(i, j);
        // Interior vertices carry h^2, edges and corners less (six triangles of h^2 / 2, a third each).
        const int edges = (i == 0 || i == n) + (j == 0 || j == n);
        in.area = h * h * (edges == 0 ? 1.0 : (edges == 1 ? 0.5 : 0.25));
        StickAnchor anchors[2];
        total += tool_vertex_force(p.needle, p.rim, p.dt, pose, in, &anchors[0], &anchors[1]).force.z;
      }
  }
  return -total;  // the tip pushes the plate down (-z): report the magnitude
}

TEST(NeedleFaceForce, PlateLoadIsTheExactIntegralAtEveryResolution) {
  // Penalty pressure kappa * penetration (s the distance from the sphere's centre, c = R - d
  // the centre's height, rho dA = 2 pi s ds). On the faces it acts along the plate's normal:
  // kappa 2 pi int_c^R (R - s) s ds = kappa pi d^2 (R - 2 d / 3). At the vertices it acts along
  // the sphere's radial normal, whose axial part c / s leaves 2 pi c int_c^R (R - s) ds =
  // kappa pi c d^2. The face quadrature gets its integral within 2 % from a grid whose cells are
  // as wide as the tip's radius down to one ten times finer; the vertex lumping misses its own
  // by far more on the coarse grid, and cannot see a tip between vertices.
  const double depth = 0.3, radius = 1.0, kappa = needle_params().needle.pressure_stiffness;
  const double exact_faces = kappa * M_PI * depth * depth * (radius - 2.0 * depth / 3.0);
  const double exact = kappa * M_PI * (radius - depth) * depth * depth;
  for (int n : {4, 10, 40}) {
    const double faces = plate_load(n, depth, true);
    EXPECT_NEAR(faces, exact_faces, 0.02 * exact_faces) << n << " x " << n << " grid";
  }
  const double coarse_vertices = plate_load(4, depth, false);
  EXPECT_GT(std::abs(coarse_vertices - exact), 0.1 * exact) << coarse_vertices << " vs " << exact;
  EXPECT_NEAR(plate_load(40, depth, false), exact, 0.05 * exact);
}

TEST(NeedleFaceForce, TipBetweenVerticesStillPushesAndLoadsSumToTheTotal) {
  // One triangle much larger than the tip, pressed in its middle: no corner is inside the
  // needle, the quadrature points are. The corner loads push the triangle along -z and, for a
  // tip at the centroid, about equally.
  JobParams p = needle_params();
  p.needle.direction = Vec3d{0, 0, -1};
  p.needle.on_faces = 1;
  ToolFaceInput in;
  in.x[0] = Vec3d{-3, -2, 0};
  in.x[1] = Vec3d{3, -2, 0};
  in.x[2] = Vec3d{0, 4, 0};
  in.area = 18;
  ToolPose pose;
  pose.tip = Vec3d{0, 0, -0.2};
  StickAnchor anchors[kFacePoints];
  const ToolFaceForce f = needle_face_force(p.needle, pose, in, anchors);
  EXPECT_GT(f.contacts, 0);
  for (int c = 0; c < 3; ++c) {
    EXPECT_LT(f.corner[c].z, 0);
    EXPECT_NEAR(f.corner[c].z, f.corner[0].z, 0.35 * std::abs(f.corner[0].z));
    ToolVertexInput corner;
    corner.x = in.x[c];
    corner.area = 6;
    p.needle.on_faces = 0;
    StickAnchor corner_anchors[2];
    EXPECT_EQ(tool_vertex_force(p.needle, p.rim, p.dt, pose, corner, &corner_anchors[0], &corner_anchors[1])
                  .needle_contact,
              0);
    p.needle.on_faces = 1;
  }
  // The deepest point is the one under the tip: 0.2 inside (the triangle lies at z = 0, the
  // apex at z = -0.2), within the quadrature's spacing.
  EXPECT_GT(f.depth, 0.15);
  EXPECT_LE(f.depth, 0.2 + 1e-12);
  // Far from the tip: nothing, and no point is evaluated beyond the centroid test.
  pose.tip = Vec3d{0, 0, 20};
  EXPECT_EQ(needle_face_force(p.needle, pose, in, anchors).contacts, 0);
  EXPECT_EQ(needle_face_force(p.needle, pose, in, anchors).depth, 0);
}

TEST(NeedleFaceForce, PressureActsAlongTheTriangleNormal) {
  // A flat triangle across one side of the hemispherical tip: the tool's normals there lean
  // outward by up to ~50 degrees, but the load is a pressure on the triangle, along its inward
  // normal: no corner gets an in-plane pull (which would stretch the triangle around the tip),
  // and the total is the pressure integral along -z. A triangle facing the other way (its
  // outward normal away from the tool) keeps the tool's normal.
  JobParams p = needle_params();
  p.needle.direction = Vec3d{0, 0, -1};
  p.needle.on_faces = 1;
  ToolFaceInput in;
  in.x[0] = Vec3d{0, -0.8, 0};
  in.x[1] = Vec3d{0.9, -0.8, 0};  // counter-clockwise seen from +z: outward normal +z
  in.x[2] = Vec3d{0, 0.8, 0};
  in.area = 0.72;
  ToolPose pose;
  pose.tip = Vec3d{0, 0, -0.3};
  StickAnchor anchors[kFacePoints];
  const ToolFaceForce f = needle_face_force(p.needle, pose, in, anchors);
  ASSERT_GT(f.contacts, 4);
  double fz = 0;
  for (int c = 0; c < 3; ++c) {
    EXPECT_EQ(f.corner[c].x, 0.0) << "corner " << c;
    EXPECT_EQ(f.corner[c].y, 0.0) << "corner " << c;
    fz += f.corner[c].z;
  }
  EXPECT_LT(fz, 0);
  std::swap(in.x[1], in.x[2]);  // now facing -z, towards the cell's inside
  StickAnchor fresh[kFacePoints];
  const ToolFaceForce g = needle_face_force(p.needle, pose, in, fresh);
  double gx = 0;
  for (int c = 0; c < 3; ++c) gx += g.corner[c].x;
  EXPECT_GT(gx, 0);  // the tool's normals lean towards +x over this triangle
}

// The membrane strain the strain criterion reads: a triangle stretched by 10 % along one edge has
// Green strain (1.1^2 - 1) / 2 whatever its orientation and wherever it is moved; a rigid motion
// has none; a compressed triangle reports 0 (the criterion is on stretch).
TEST(NeedleFaceStrain, IsTheLargestInPlaneGreenStrain) {
  const Vec3d rest[3] = {{0, 0, 0}, {2e-6, 0, 0}, {0.5e-6, 1.5e-6, 0}};
  // A rotation about an oblique axis and a shift: the same triangle, no strain.
  const Vec3d axis = (1.0 / std::sqrt(14.0)) * Vec3d{1, 2, 3};
  const double angle = 0.7, c = std::cos(angle), s = std::sin(angle);
  auto rotate = [&](Vec3d v) {
    return c * v + s * cross(axis, v) + (1 - c) * dot(axis, v) * axis + Vec3d{1e-6, -2e-6, 3e-6};
  };
  Vec3d moved[3], stretched[3], squeezed[3], biaxial[3];
  for (int k = 0; k < 3; ++k) {
    moved[k] = rotate(rest[k]);
    stretched[k] = rotate(Vec3d{1.1 * rest[k].x, rest[k].y, rest[k].z});
    squeezed[k] = Vec3d{0.9 * rest[k].x, 0.95 * rest[k].y, rest[k].z};
    biaxial[k] = Vec3d{1.05 * rest[k].x, 1.2 * rest[k].y, 0.3 * rest[k].x};
  }
  EXPECT_NEAR(needle_face_strain(rest, moved), 0.0, 1e-12);
  EXPECT_NEAR(needle_face_strain(rest, stretched), 0.5 * (1.1 * 1.1 - 1), 1e-12);
  EXPECT_EQ(needle_face_strain(rest, squeezed), 0.0);
  // x -> (1.05 x, 1.2 y, 0.3 x): F^T F = [[1.05^2 + 0.09, 0], [0, 1.44]]; largest 0.22.
  EXPECT_NEAR(needle_face_strain(rest, biaxial), 0.5 * (1.44 - 1), 1e-12);
}

}  // namespace
}  // namespace zona
