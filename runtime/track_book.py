"""The engine's tracks: who is who across frames, within the track limits, and their recordings.

:class:`TrackBook` runs the tracker (:mod:`mocapdb.runtime.tracker`) within
:class:`~mocapdb.runtime.engine_config.TrackLimits` (the new-track window: :class:`NewTrackWindow`),
starts a track's memory (:class:`~mocapdb.runtime.track_state.TrackState`) when it is confirmed,
ends every track after a gap in time, feeds each track's stillness check and hands out the
recordings: finished, open, cut. It knows nothing of retrieval: it says which track each detection
belongs to (:class:`Sighting`), and the pose pipeline (:mod:`mocapdb.runtime.pose_pipeline`) makes
and records its pose.
"""
from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np

from mocapdb.core.outputs import TrackRecording
from mocapdb.runtime.engine_config import EngineConfig
from mocapdb.runtime.frame_people import Detection, FramePeople
from mocapdb.runtime.track_state import TrackState
from mocapdb.runtime.tracker import Tracker, TrackUpdate


@dataclass
class TrackCounts:
    tracks_started: int = 0
    gaps: int = 0             # jumps in time or frame number that ended every track
    over_max_tracks: int = 0  # detections not tracked: TrackLimits.max_tracks tracks were alive
    over_max_new: int = 0     # detections not tracked: TrackLimits.max_new_per_min reached


@dataclass
class Sighting:
    """A confirmed track seen in a frame: its memory, its ``detection`` there and, when it was
    confirmed on this frame, its ``earlier`` detections (the frames before, oldest first) to record first."""

    state: TrackState
    detection: Detection
    earlier: list[Detection]


class NewTrackWindow:
    """When the tracks of the last 60 s were confirmed, to hold their number to a limit."""

    def __init__(self) -> None:
        self.times: deque[float] = deque()

    def allowed(self, limit: int, now_s: float) -> int | None:
        """How many tracks may be confirmed at ``now_s`` (None: no limit)."""
        if not limit:
            return None
        while self.times and self.times[0] <= now_s - 60.0:
            self.times.popleft()
        return max(limit - len(self.times), 0)

    def add(self, n: int, limit: int, now_s: float) -> None:
        if limit:
            self.times.extend([now_s] * n)


class TrackBook:
    """The tracks of one stream: call :meth:`update` per frame, :meth:`finish` at the end."""

    def __init__(self, config: EngineConfig, counts: TrackCounts | None = None):
        self.config = config
        self.counts = counts if counts is not None else TrackCounts()
        self.tracker = Tracker(config.tracker)
        self.tracks: dict[int, TrackState] = {}  # the confirmed tracks alive, by id
        self.finished: list[TrackRecording] = []
        self._new_tracks = NewTrackWindow()
        self._last_seen: tuple[int, float] | None = None
        # the last frames' usable people, for tracks confirmed later
        self._recent: deque[FramePeople] = deque(maxlen=max(config.tracker.min_hits - 1, 0))

    def warm_up(self, points_px: np.ndarray, confidence: np.ndarray) -> None:
        """Run the tracker's compiled kernels on a pose ``[14, 2]`` px (a throw-away tracker)."""
        Tracker(self.config.tracker).update(points_px[None], confidence[None], 0.0)

    def update(self, people: FramePeople, now_s: float | None = None) -> list[Sighting]:
        """Track a frame's people; returns the confirmed tracks seen in it, by track id (a track
        confirmed now with its detections of the frames before). ``now_s``: the clock of the
        new-track limit (seconds; default the frame's time)."""
        self._end_tracks_after_a_gap(people.frame_index, people.t_s)
        update = self._limited_update(people, people.t_s if now_s is None else now_s)
        for track in update.ended:
            self._end(track)
        sightings = []
        for track, det in update.assignments:
            earlier = []
            if track not in self.tracks:
                earlier = self._start(track, update.earlier.get(track, []), people.frame_index)
            sightings.append(Sighting(self.tracks[track], people.detection(det), earlier))
        for sighting in sightings:
            for detection in (*sighting.earlier, sighting.detection):
                sighting.state.stillness.add(detection.points_px, detection.confidence > 0, detection.t_s)
        self._recent.append(people)
        return sightings

    def open_recordings(self) -> list[TrackRecording]:
        """The recordings of the tracks still open (``static`` says whether they are so far)."""
        for state in self.tracks.values():
            state.recording.static = state.stillness.static
        return [s.recording for s in self.tracks.values() if len(s.recording)]

    def cut_recordings(self, max_frames: int) -> list[TrackRecording]:
        """The recordings of open tracks that reached ``max_frames`` frames (``static`` set so far),
        each replaced by an empty one (next ``part``): no recording grows beyond ``max_frames``."""
        cut = []
        for state in self.tracks.values():
            rec = state.recording
            if len(rec) >= max_frames:
                rec.static = state.stillness.static
                state.recording = TrackRecording(rec.track, state.last_frame + 1, part=rec.part + 1,
                                                 camera_px=rec.camera_px)
                cut.append(rec)
        return cut

    def pop_finished(self) -> list[TrackRecording]:
        """The recordings of the tracks ended since the last call; the book forgets them."""
        done, self.finished = self.finished, []
        return done

    def finish(self) -> list[TrackRecording]:
        """End every track; returns the recordings not yet popped (ended earlier or now), by track id."""
        self._end_all()
        return sorted(self.finished, key=lambda r: r.track)

    def _start(self, track: int, earlier: list[int], frame_index: int) -> list[Detection]:
        """A track confirmed on frame ``frame_index``: its memory, whose recording starts at its first
        detection (the stream at its confirmation). Returns those ``earlier`` detections (the frames
        before, :attr:`TrackUpdate.earlier`)."""
        frames = list(self._recent)[len(self._recent) - len(earlier):] if earlier else []
        first = frames[0].frame_index if frames else frame_index
        state = self.tracks[track] = TrackState(track, first, self.config, len(self.config.window_weights))
        if self.config.keep_take and self.config.refine:
            state.recording.camera_px = (self.config.focal_px, *self.config.center_px)
        self.counts.tracks_started += 1
        return [people.detection(det) for people, det in zip(frames, earlier)]

    def _limited_update(self, people: FramePeople, now_s: float) -> TrackUpdate:
        """The tracker's update within the limits, counting what they held back."""
        limits = self.config.limits
        allowed = self._new_tracks.allowed(limits.max_new_per_min, now_s)
        update = self.tracker.update(people.points_px, people.confidence, people.t_s, limits.max_tracks, allowed)
        self._new_tracks.add(len(update.started), limits.max_new_per_min, now_s)
        self.counts.over_max_tracks += update.over_max_tracks
        self.counts.over_max_new += update.over_max_new
        return update

    def _end_tracks_after_a_gap(self, frame_index: int, t_s: float) -> None:
        """A jump of more than ``max_gap_s`` ends every track, so a time (or, for frames without
        one, a frame number) far in the future costs one frame, not the frames in between."""
        last = self._last_seen
        self._last_seen = (frame_index, t_s)
        if last is not None and t_s - last[1] > self.config.max_gap_s:
            self.counts.gaps += 1
            self._end_all()

    def _end(self, track: int) -> None:
        state = self.tracks.pop(track, None)
        if state is not None and len(state.recording):
            state.recording.static = state.stillness.static
            self.finished.append(state.recording)

    def _end_all(self) -> None:
        for track in self.tracker.finish():
            self._end(track)
        for track in list(self.tracks):
            self._end(track)
