"""zona.load_scene and zona.find_scene: the scene as a dict, overrides, lookup, errors."""

import json
import os

import pytest

import zona


def test_load_scene_gives_the_resolved_scene_in_si():
    scene = zona.load_scene("mouse_oocyte")
    assert scene["name"] == "mouse_oocyte"
    assert scene["model"] == "neohookean"
    assert scene["materials"]["default"]["young"] == "16500 Pa"
    # The same text `zona run` writes as scene.json, and it loads back to itself.
    again = json.loads(json.dumps(scene))
    assert zona.load_scene("mouse_oocyte") == again


def test_sets_as_list_or_dict_override_keys():
    a = zona.load_scene("mouse_oocyte", sets=["mesh.generate.vertices=1500", "needle.speed=0.2 mm/s"])
    b = zona.load_scene("mouse_oocyte", sets={"mesh.generate.vertices": 1500,
                                              "needle.speed": "0.2 mm/s"})
    assert a == b
    assert a["mesh"]["generate"]["vertices"] == 1500
    assert a["needle"]["speed"] == "2e-04 m/s"


def test_find_scene_resolves_names_and_paths(tmp_path):
    path = zona.find_scene("mouse_oocyte")
    assert os.path.isabs(path) and path.endswith("scenes/mouse_oocyte.json")
    assert zona.find_scene(path) == path
    copy = tmp_path / "mine.json"
    copy.write_text(open(path).read())
    assert zona.load_scene(copy)["name"] == "mouse_oocyte"


def test_bad_scenes_raise_one_line_errors(tmp_path):
    with pytest.raises(zona.ZonaError, match="scene 'nope' not found"):
        zona.load_scene("nope")
    with pytest.raises(zona.ZonaError, match=r"materials\.default\.young"):
        zona.load_scene("mouse_oocyte", sets=["materials.default.young=17"])
    broken = tmp_path / "broken.json"
    broken.write_text("{ \"name\": ")
    with pytest.raises(zona.ZonaError, match="broken.json") as caught:
        zona.load_scene(broken)
    assert "\n" not in str(caught.value)
    assert isinstance(caught.value, ValueError)
