// Tests for engine/scene_write: scene_to_json writes SI values that read back to the same scene
// (the tools' stick lengths with their range check among them).
#include <gtest/gtest.h>

#include <filesystem>
#include <nlohmann/json.hpp>

#include "engine/scene/scene.h"

namespace zona {
namespace {

using json = nlohmann::json;
namespace fs = std::filesystem;

const std::string kScenes = std::string(ZONA_SOURCE_DIR) + "/scenes/";

TEST(SceneWrite, EveryShippedSceneRoundTrips) {
  for (const fs::directory_entry& e : fs::directory_iterator(kScenes)) {
    if (e.path().extension() != ".json") continue;
    SCOPED_TRACE(e.path().string());
    Result<Scene> s = load_scene(e.path().string());
    ASSERT_TRUE(s.ok()) << s.error().message;
    const json first = scene_to_json(*s);
    Result<Scene> again = parse_scene(first, "");
    ASSERT_TRUE(again.ok()) << again.error().message << "\n" << first.dump(2);
    EXPECT_EQ(scene_to_json(*again), first);
  }
}

TEST(SceneWrite, WritesSiValuesAndResolvedChoices) {
  Result<Scene> s = load_scene(kScenes + "zebrafish_embryo.json", {"needle.speed=0.6 mm/s"});
  ASSERT_TRUE(s.ok()) << s.error().message;
  const json j = scene_to_json(*s);
  EXPECT_EQ(j["mesh"]["generate"]["diameter"], "8e-04 m");  // shortest exact text
  EXPECT_EQ(j["needle"]["speed"], "6e-04 m/s");
  EXPECT_EQ(j["needle"]["start"], "auto");
  EXPECT_EQ(j["mesh"]["generate"]["refine_at"], "needle");
  EXPECT_EQ(j["holding_pipette"]["suction"], "2500 Pa");
  // The speed table is written, not the modulus it gave at this speed.
  EXPECT_FALSE(j["materials"]["default"].contains("young"));
  EXPECT_EQ(j["materials"]["default"]["young_by_speed"][0]["young"], "72400 Pa");
  EXPECT_EQ(j["integrator"]["dt"], "auto");
  // The constitutive model by its scene-file name.
  Result<Scene> snh = load_scene(kScenes + "mouse_oocyte.json", {"model=neohookean"});
  ASSERT_TRUE(snh.ok()) << snh.error().message;
  EXPECT_EQ(scene_to_json(*snh)["model"], "neohookean");
  Result<Scene> back = parse_scene(scene_to_json(*snh), "");
  ASSERT_TRUE(back.ok()) << back.error().message;
  EXPECT_EQ(back->model, ModelKind::kStableNeoHookean);
  // Where the volumetric term is taken (the shipped mouse scene: at the vertices) reads back.
  EXPECT_EQ(scene_to_json(*snh)["volumetric"], "nodal");
  EXPECT_TRUE(back->nodal_pressure);
  Result<Scene> element = load_scene(kScenes + "mouse_oocyte.json", {"volumetric=element"});
  ASSERT_TRUE(element.ok()) << element.error().message;
  EXPECT_EQ(scene_to_json(*element)["volumetric"], "element");
}

// The friction's stick lengths (needle and holding pipette) read with their unit, write in SI and
// read back; a negative one is refused with its key named. Unset, both are 0 (the old law).
TEST(SceneWrite, StickLengthsReadWriteAndReadBack) {
  Result<Scene> plain = load_scene(kScenes + "mouse_oocyte.json");
  ASSERT_TRUE(plain.ok()) << plain.error().message;
  EXPECT_EQ(plain->holding_pipette.stick_length, 0.0);
  EXPECT_EQ(plain->needle.stick_length, 0.0);
  Result<Scene> s = load_scene(kScenes + "mouse_oocyte.json",
                               {"holding_pipette.stick_length=0.1 um", "needle.stick_length=50 nm"});
  ASSERT_TRUE(s.ok()) << s.error().message;
  EXPECT_DOUBLE_EQ(s->holding_pipette.stick_length, 1e-7);
  EXPECT_DOUBLE_EQ(s->needle.stick_length, 5e-8);
  const json j = scene_to_json(*s);
  EXPECT_EQ(j["holding_pipette"]["stick_length"], "1e-07 m");
  EXPECT_EQ(j["needle"]["stick_length"], "5e-08 m");
  Result<Scene> back = parse_scene(j, "");
  ASSERT_TRUE(back.ok()) << back.error().message;
  EXPECT_EQ(back->holding_pipette.stick_length, s->holding_pipette.stick_length);
  EXPECT_EQ(back->needle.stick_length, s->needle.stick_length);
  for (const char* key : {"holding_pipette.stick_length", "needle.stick_length"}) {
    Result<Scene> bad = load_scene(kScenes + "mouse_oocyte.json", {std::string(key) + "=-1 um"});
    ASSERT_FALSE(bad.ok()) << key;
    EXPECT_NE(bad.error().message.find(key), std::string::npos) << bad.error().message;
  }
}

TEST(SceneWrite, DisabledToolsAndDefaultsReadBack) {
  Scene scene;  // a default scene plus one material is valid once something ends the run
  MaterialDef material;
  material.young = 17.9e3;
  material.poisson = 0.49;
  scene.materials.push_back({"default", material});
  scene.integrator.duration = 1e-3;
  scene.integrator.dt = 1e-8;
  scene.holding_pipette.inner_radius = 5e-6;  // ignored while disabled
  const json j = scene_to_json(scene);
  EXPECT_EQ(j["needle"], json({{"enabled", false}}));
  EXPECT_EQ(j["holding_pipette"], json({{"enabled", false}}));
  EXPECT_EQ(j["integrator"]["dt"], "1e-08 s");
  Result<Scene> back = parse_scene(j, "");
  ASSERT_TRUE(back.ok()) << back.error().message;
  EXPECT_FALSE(back->needle.enabled);
  EXPECT_EQ(*back->integrator.dt, 1e-8);
  EXPECT_EQ(back->mesh.generate.edge_length, scene.mesh.generate.edge_length);
  EXPECT_EQ(scene_to_json(*back), j);
}

// A duration far past the needle's scripted end ends with the needle; one that is not, or a needle
// without an end, is left alone.
TEST(SceneWrite, EndRunWithNeedleOnlyCutsADurationFarPastTheNeedle) {
  Scene scene;
  scene.needle.enabled = true;
  scene.needle.speed = 1e-3;
  scene.needle.max_travel = 20e-6;  // ends at 0.02 s
  scene.integrator.duration = 3600;
  EXPECT_DOUBLE_EQ(end_run_with_needle(scene), 0.02);
  EXPECT_EQ(scene.integrator.duration, 0);
  scene.integrator.duration = 0.5;  // over twice the end but not a second past it
  EXPECT_EQ(end_run_with_needle(scene), 0);
  EXPECT_EQ(scene.integrator.duration, 0.5);
  scene.integrator.duration = 3600;
  scene.needle.max_travel = 0;  // no scripted end
  EXPECT_EQ(end_run_with_needle(scene), 0);
  EXPECT_EQ(scene.integrator.duration, 3600);
}

}  // namespace
}  // namespace zona
