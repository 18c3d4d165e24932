// Tests for engine/needle: tip and shaft distance, scripted motion, trajectory files.
#include "engine/tools/needle.h"

#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <fstream>

namespace zona {
namespace {

void expect_vec(Vec3d a, Vec3d b, double tol) {
  EXPECT_NEAR(a.x, b.x, tol);
  EXPECT_NEAR(a.y, b.y, tol);
  EXPECT_NEAR(a.z, b.z, tol);
}

TEST(Needle, SphereTipDistanceAheadBesideAndInside) {
  const NeedleGeometry n{NeedleShape::kSphere, 2.0, Vec3d{1, 0, 0}};
  const Vec3d tip{0, 0, 0};  // hemisphere centre at (-2, 0, 0)
  // Straight ahead of the apex.
  ToolDistance d = needle_distance(n, tip, Vec3d{3, 0, 0});
  EXPECT_DOUBLE_EQ(d.distance, 3.0);
  expect_vec(d.normal, Vec3d{1, 0, 0}, 1e-15);
  // Inside the hemisphere, 1 below the apex on the axis.
  d = needle_distance(n, tip, Vec3d{-1, 0, 0});
  EXPECT_DOUBLE_EQ(d.distance, -1.0);
  expect_vec(project_to_surface(Vec3d{-1, 0, 0}, d), tip, 1e-15);
  // Beside the shaft, behind the hemisphere: radial distance to the cylinder.
  d = needle_distance(n, tip, Vec3d{-10, 0, 5});
  EXPECT_DOUBLE_EQ(d.distance, 3.0);
  expect_vec(d.normal, Vec3d{0, 0, 1}, 1e-15);
  // Inside the shaft.
  d = needle_distance(n, tip, Vec3d{-10, 1.5, 0});
  EXPECT_DOUBLE_EQ(d.distance, -0.5);
  expect_vec(d.normal, Vec3d{0, 1, 0}, 1e-15);
  // The point shape uses the same hemisphere (the footprint of Ladjal et al.'s point needle).
  const NeedleGeometry p{NeedleShape::kPoint, 2.0, Vec3d{1, 0, 0}};
  EXPECT_DOUBLE_EQ(needle_distance(p, tip, Vec3d{-1, 0, 0}).distance, -1.0);
}

TEST(Needle, FlatTipDistanceFaceRimAndShaft) {
  const NeedleGeometry n{NeedleShape::kFlat, 2.0, Vec3d{0, 0, -1}};
  const Vec3d tip{0, 0, 10};
  // Below the face (ahead), within the radius.
  ToolDistance d = needle_distance(n, tip, Vec3d{1, 0, 7});
  EXPECT_DOUBLE_EQ(d.distance, 3.0);
  expect_vec(d.normal, Vec3d{0, 0, -1}, 1e-15);
  // Ahead and outside the radius: distance to the rim circle.
  d = needle_distance(n, tip, Vec3d{5, 0, 6});
  EXPECT_NEAR(d.distance, 5.0, 1e-12);  // rim point (2, 0, 10): offset (3, 0, -4)
  expect_vec(d.normal, Vec3d{0.6, 0, -0.8}, 1e-12);
  // Just inside the face: leaves through the face.
  d = needle_distance(n, tip, Vec3d{0.5, 0, 10.2});
  EXPECT_NEAR(d.distance, -0.2, 1e-12);
  expect_vec(d.normal, Vec3d{0, 0, -1}, 1e-15);
  // Deep inside near the wall: leaves radially.
  d = needle_distance(n, tip, Vec3d{1.9, 0, 15});
  EXPECT_NEAR(d.distance, -0.1, 1e-12);
  expect_vec(d.normal, Vec3d{1, 0, 0}, 1e-15);
}

TEST(Needle, StraightScriptStopsAtMaxTravel) {
  NeedleScript s;
  s.start = Vec3d{-30e-6, 0, 0};
  s.direction = Vec3d{1, 0, 0};
  s.speed = 1e-4;
  s.max_travel = 20e-6;
  expect_vec(needle_tip_at(s, 0.0), s.start, 0);
  expect_vec(needle_tip_at(s, 0.1), Vec3d{-20e-6, 0, 0}, 1e-18);
  expect_vec(needle_tip_at(s, 1.0), Vec3d{-10e-6, 0, 0}, 1e-18);  // stopped
  EXPECT_DOUBLE_EQ(needle_script_end_time(s), 0.2);
}

TEST(Needle, TrajectoryFileIsInterpolatedAndHeld) {
  const std::filesystem::path path = std::filesystem::temp_directory_path() / "zona_needle_traj.csv";
  {
    std::ofstream f(path);
    f << "time_s,x_m,y_m,z_m\n0,0,0,0\n0.5,1e-6,0,0\n1.0,1e-6,2e-6,0\n";
  }
  Result<NeedleTrajectory> t = read_needle_trajectory(path.string());
  ASSERT_TRUE(t.ok()) << t.error().message;
  NeedleScript s;
  s.trajectory = *t;
  expect_vec(needle_tip_at(s, 0.25), Vec3d{0.5e-6, 0, 0}, 1e-18);
  expect_vec(needle_tip_at(s, 0.75), Vec3d{1e-6, 1e-6, 0}, 1e-18);
  expect_vec(needle_tip_at(s, 5.0), Vec3d{1e-6, 2e-6, 0}, 0);
  EXPECT_DOUBLE_EQ(needle_script_end_time(s), 1.0);
  std::filesystem::remove(path);
}

TEST(Needle, BadTrajectoriesNameFileAndLine) {
  const std::filesystem::path path = std::filesystem::temp_directory_path() / "zona_needle_bad.csv";
  auto error_of = [&](const std::string& text) {
    {
      std::ofstream f(path);
      f << text;
    }
    Result<NeedleTrajectory> t = read_needle_trajectory(path.string());
    EXPECT_FALSE(t.ok());
    return t.ok() ? std::string() : t.error().message;
  };
  EXPECT_NE(error_of("t,x,y,z\n0,0,0,0\n").find(":1: expected the header"), std::string::npos);
  EXPECT_NE(error_of("time_s,x_m,y_m,z_m\n0,0,0,0\n1,0,zero,0\n").find(":3: column 3"),
            std::string::npos);
  EXPECT_NE(error_of("time_s,x_m,y_m,z_m\n0,0,0,0\n0,1,0,0\n").find(":3: times must increase"),
            std::string::npos);
  EXPECT_NE(error_of("time_s,x_m,y_m,z_m\n0.1,0,0,0\n1,1,0,0\n").find("first time must be 0"),
            std::string::npos);
  EXPECT_NE(error_of("time_s,x_m,y_m,z_m\n0,0,0,0\n").find("at least 2 rows"), std::string::npos);
  EXPECT_NE(error_of("time_s,x_m,y_m,z_m\n0,0,0\n").find("expected 4 columns"), std::string::npos);
  Result<NeedleTrajectory> missing = read_needle_trajectory("/nonexistent/zona.csv");
  ASSERT_FALSE(missing.ok());
  EXPECT_NE(missing.error().message.find("cannot open"), std::string::npos);
  std::filesystem::remove(path);
}

}  // namespace
}  // namespace zona
