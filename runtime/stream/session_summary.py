"""What a session reports: :class:`SessionSummary` (frames, people, tracks, malformed messages,
latency, throughput, the files written, the world's lines) and :class:`LimitReport` (the limits in
force and what they held back), each list capped so memory stays bounded."""
from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

from mocapdb.runtime.stream.latency import LatencyBook
from mocapdb.runtime.stream.transport import StreamStats

MAX_REASONS = 50         # distinct malformed-message reasons counted; further ones as "other"
MAX_LISTED = 100         # static track ids listed in the summary


@dataclass
class LimitReport:
    """The limits in force and what they held back (data_specs/stream_output.md, "Limits")."""

    max_tracks: int = 0
    max_new_per_min: int = 0
    max_bvh_files: int = 0
    min_track_s: float = 0.0
    over_max_tracks: int = 0   # detections not tracked
    over_max_new: int = 0      # detections not tracked
    over_max_files: int = 0    # tracks (or parts) without a BVH file
    short_tracks: int = 0      # tracks without a BVH file

    def lines(self) -> list[str]:
        held = [(self.over_max_tracks, f"detections not tracked (--max-tracks {self.max_tracks} alive)"),
                (self.over_max_new, f"detections not tracked (--max-new-tracks-per-min {self.max_new_per_min})"),
                (self.over_max_files, f"tracks or parts without BVH (--max-bvh-files {self.max_bvh_files})"),
                (self.short_tracks, f"tracks without BVH (shorter than --min-track-s {self.min_track_s:g} s)")]
        return [f"limits: {what}: {n}" for n, what in held if n]


@dataclass
class SessionSummary:
    """What a session did; :meth:`report` renders it for the terminal."""

    frames: int = 0
    person_frames: int = 0
    tracks: int = 0
    malformed: Counter = field(default_factory=Counter)
    malformed_first: dict = field(default_factory=dict)  # reason → where it was first seen
    stream: StreamStats = field(default_factory=StreamStats)
    latency: LatencyBook = field(default_factory=LatencyBook)   # capture → the sink's send, the lag
    wall_s: float = 0.0
    steady_s: float = 0.0   # from the first frame processed (its output written) to the last
    bvh_files: list[Path] = field(default_factory=list)
    static_tracks: list[int] = field(default_factory=list)  # left out of the BVH output (first MAX_LISTED)
    n_static: int = 0
    gaps: int = 0
    degenerate: int = 0
    points_out_of_frame: int = 0   # keypoints a detector put beyond its video's image, taken as unseen
    limits: LimitReport = field(default_factory=LimitReport)
    sink_error: str | None = None  # why the sink failed, which stopped the session
    world_lines: list[str] = field(default_factory=list)  # the take's world and each track's size (world_summary)

    def add_malformed(self, reason: str, origin: str | None = None) -> None:
        if reason not in self.malformed and len(self.malformed) >= MAX_REASONS:
            reason = "other reasons"
        self.malformed[reason] += 1
        if origin and reason not in self.malformed_first:
            self.malformed_first[reason] = origin

    def add_static(self, track: int) -> None:
        self.n_static += 1
        if len(self.static_tracks) < MAX_LISTED:
            self.static_tracks.append(track)

    def _files_by_format(self) -> str:
        """``6 (2 BVH, 2 TRC, 2 CSV)``: the track files written, per format."""
        kinds = Counter(path.suffix.lstrip(".").upper() for path in self.bvh_files)
        per_format = ", ".join(f"{n} {kind}" for kind, n in kinds.items())
        return f"{len(self.bvh_files)}" + (f" ({per_format})" if per_format else "")

    def _throughput(self) -> str:
        """The frames/s after the first frame processed (steady state: start-up, model loading and the first
        frame's compiling left out) and the session's whole time."""
        rate = (self.frames - 1) / self.steady_s if self.frames > 1 and self.steady_s > 0 else float("nan")
        return (f"throughput {rate:.1f} frames/s from the first frame processed (over {self.steady_s:.2f} s), "
                f"session {self.wall_s:.2f} s")

    def report(self) -> str:
        lines = [f"frames {self.frames}, people {self.person_frames} person-frames, tracks {self.tracks}, "
                 f"track files {self._files_by_format()}",
                 f"{self.latency.line()}; {self._throughput()}",
                 f"skipped: stale {self.stream.dropped_stale}, oversized {self.stream.oversized}, "
                 f"not UTF-8 {self.stream.decode_errors}, undelivered output lines {self.stream.sink_dropped}"
                 + (f", folder entries not regular files {self.stream.not_regular}" if self.stream.not_regular else "")]
        lines += [f"skipped malformed ({n}): {why}" + (f" (first in {self.malformed_first[why]})"
                                                         if why in self.malformed_first else "")
                  for why, n in self.malformed.most_common()]
        if self.static_tracks:
            unlisted = self.n_static - len(self.static_tracks)
            more = f" and {unlisted} more" if unlisted else ""
            lines.append(f"static tracks (keypoints never moved; no BVH, --keep-static keeps them): "
                         f"{', '.join(map(str, self.static_tracks))}{more}")
        if self.points_out_of_frame:
            lines.append(f"keypoints beyond the video's image (a part out of frame, its place guessed), taken as "
                         f"unseen: {self.points_out_of_frame}")
        if self.degenerate:
            lines.append(f"people skipped with all keypoints within 4 px (no size, no depth): {self.degenerate}")
        if self.gaps:
            lines.append(f"jumps in time longer than the gap limit (every track ended): {self.gaps}")
        lines += self.limits.lines()
        lines += self.world_lines
        if self.sink_error:
            lines.append(f"output stopped: the sink failed ({self.sink_error})")
        return "\n".join(lines)
