"""scene.json (mocapdb/core/formats/scene.py): written and read back, and broken files named."""
import json

import numpy as np
import pytest

from mocapdb.core.formats.scene import SCENE_FILE, SceneError, SceneLines, read_scene, write_scene


def test_scene_round_trip(tmp_path):
    segments = (np.array([[1.0, 2.0, 300.0, 4.0], [5.0, 6.0, 7.0, 400.0]]), np.zeros((0, 4)))
    write_scene(tmp_path, SceneLines((640, 480), (0, 30), segments, "lsd"))
    back = read_scene(tmp_path)
    assert back.image_size == (640, 480) and back.frames == (0, 30) and back.detector == "lsd"
    assert np.allclose(back.segments[0], segments[0]) and back.segments[1].shape == (0, 4)
    assert back.all_segments().shape == (2, 4)


def test_no_scene_is_none(tmp_path):
    assert read_scene(tmp_path) is None


@pytest.mark.parametrize("body, says", [
    ("not json", "not a scene file"),
    (json.dumps({"format": "other"}), "format 'mocapdb-scene' expected"),
    (json.dumps({"format": "mocapdb-scene", "version": 9}), "version 9"),
    (json.dumps({"format": "mocapdb-scene", "version": 1, "image_size": [640, 480],
                 "frames": [{"frame": 0, "segments": [[1, 2, 3]]}]}), "segments"),
    (json.dumps({"format": "mocapdb-scene", "version": 1, "image_size": [640, 480],
                 "frames": [{"frame": 0, "segments": [[1, 2, 3, "x"]]}]}), "scene.json"),
])
def test_broken_scene_is_named(tmp_path, body, says):
    (tmp_path / SCENE_FILE).write_text(body)
    with pytest.raises(SceneError, match=says):
        read_scene(tmp_path)
