"""The scene's lines in the world's posterior (issue 51, item 1): the up the room's vertical
vanishing point shows (:class:`~mocapdb.runtime.world.scene_lines.SceneTilt`) as one more term of
the cost over the camera's pitch and roll (:mod:`~mocapdb.runtime.world.fuse`), weighted by its
error as the people's evidence is by theirs; where the grid is centred; and what decided the tilt
(``world.json``'s ``tilt_from``, the summary). ``data_specs/world.md``, "The scene's lines"."""
from __future__ import annotations

import numpy as np

from mocapdb.runtime.world.scene_lines import SceneTilt, pitch_roll_deg
from mocapdb.runtime.world.tilt import tilt_cost, tilted_normals

SCENE_DECIDES = 0.8   # the scene's share of the tilt's precision over which it decided (under 1 − this: the people)


def tilt_source(share: float | None) -> str:
    """What decided the tilt, from the scene's share of its precision (None: no scene): "people",
    "scene" or "people and scene"."""
    if share is None or share < 1.0 - SCENE_DECIDES:
        return "people"
    return "scene" if share > SCENE_DECIDES else "people and scene"


def grid_centre(people_up: np.ndarray, people_sds_deg: tuple[float, float], scene: SceneTilt) -> np.ndarray:
    """The people's and the scene's ups (view frame, unit) blended by their precisions (the mean of
    the pitch's and the roll's, degrees): the tilt grid's centre, so that a scene far from the
    people (a lone person in a stance leans the world 22°) lies inside the grid."""
    people = 1.0 / np.mean(np.square(people_sds_deg))
    seen = 1.0 / np.mean(np.square([scene.pitch_sd_deg, scene.roll_sd_deg]))
    blend = people * people_up + seen * scene.up
    return blend / np.linalg.norm(blend)


def scene_cost_of(scene: SceneTilt, normal: np.ndarray, tilts_deg: np.ndarray) -> np.ndarray:
    """``−log`` likelihood ``[T, 1]`` of the tilts ``[T, 2]`` (pitch, roll; degrees) about ``normal``
    given the scene's up: the tilt prior's mixture (:func:`~mocapdb.runtime.world.tilt.tilt_cost`:
    a wrong vertical, a cluster of leaning lines, falls in its tail) about the scene's pitch and
    roll with its errors."""
    pitch, roll = pitch_roll_deg(tilted_normals(normal, tilts_deg))
    off = np.column_stack([pitch - scene.pitch_deg, roll - scene.roll_deg])
    return tilt_cost(off, (scene.pitch_sd_deg, scene.roll_sd_deg))[:, None]


def scene_share(scene: SceneTilt, people_sds_deg: tuple[float, float]) -> float:
    """The scene's share of the tilt's precision (the mean over pitch and roll): its inverse variance
    over its own and the people's (``people_sds_deg``: their posterior spread without the scene)."""
    seen = 1.0 / np.square([scene.pitch_sd_deg, scene.roll_sd_deg])
    return float(np.mean(seen / (seen + 1.0 / np.square(people_sds_deg))))
