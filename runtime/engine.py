"""The per-frame engine: people's 2D keypoints → tracked, retrieved, smoothed 3D skeletons.

One code path serves `mocapdb reconstruct` (files) and `mocapdb live` (streams). Frames
(``data_specs/stream_output.md``):

* **view frame** (right-handed, metres): x to the image's right, y up, z towards the camera.
  The matched database skeleton turned by its yaw lives here (the database camera looks along
  −z); BVH output and the stored quaternions use it.
* **camera-aligned frame** (the JSON ``joints``/``root``): x right, y up, z away from the camera
  (the view frame with z negated); the origin is the camera centre when the root translation is
  estimated, otherwise the pelvis.

:class:`Engine` composes the frame's usable people (:mod:`mocapdb.runtime.frame_people`), the
tracks (:mod:`mocapdb.runtime.track_book`: tracker, limits, lifecycle, recordings) and one person's
pose (:mod:`mocapdb.runtime.pose_pipeline`: retrieve, choose, refine, smooth). Its parameters:
:mod:`mocapdb.runtime.engine_config`; each track's memory (skeletons, body, filters, recording,
stillness): :mod:`mocapdb.runtime.track_state`.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mocapdb.core.formats.database import MotionDatabase
from mocapdb.core.formats.keypoints import KeypointFrame
from mocapdb.core.outputs import PersonPose, TrackRecording
from mocapdb.core.skeleton import N_KEYPOINTS_2D
from mocapdb.runtime.engine_config import EngineConfig
from mocapdb.runtime.frame_people import usable_people
from mocapdb.runtime.pose_pipeline import PosePipeline
from mocapdb.runtime.track_book import TrackBook, TrackCounts


@dataclass
class EngineStats(TrackCounts):
    frames: int = 0
    person_frames: int = 0
    skipped_people: int = 0  # detections with too few confident joints or no hip
    degenerate_people: int = 0  # detections whose confident keypoints span less than MIN_EXTENT_PX


class Engine:
    """Retrieval engine over one database; call :meth:`step` per frame, :meth:`finish` at the end."""

    def __init__(self, db: MotionDatabase, config: EngineConfig | None = None):
        self.config = config or EngineConfig()
        self.stats = EngineStats()
        self.pipeline = PosePipeline(db, self.config)
        self.book = TrackBook(self.config, self.stats)
        self._warm_up()

    def _warm_up(self) -> None:
        """Run every compiled kernel once on a database pose, so the first real frame is not slow."""
        points = self.pipeline.index.pose(0).astype(np.float64) * 400.0 + 500.0
        conf = np.ones(N_KEYPOINTS_2D)
        self.book.warm_up(points, conf)
        self.pipeline.warm_up(points, conf)

    def step(self, frame: KeypointFrame, now_s: float | None = None) -> list[PersonPose]:
        """Process one frame; returns the poses of the confirmed tracks seen in it (a track confirmed
        now records its detections of the frames before too, without returning them). ``now_s``: the
        clock of the new-track limit (seconds; default the frame's time)."""
        people = usable_people(frame, self.config)
        self.stats.frames += 1
        self.stats.skipped_people += people.skipped
        self.stats.degenerate_people += people.degenerate
        poses = []
        for seen in self.book.update(people, now_s):
            for detection in seen.earlier:
                self.pipeline.pose(seen.state, detection)
            poses.append(self.pipeline.pose(seen.state, seen.detection))
        self.stats.person_frames += len(poses)
        return poses

    def open_recordings(self) -> list[TrackRecording]:
        """The recordings of the tracks still open (``static`` says whether they are so far)."""
        return self.book.open_recordings()

    def cut_recordings(self, max_frames: int) -> list[TrackRecording]:
        """The recordings of open tracks that reached ``max_frames`` frames (``static`` set so far),
        each replaced by an empty one (next ``part``): no recording grows beyond ``max_frames``."""
        return self.book.cut_recordings(max_frames)

    def pop_finished(self) -> list[TrackRecording]:
        """The recordings of the tracks ended since the last call; the engine forgets them."""
        return self.book.pop_finished()

    def finish(self) -> list[TrackRecording]:
        """End every track; returns the recordings not yet popped (ended earlier or now), by track id."""
        return self.book.finish()
