"""``mocapdb live --view``: the stream's frames for the pages watching it, never waiting for them.

:class:`PageSink` is one more sink of the session (beside ``--sink``, through
:class:`~mocapdb.runtime.stream.sinks.TeeSink`): the engine's thread only copies each frame's
joints into every watching page's queue (:class:`LiveFeed`), at most :data:`QUEUE_FRAMES` deep, the
oldest dropped and counted when a page falls behind. Each page's own server thread turns its frames
into JSON (levelled on the floor the stream estimates, re-projected through the run's camera) and
sends them as server-sent events; a slow or closed page slows only that thread. The scene stands on
the floor the stream estimates under the person seen longest.
"""
from __future__ import annotations

import json
import threading
import time
from collections import deque
from dataclasses import dataclass

import numpy as np

from mocapdb.core.outputs import CAMERA_FROM_VIEW, STREAM_FORMAT, PersonPose
from mocapdb.core.skeleton import KEYPOINTS, swing_matrices
from mocapdb.render.draw import project_pinhole
from mocapdb.runtime.stream.sinks import Sink
from mocapdb.view import payload

QUEUE_FRAMES = 4    # frames queued per page before the oldest is dropped
MAX_PAGES = 8       # pages watching at once; more are refused (each holds a server thread)
MAX_COUNTED_TRACKS = 256   # tracks whose frames are counted; beyond, those not in the frame are forgotten
END = "end"         # queued when the stream ends
_ANKLES = [KEYPOINTS.index("r_ankle"), KEYPOINTS.index("l_ankle")]
_Y = np.array([0.0, 1.0, 0.0])


@dataclass(frozen=True)
class LivePerson:
    """What the page needs of one person of one frame, copied out of the engine's pose."""
    track: int
    joints: np.ndarray                 # [15, 3] camera-aligned, metres
    keypoints: np.ndarray | None       # [14, 3] the keypoints it was fitted to: x, y px, confidence
    up_view: np.ndarray | None
    floor_offset_m: float | None
    height_m: float
    quaternions: np.ndarray            # [11, 4] the rig's local rotations, view frame
    end_quaternions: np.ndarray | None  # [5, 4] the feet's, hands' and head's (None: not turned)


@dataclass(frozen=True)
class LiveFrame:
    index: int
    time_s: float
    sent_s: float      # time.time() when the engine wrote it
    people: tuple[LivePerson, ...]


class Page:
    """One watching page: a bounded queue of frames (the oldest dropped and counted)."""

    def __init__(self) -> None:
        self.queue: deque[LiveFrame | dict | str] = deque(maxlen=QUEUE_FRAMES)
        self.cond = threading.Condition()
        self.dropped = 0

    def offer(self, item: LiveFrame | dict | str) -> int:
        """Queue ``item``; returns 1 when the oldest frame was dropped for it, else 0."""
        with self.cond:
            full = len(self.queue) == self.queue.maxlen
            self.queue.append(item)
            self.dropped += full
            self.cond.notify()
        return int(full)

    def take(self, timeout_s: float) -> LiveFrame | dict | str | None:
        """The oldest queued item, or None after ``timeout_s`` without one."""
        with self.cond:
            if not self.cond.wait_for(lambda: self.queue, timeout_s):
                return None
            return self.queue.popleft()


class LiveFeed:
    """The live stream as the pages see it: the run's camera (from the stream's header) and its
    frames, fanned out to at most :data:`MAX_PAGES` pages; counts frames sent and dropped."""

    def __init__(self) -> None:
        self.header: dict | None = None
        self._pages: list[Page] = []
        self._lock = threading.Lock()
        self.pages_seen = self.frames = self.dropped = 0
        self.ended = False
        self._seen: dict[int, int] = {}   # frames seen per track

    def subscribe(self) -> Page | None:
        """A new page's queue (the header first when known); None when :data:`MAX_PAGES` watch."""
        with self._lock:
            if len(self._pages) >= MAX_PAGES:
                return None
            page = Page()
            if self.header is not None:
                page.offer(self.header)
            if self.ended:
                page.offer(END)
            self._pages.append(page)
            self.pages_seen += 1
            return page

    def unsubscribe(self, page: Page) -> None:
        with self._lock:
            if page in self._pages:
                self._pages.remove(page)

    def _publish(self, item: LiveFrame | dict | str) -> None:
        with self._lock:
            pages = list(self._pages)
        dropped = sum(page.offer(item) for page in pages)
        with self._lock:
            self.dropped += dropped

    def line(self, text: str) -> None:
        """A line of the stream: its header gives the camera and the frame rate."""
        try:
            obj = json.loads(text)
        except ValueError:
            return
        if not isinstance(obj, dict) or obj.get("format") != STREAM_FORMAT:
            return
        size, focal = obj.get("image_size"), obj.get("focal_px")
        image = payload.image(float(focal), (int(size[0]), int(size[1]))) \
            if isinstance(size, list) and len(size) == 2 and isinstance(focal, (int, float)) else None
        self.header = {"type": "header", "fps": obj.get("fps"), "image": image, "lag_s": obj.get("lag_s")}
        self._publish(self.header)

    def frame(self, index: int, time_s: float, people: list[PersonPose]) -> None:
        """One frame from the engine's thread: copied and queued for every page, never waited for;
        the person seen longest first (the floor is theirs: a false detection's is not the floor)."""
        for p in people:
            self._seen[p.track] = self._seen.get(p.track, 0) + 1
        if len(self._seen) > MAX_COUNTED_TRACKS:
            self._seen = {p.track: self._seen[p.track] for p in people}
        with self._lock:
            if not self._pages:
                return
            self.frames += 1
        first = sorted(people, key=lambda p: (-self._seen[p.track], float(np.linalg.norm(p.root_m))))
        copied = tuple(LivePerson(p.track, np.array(p.joints_m, dtype=np.float64),
                                  None if p.keypoints_px is None else np.array(p.keypoints_px),
                                  None if p.up_view is None else np.array(p.up_view), p.floor_offset_m,
                                  float(p.height_m), np.array(p.quaternions),
                                  None if p.end_quaternions is None else np.array(p.end_quaternions))
                       for p in first)
        self._publish(LiveFrame(index, time_s, time.time(), copied))

    def end(self) -> None:
        """The stream ended: every page is told."""
        self.ended = True
        self._publish(END)

    def meta(self) -> dict:
        """The page's description of the live take (``data_specs/viewer.md``)."""
        header = self.header or {}
        return {"kind": "live", "title": "live", "fps": header.get("fps"), "frames": [],
                "skeleton": payload.skeleton(), "image": header.get("image"), "video": False, "keypoints": True,
                "tracks": [], "cameras": [], "floor": False, "floor_y": 0.0, "summary": [], "files": [],
                "note": "the live stream"}

    def event(self, item: LiveFrame | dict, page: Page) -> str:
        """The server-sent event of a queued item (the header, or a frame levelled on the first
        person's floor that has one, and projected)."""
        if isinstance(item, dict):
            return json.dumps(item)
        image = (self.header or {}).get("image")
        level = next(((p.up_view, p.floor_offset_m) for p in item.people
                      if p.up_view is not None and p.floor_offset_m is not None and np.all(np.isfinite(p.up_view))),
                     None)
        turn = np.eye(3) if level is None else swing_matrices(level[0] / np.linalg.norm(level[0]), _Y)
        lift = np.zeros(3) if level is None else np.array([0.0, -float(level[1]), 0.0])
        people = []
        for p in item.people:
            scene = (p.joints * CAMERA_FROM_VIEW) @ turn.T + lift
            person = {"track": p.track, "joints": payload.numbers(scene, 4), "colour": payload.colour(p.track),
                      "label": f"#{p.track} {p.height_m:.2f} m"}
            if image is not None:
                person["px"] = payload.numbers(project_pinhole(p.joints, image["focal"], (image["cx"], image["cy"])), 1)
            if p.keypoints is not None:
                person["keypoints"] = payload.input_people([p.keypoints])[0]
            if p.end_quaternions is not None:
                person.update(payload.end_directions(p.quaternions, p.end_quaternions, turn))
            people.append(person)
        axes = payload.VIEW_AXES @ turn.T
        camera = payload.camera("camera", lift, axes, None if image is None else payload.fov(image),
                                "camera" if level is None else f"camera {lift[1]:.2f} m")
        ankles = np.array([(p.joints * CAMERA_FROM_VIEW)[_ANKLES] @ turn.T + lift for p in item.people]).reshape(-1, 3)
        low = ankles[np.isfinite(ankles[:, 1]), 1]
        floor_y = 0.0 if level is not None or not len(low) else float(low.min()) - 0.08
        return json.dumps({"type": "frame", "frame": item.index, "time": round(item.time_s, 6),
                           "sent_ms": round(item.sent_s * 1000, 1), "dropped": page.dropped, "people": people,
                           "camera": camera, "floor": level is not None, "floor_y": round(floor_y, 3)})

    def report(self) -> str:
        """One line for the end of the run."""
        return (f"view: {self.pages_seen} page(s) watched, {self.frames} frame(s) sent, {self.dropped} dropped "
                "for pages that fell behind")


class PageSink(Sink):
    """The live pages' sink: the header and frames go to the :class:`LiveFeed`, never waited for."""

    def __init__(self, feed: LiveFeed) -> None:
        super().__init__()
        self.feed = feed

    def _put(self, text: str) -> None:
        self.feed.line(text)

    def write_frame(self, frame_index: int, time_s: float, people: list[PersonPose]) -> None:
        self.feed.frame(frame_index, time_s, people)

    def close(self) -> None:
        self.feed.end()
