"""The camera's rotation per frame from the background (issue 51, item 2), measured where `mocapdb
detect` reads the frames.

Each frame's green channel is shrunk to a grey image of about :data:`WORK_SIDE_PX` on its longer side
(a whole factor of it: :func:`shrink_factor`). Corners
(``cv2.goodFeaturesToTrack``) are found outside the people's boxes (their keypoints' box grown by
:data:`BOX_MARGIN`) in a *keyframe* and followed frame to frame by pyramidal Lucas-Kanade, each
kept only if tracking it back lands within :data:`BACK_TRACK_PX` of where it came from and it stays
out of the people's boxes. A camera that only turns moves every background pixel by one homography
``K R K⁻¹``, so the rotation from the keyframe to the frame is fitted to the tracks' rays directly
(:func:`fit_rotation`: RANSAC over two-ray samples, then least squares on the inliers). Each
frame's rotation is measured from its keyframe, not chained frame to frame, so the error does not
grow with every frame; it grows only when a new keyframe is taken (fewer than
:data:`KEEP_SHARE` of its tracks left, or fewer than :data:`MIN_TRACKS`).

A camera that *moves* (a phone carried by someone walking) shows parallax: near and far points no
longer share one homography. The median residual of the rotation-only fit over the tracked points
(pixels of the full image) is kept per frame; a frame whose tracks a free homography (8 degrees of
freedom: any rotation at any focal, and any plane) leaves a quarter of them more than
:data:`PARALLAX_PX` off on the shrunk image (6 px of a 1920 px frame; the tracking's own noise
there reached 0.54 px on the warped balancing video) is flagged ``moved``: the translation is
detected and reported, not compensated. (The rotation-only residual alone would flag a turning
camera whose focal is wrong.) A camera whose every turn stays under :data:`STILL_DEG` is written
as still (identity rotations: a tripod gives the figures it gave before). A turn of 3° between two
frames at a 600 px focal on a 640 px image (16 px of the shrunk image) is followed
(``tests/test_camera_motion.py``); a faster whip can lose the tracks (Lucas-Kanade's pyramid of
:data:`LK_LEVELS` levels), and a frame without tracks keeps the rotation before it until a new keyframe. Cost: a few
milliseconds a frame on the shrunk image (``tools/bench_video.py``). Without a given focal, the
path is refitted at the end at the focal the turn shows (:mod:`mocapdb.detect.focal_from_turn`).
"""
from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from mocapdb.core.formats.camera_path import CameraPath, intrinsic_matrix, rotation_angle_deg, write_camera_path
from mocapdb.core.formats.take import default_focal_px
from mocapdb.core.geometry import kabsch
from mocapdb.detect.errors import DetectError
from mocapdb.detect.focal_from_turn import Matches, best_focal, kept, rays, rotations_at, turn_from_key_deg

WORK_SIDE_PX = 320        # the longer side of the grey image tracked, about (pixels; a whole factor of the frame's)
MAX_FEATURES = 100        # corners found per keyframe
MIN_DISTANCE_PX = 8       # between two corners (on the shrunk image)
BOX_MARGIN = 0.25         # a person's keypoint box grown by this share of its size on each side
BACK_TRACK_PX = 0.5       # forward-backward disagreement tolerated (shrunk image pixels)
INLIER_PX = 1.0           # RANSAC: a track this close to the rotation's prediction agrees (shrunk pixels)
RANSAC_SAMPLES = 96       # two-ray hypotheses per frame
MIN_TRACKS = 12           # fewer tracks than this: a new keyframe
MIN_AGREE = 8             # fewer tracks than this agreeing on a rotation: the last frame's rotation is held
KEEP_SHARE = 0.5          # a keyframe whose tracks fell under this share of those it began with is renewed
PARALLAX_PX = 1.0         # a free homography's residual over this (shrunk image px, PARALLAX_QUANTILE): it moved
PARALLAX_QUANTILE = 0.75  # of the tracks: a quarter of the background off (one plane may hold the rest)
STILL_DEG = 0.1           # a camera whose every frame turned less than this from the first is still
MIN_CONFIDENCE = 0.3      # keypoints that count for a person's box
LK_WINDOW = (11, 11)
LK_LEVELS = 3
LIVE_EVERY = 2            # live measures every this many frames; the rotation between is extrapolated


def fit_rotation(a: np.ndarray, b: np.ndarray, threshold_rad: float, rng: np.random.Generator
                 ) -> tuple[np.ndarray, np.ndarray]:
    """The rotation ``R`` with ``b ≈ R a`` for rays ``[N, 3]`` (N ≥ 2), robust to outliers: the
    two-ray sample (of :data:`RANSAC_SAMPLES`) whose rotation most rays agree with to
    ``threshold_rad``, refitted twice on its inliers. Returns ``R`` and the inliers ``bool [N]``."""
    first = rng.integers(len(a), size=RANSAC_SAMPLES)
    picks = np.stack([first, (first + rng.integers(1, len(a), size=RANSAC_SAMPLES)) % len(a)], axis=1)  # distinct
    hypotheses = kabsch(a[picks], b[picks])                               # [S, 3, 3]
    # b·(R a) = Σ_ij R_ij b_i a_j: every hypothesis against every ray in one [S, 9] @ [9, N] product
    outer = (b[:, :, None] * a[:, None, :]).reshape(len(a), 9)
    agree = hypotheses.reshape(-1, 9) @ outer.T > np.cos(threshold_rad)   # [S, N]
    inliers = agree[int(np.argmax(agree.sum(axis=1)))]
    rotation = np.eye(3)
    for _ in range(2):
        if inliers.sum() < 2:
            break
        rotation = kabsch(a[inliers], b[inliers])
        inliers = (a @ rotation.T * b).sum(axis=1) > np.cos(threshold_rad)
    return rotation, inliers


def shrink_factor(image_size: tuple[int, int]) -> int:
    """The whole factor by which a frame of ``image_size`` (width, height px) is shrunk for tracking
    (boxes of ``factor × factor`` pixels averaged): the nearest to its longer side over
    :data:`WORK_SIDE_PX`. A whole factor keeps OpenCV's area resize on its fast path (1768 × 994:
    a quarter of the cost of a shrink to exactly 320 px)."""
    return max(1, round(max(image_size) / WORK_SIDE_PX))


def people_mask(shape: tuple[int, int], keypoints: np.ndarray, scale: float) -> np.ndarray:
    """``uint8 [H, W]`` of the shrunk image: 255 on the background, 0 in every person's box (its
    confident keypoints' box, ``[P, K, 3]`` full-image px, grown by :data:`BOX_MARGIN`)."""
    mask = np.full(shape, 255, dtype=np.uint8)
    for person in np.asarray(keypoints, dtype=np.float64).reshape(-1, *np.shape(keypoints)[-2:]):
        seen = person[(person[:, 2] >= MIN_CONFIDENCE) & np.isfinite(person[:, :2]).all(axis=1), :2] * scale
        if len(seen) < 2:
            continue
        low, high = seen.min(axis=0), seen.max(axis=0)
        grow = BOX_MARGIN * (high - low)
        x0, y0 = np.floor(np.maximum(low - grow, 0)).astype(int)
        x1, y1 = np.ceil(high + grow).astype(int)
        mask[y0:y1 + 1, x0:x1 + 1] = 0
    return mask


class BackgroundMotion:
    """The camera's rotation per frame (module docstring) through a camera of ``focal_px`` (pixels;
    None: :func:`~mocapdb.core.formats.take.default_focal_px` of the first frame's size; the principal
    point at the image's centre): :meth:`see` each frame with its people, then :meth:`path`, or
    :meth:`finish` to write it beside the keypoints (a `detect` frame watcher). Without ``history``
    (``live``) only the last frame is kept, for :meth:`online`: memory stays bounded however long
    it runs, and there is no whole path; there the background may be measured on every ``every``-th
    frame only, the frames between turned on at the pace of the last two measured
    (:meth:`_extrapolated`)."""

    def __init__(self, focal_px: float | None = None, history: bool = True, every: int = 1) -> None:
        if every < 1 or (every > 1 and history):
            raise ValueError("the camera path measures every frame when it keeps the whole path (every 1)")
        self.given_focal_px, self.history, self.every = focal_px, history, every
        self._seen = 0          # frames seen
        self._paced: list[tuple[int, np.ndarray]] = []   # the last two measured frames that agreed: number, rotation
        self.rng = np.random.default_rng(0)
        self.frames: list[int] = []
        self.rotations: list[np.ndarray] = []
        self.residual_px: list[float] = []
        self._grey: np.ndarray | None = None
        self._key_rays = np.zeros((0, 3))              # the keyframe's tracks' rays
        self._key_points = np.zeros((0, 2), np.float32)    # and their pixels there (shrunk px)
        self.parallax_px: list[float] = []
        self._points = np.zeros((0, 2), np.float32)    # where they are now (shrunk px)
        self._key_count = 0
        self._key_rotation = np.eye(3)
        self._turned = False    # a frame has turned STILL_DEG from the first (online)
        self._key_index = 0     # the keyframe's frame (an index into frames)
        self._matches: list[Matches | None] = []   # each frame's tracks against its keyframe (focal_from_turn)

    def _start(self, image_size: tuple[int, int]) -> None:
        """The shrunk image's size and the intrinsics, from the first frame's ``image_size`` (px)."""
        focal_px = self.given_focal_px or default_focal_px(image_size)
        self.image_size = image_size
        self.factor = shrink_factor(image_size)
        self.scale = 1.0 / self.factor
        self.small = (max(image_size[0] // self.factor, 1), max(image_size[1] // self.factor, 1))
        self.focal_px, self.center_px = float(focal_px), (image_size[0] / 2.0, image_size[1] / 2.0)
        self.intrinsics = intrinsic_matrix(focal_px * self.scale, (self.center_px[0] * self.scale,
                                                                   self.center_px[1] * self.scale))

    def see(self, number: int, image: np.ndarray, keypoints: np.ndarray) -> None:
        """Frame number ``number`` (``[H, W, 3]`` BGR) whose people are ``keypoints [P, K, 3]`` (x px,
        y px, confidence)."""
        if not self.frames:
            self._start((int(image.shape[1]), int(image.shape[0])))
        elif (image.shape[1], image.shape[0]) != self.image_size:
            raise DetectError(f"frame {number} is {image.shape[1]}x{image.shape[0]} px, the video's first "
                              f"{self.image_size[0]}x{self.image_size[1]}: no camera path across a change of size")
        self._seen += 1
        if (self._seen - 1) % self.every:
            self._keep(number, self._extrapolated(number), float("nan"), float("nan"), None)
            return
        grey = self._shrink(image)
        mask = people_mask(grey.shape, keypoints, self.scale)
        rotation = self.rotations[-1] if self.rotations else self._key_rotation
        residual, parallax = float("nan"), float("nan")
        matches = None if self._grey is None else Matches(self._key_index, np.zeros((0, 2)), np.zeros((0, 2)))
        measured = self._grey is None   # the first frame is the reference: its rotation the identity
        if self._grey is not None and len(self._points):
            self._track(self._grey, grey, mask)
            if len(self._points) >= MIN_AGREE:
                relative, fit_residual, fit_matches, agreeing = self._fit()
                if agreeing >= MIN_AGREE:   # else too little background to say: held
                    rotation, residual, matches = relative @ self._key_rotation, fit_residual, fit_matches
                    parallax = self._parallax() if self.history else parallax   # live reports no parallax
                    measured = True
        self._paced = [*self._paced, (int(number), rotation)][-2:] if measured else []
        self._keep(number, rotation, residual, parallax, matches)
        if len(self._points) < max(MIN_TRACKS, KEEP_SHARE * self._key_count):
            self._new_keyframe(grey, mask, rotation)
        self._grey = grey

    def _keep(self, number: int, rotation: np.ndarray, residual: float, parallax: float,
              matches: Matches | None) -> None:
        """Frame ``number``'s rotation, residual and parallax (px) and matches, noted (without
        ``history``: in place of the last frame's)."""
        self.frames.append(int(number))
        self.rotations.append(rotation)
        self.residual_px.append(residual)
        self.parallax_px.append(parallax)
        self._matches.append(matches)
        if not self.history:
            for kept_so_far in (self.frames, self.rotations, self.residual_px, self.parallax_px, self._matches):
                del kept_so_far[:-1]

    def _extrapolated(self, number: int) -> np.ndarray:
        """Frame ``number``'s rotation, not measured (``every`` > 1): the last measured one turned on by
        the turn between the last two measured (the same axis, its angle in proportion to the frames
        since); the last frame's rotation when the last two did not both agree on a rotation."""
        if len(self._paced) < 2:
            return self.rotations[-1] if self.rotations else self._key_rotation
        (first, before), (last, after) = self._paced
        turn, _ = cv2.Rodrigues(after @ before.T)
        ahead, _ = cv2.Rodrigues(turn * ((number - last) / max(last - first, 1)))
        return ahead @ after

    def _shrink(self, image: np.ndarray) -> np.ndarray:
        """``image``'s (``[H, W, 3]`` BGR) green channel (most of the luminance: half the cost of a colour
        conversion) as the grey image tracked, :attr:`small` (px): the frame cut to a whole number of
        :attr:`factor` boxes (the last few rows and columns), each box averaged."""
        cut = image[:self.small[1] * self.factor, :self.small[0] * self.factor]
        return cv2.resize(cv2.extractChannel(cut, 1), self.small, interpolation=cv2.INTER_AREA)

    def online(self) -> np.ndarray | None:
        """The rotation (reference → the last frame seen) the path known so far gives, as ``live``
        uses it; None (still) while no frame has turned :data:`STILL_DEG` (as :meth:`path` decides
        at the end)."""
        if self.frames and not self._turned:
            self._turned = bool(rotation_angle_deg(self.rotations[-1]) >= STILL_DEG)
        return self.rotations[-1] if self._turned else None

    @property
    def full_intrinsics(self) -> np.ndarray:
        """``K`` of the full image (the first frame's size; its focal and centre)."""
        return intrinsic_matrix(self.focal_px, self.center_px)

    def _track(self, previous: np.ndarray, grey: np.ndarray, mask: np.ndarray) -> None:
        """The tracks followed from ``previous`` into ``grey``: those that track back to where they
        were and stay out of the people's boxes."""
        # output arrays given: OpenCV 4's stubs take no None for them
        ahead, ok, _ = cv2.calcOpticalFlowPyrLK(previous, grey, self._points, np.empty_like(self._points),
                                                winSize=LK_WINDOW, maxLevel=LK_LEVELS)
        back, ok_back, _ = cv2.calcOpticalFlowPyrLK(grey, previous, ahead, np.empty_like(self._points),
                                                    winSize=LK_WINDOW, maxLevel=LK_LEVELS)
        returned = np.linalg.norm(back - self._points, axis=1) < BACK_TRACK_PX
        keep = (ok.ravel() == 1) & (ok_back.ravel() == 1) & returned
        x, y = np.round(ahead[:, 0]).astype(int), np.round(ahead[:, 1]).astype(int)
        inside = (x >= 0) & (y >= 0) & (x < grey.shape[1]) & (y < grey.shape[0])
        keep &= inside
        keep[keep] &= mask[y[keep], x[keep]] > 0
        self._points, self._key_rays, self._key_points = ahead[keep], self._key_rays[keep], self._key_points[keep]

    def _fit(self) -> tuple[np.ndarray, float, Matches, int]:
        """The rotation from the keyframe to now, the rotation-only fit's median residual over the
        tracks (full-image px), its inliers' matches (for the focal, :meth:`path`) and their count."""
        now = rays(self._points.astype(np.float64), self.intrinsics)
        relative, inliers = fit_rotation(self._key_rays, now, INLIER_PX / self.intrinsics[0, 0], self.rng)
        predicted = (self._key_rays @ relative.T) @ self.intrinsics.T
        error = np.linalg.norm(predicted[:, :2] / predicted[:, 2:] - self._points, axis=1)
        matches = Matches(self._key_index, kept(self._key_points[inliers]), kept(self._points[inliers]))
        return relative, float(np.median(error)) / self.scale, matches, int(inliers.sum())

    def _parallax(self) -> float:
        """The residual (full-image px, its :data:`PARALLAX_QUANTILE` over the tracks) of a free
        homography from the keyframe's tracks to now (RANSAC): what no rotation at any focal
        explains, the parallax of a camera that moved;
        NaN with fewer than 8 tracks."""
        if len(self._points) < 8:
            return float("nan")
        homography, _ = cv2.findHomography(self._key_points, self._points, cv2.RANSAC, 2.0 * INLIER_PX)
        if homography is None:
            return float("nan")
        moved = cv2.perspectiveTransform(self._key_points.reshape(-1, 1, 2), homography).reshape(-1, 2)
        return float(np.quantile(np.linalg.norm(moved - self._points, axis=1), PARALLAX_QUANTILE)) / self.scale

    def _new_keyframe(self, grey: np.ndarray, mask: np.ndarray, rotation: np.ndarray) -> None:
        """Fresh corners in ``grey``'s background; the keyframe's rotation is this frame's."""
        corners = cv2.goodFeaturesToTrack(grey, MAX_FEATURES, 0.01, MIN_DISTANCE_PX, mask=mask)
        self._points = np.zeros((0, 2), np.float32) if corners is None else corners.reshape(-1, 2).astype(np.float32)
        self._key_points = self._points.copy()
        self._key_rays = rays(self._points.astype(np.float64), self.intrinsics)
        self._key_count, self._key_rotation = len(self._points), rotation
        self._key_index = len(self.frames) - 1

    def path(self) -> CameraPath:
        """The path of the frames seen: the rotations from the first frame's camera, each frame's
        residual, ``moved`` where a free homography leaves over :data:`PARALLAX_PX`, ``still`` when no
        turn reached :data:`STILL_DEG`
        (then every rotation is the identity)."""
        if not self.frames or not self.history:
            raise ValueError("no camera path: no frame seen, or none kept (history=False)")
        rotations, focal_px = self._focal_from_turn()
        residual = np.array(self.residual_px)
        still = bool(np.all(rotation_angle_deg(rotations) < STILL_DEG))
        if still:
            rotations = np.broadcast_to(np.eye(3), rotations.shape).copy()
        moved = np.nan_to_num(np.array(self.parallax_px), nan=0.0) > PARALLAX_PX / self.scale
        return CameraPath(np.array(self.frames), rotations, focal_px, self.center_px, residual, moved, still)

    def _focal_from_turn(self) -> tuple[np.ndarray, float]:
        """The rotations and the focal (full-image px): refitted at the focal the background's turn
        shows (:mod:`~mocapdb.detect.focal_from_turn`) when none was given and it shows one, else
        as measured."""
        rotations = np.array(self.rotations)
        if self.given_focal_px is not None:
            return rotations, self.focal_px
        keys = np.array([0 if m is None else m.key_frame for m in self._matches])
        centre = (self.center_px[0] * self.scale, self.center_px[1] * self.scale)
        focal = best_focal(self._matches, turn_from_key_deg(rotations, keys), self.intrinsics[0, 0], centre)
        if focal is None:
            return rotations, self.focal_px
        return rotations_at(self._matches, focal, centre), focal / self.scale

    def finish(self, out_dir: Path) -> list[str]:
        """Write the path (``camera_path.json``) into ``out_dir``; returns the lines `detect` reports
        (how far the camera turned; the frames whose background showed it moved)."""
        if not self.frames:
            return []
        path = self.path()
        write_camera_path(out_dir, path)
        return [describe_path(path)]


def describe_path(path: CameraPath) -> str:
    """One line on a camera path: still, or how far it turned; the frames that showed parallax."""
    turned = "still" if path.still else f"turned up to {path.turn_deg().max():.1f} deg from the first frame"
    line = f"camera {turned} (background tracked; focal {path.focal_px:.0f} px)"
    if path.moved.any():
        line += (f"; {int(path.moved.sum())} frame(s) show parallax (a quarter of the background off any "
                 "homography): the camera moved, not only turned, and its translation is not compensated")
    return line
