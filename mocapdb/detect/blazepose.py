"""BlazePose for several people: the person detector finds them, one landmark run per person follows each.

Two ONNX models converted from MediaPipe's TFLite files (:mod:`mocapdb.detect.model_store`):

- the **person detector** (224 × 224, an SSD over :func:`ssd_anchors`): per person a box and four
  alignment points, of which the hips' centre and a point above the head give the person's region
  (:func:`region_from_points`): a square, rotated so the body stands upright, 1.25 × the body's
  reach on each side;
- the **landmark model** (256 × 256, lite, full or heavy): in a person's region, 33 landmarks
  (x, y px, depth, visibility, presence), a flag that a person is there, two more points (the
  hips' centre and the head's) that give the region of the next frame, and the **world landmarks**:
  the 33 landmarks in metres, 3D, origin at the hips' centre (:func:`world_from_output`).

:class:`BlazePose` runs them on consecutive frames: each person's region follows its own landmarks
from frame to frame. The detector runs on squares of the frame (:func:`scan_tiles`: the whole frame,
squares of its shorter side, squares of half that, for people far away): all but the smallest on
the first frame and after someone is lost or while nobody is followed, and otherwise one square
every ``scan_every`` frames in turn. A detection outside every followed region starts a new person;
with ``max_people``, only while fewer are followed, the most prominent first (:func:`prominence`); the
ones followed are kept until lost (no flip to a bystander), and while ``max_people`` are followed the
scan is skipped.
Output: :class:`~mocapdb.detect.model.Detections` with 33 keypoints per person in the
``mediapipe33`` layout (``data_specs/keypoint_formats.md``), the landmark's visibility as its
confidence, and their world landmarks ``[P, 33, 3]`` (metres; x right, y down along the image's
axes, z away from the camera; origin at the hips' centre: MediaPipe's ``pose_world_landmarks``). Pre- and
post-processing, and the figures they come from: ``data_specs/pose_models.md``.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from mocapdb.core.formats.keypoint_layouts import LAYOUTS
from mocapdb.detect.model import Detections, box_area, box_intersection, box_iou, load_session

DETECTOR_PX = 224            # person detector input side, pixels
LANDMARK_PX = 256            # landmark model input side, pixels
ANCHOR_STRIDES = (8, 16, 32, 32, 32)   # SSD layers; layers of one stride share a grid
ANCHOR_MIN_SCALE, ANCHOR_MAX_SCALE = 0.1484375, 0.75
DETECTION_SCORE = 0.5        # least person score (sigmoid of the detector's logit)
SCORE_CLIP = 100.0           # detector logits are clipped to ± this before the sigmoid
DETECTION_IOU = 0.3          # detections overlapping a better one by more are merged into it
REGION_SCALE = 1.25          # a region's side: this × twice the hips-to-head-point distance
PRESENCE = 0.5               # a landmark run whose person flag is below this has lost its person
MIN_FILL = 0.5               # a body's landmarks span at least this share of its region's side (else: no body)
SAME_PERSON_SHARE = 0.5      # two followed people are one when this share of the smaller box lies in the other
N_LANDMARKS = 33             # the landmarks written (the mediapipe33 layout)
N_OUTPUT_POINTS = 39         # the model's points: 33 landmarks, then the region points and 4 more
REGION_POINTS = (33, 34)     # the hips' centre and the point above the head, among the model's points
LANDMARK_OUTPUTS = ("Identity", "Identity_1")   # the landmarks and the person flag; the mask and the
                                                # heatmaps are never computed (a third of the cost)
WORLD_OUTPUT = "Identity_4"  # the world landmarks [1, 117]: the 39 points' (x, y, z), metres, in the crop's
                             # axes (one 1 × 1 convolution more than the landmarks: no measurable cost)
DEFAULT_SCAN_EVERY = 3       # the person detector runs on one tile of the scan every this many frames
TILE_OVERLAP = 0.25          # neighbouring tiles of one size share at least this share of their side


def ssd_anchors() -> np.ndarray:
    """The person detector's anchor centres ``[2254, 2]`` (x, y as a share of the input side), in
    the order of its outputs: per stride's grid, row by row, each cell's anchors together (two per
    layer: the layer's scale and the one between it and the next)."""
    centres = []
    layer = 0
    while layer < len(ANCHOR_STRIDES):
        stride = ANCHOR_STRIDES[layer]
        same = sum(1 for s in ANCHOR_STRIDES[layer:] if s == stride)
        side = math.ceil(DETECTOR_PX / stride)
        ys, xs = np.meshgrid((np.arange(side) + 0.5) / side, (np.arange(side) + 0.5) / side, indexing="ij")
        cells = np.stack([xs.ravel(), ys.ravel()], axis=1)
        centres.append(np.repeat(cells, 2 * same, axis=0))
        layer += same
    return np.concatenate(centres)


ANCHORS = ssd_anchors()


def decode_people(raw_boxes: np.ndarray, raw_logits: np.ndarray, anchors: np.ndarray = ANCHORS,
                  min_score: float = DETECTION_SCORE) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The detector's outputs ``[N, 12]`` and ``[N, 1]`` → boxes ``[P, 4]`` (x1, y1, x2, y2), scores
    ``[P]`` and alignment points ``[P, 4, 2]`` (x, y), all in input pixels, for the anchors scoring
    at least ``min_score``, overlapping ones merged (weighted by score)."""
    scores = _sigmoid(np.clip(raw_logits.reshape(-1).astype(np.float64), -SCORE_CLIP, SCORE_CLIP))
    keep = np.flatnonzero(scores >= min_score)
    raw = raw_boxes.reshape(-1, 12)[keep].astype(np.float64)
    centre = raw[:, :2] + anchors[keep] * DETECTOR_PX
    half = raw[:, 2:4] / 2.0
    boxes = np.concatenate([centre - half, centre + half], axis=1)
    points = raw[:, 4:].reshape(-1, 4, 2) + anchors[keep, None, :] * DETECTOR_PX
    return _merge(boxes, scores[keep], points)


def _merge(boxes: np.ndarray, scores: np.ndarray, points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Weighted non-maximum suppression: each best remaining detection absorbs the ones overlapping it
    by more than :data:`DETECTION_IOU`, its box and points their score-weighted mean."""
    order = np.argsort(-scores, kind="stable")
    boxes, scores, points = boxes[order], scores[order], points[order]
    overlaps = box_iou(boxes, boxes) > DETECTION_IOU
    free = np.ones(len(scores), dtype=bool)
    out_boxes, out_scores, out_points = [], [], []
    for i in range(len(scores)):
        if not free[i]:
            continue
        group = free & overlaps[i]
        free &= ~group
        weights = scores[group] / scores[group].sum()
        out_boxes.append(weights @ boxes[group])
        out_points.append(np.tensordot(weights, points[group], axes=1))
        out_scores.append(scores[i])
    return (np.array(out_boxes).reshape(-1, 4), np.array(out_scores), np.array(out_points).reshape(-1, 4, 2))


@dataclass(frozen=True)
class Region:
    """A person's square region in the frame: centre (x, y) and side, pixels; ``rotation``: radians
    the body leans from upright (the region is turned by it so the model sees the body upright)."""

    centre: np.ndarray
    side: float
    rotation: float

    def to_input(self, size_px: int) -> np.ndarray:
        """The affine map ``[2, 3]`` frame pixels → model input pixels (a ``size_px`` square)."""
        scale = size_px / self.side
        cos, sin = math.cos(self.rotation), math.sin(self.rotation)
        linear = scale * np.array([[cos, sin], [-sin, cos]])
        return np.concatenate([linear, (size_px / 2.0 - linear @ self.centre)[:, None]], axis=1)

    def to_frame(self, points_px: np.ndarray, size_px: int) -> np.ndarray:
        """Model input pixels ``[..., 2]`` → frame pixels."""
        forward = self.to_input(size_px)
        return (points_px - forward[:, 2]) @ np.linalg.inv(forward[:, :2]).T

    def corners(self) -> np.ndarray:
        """The axis-aligned box around the region ``[4]`` (x1, y1, x2, y2), pixels."""
        reach = self.side / 2.0 * (abs(math.cos(self.rotation)) + abs(math.sin(self.rotation)))
        return np.concatenate([self.centre - reach, self.centre + reach])


def model_input(image: np.ndarray, scale: float, offset: float = 0.0) -> np.ndarray:
    """A model's input ``[H, W, 3]`` float32 RGB, ``image`` (uint8 BGR) × ``scale`` + ``offset``: one
    colour conversion and one float copy scaled in place (a quarter of the strided NumPy conversion's time)."""
    values = cv2.cvtColor(image, cv2.COLOR_BGR2RGB).astype(np.float32)
    values *= np.float32(scale)
    if offset:
        values += np.float32(offset)
    return values


def region_from_points(hips_xy: np.ndarray, head_xy: np.ndarray, scale: float = REGION_SCALE) -> Region:
    """The region of a body from its hips' centre and the point above its head (frame pixels):
    centred on the hips, its side ``scale`` × twice their distance, turned so hips → head points up."""
    hips_xy, head_xy = np.asarray(hips_xy, dtype=np.float64), np.asarray(head_xy, dtype=np.float64)
    dx, dy = head_xy - hips_xy
    rotation = math.pi / 2.0 - math.atan2(-dy, dx)
    rotation = (rotation + math.pi) % (2.0 * math.pi) - math.pi
    return Region(hips_xy, 2.0 * float(np.hypot(dx, dy)) * scale, rotation)


def prominence(region: Region, score: float) -> float:
    """How prominent a detected person is: the area of their region (pixels², the body's size) × the
    detector's score (0–1)."""
    return region.side ** 2 * score


def _sigmoid(x: np.ndarray) -> np.ndarray:
    return 1.0 / (1.0 + np.exp(-np.clip(x, -80.0, 80.0)))


@dataclass
class _Person:
    """One person followed: the region to look in next and the box ``[4]`` (x1, y1, x2, y2 px) the
    body was last seen in (a new detection: the middle of its region); ``followed``: the landmarks
    found it before (a new detection is not yet); ``trusted``: reported from its first landmark run
    (found by the coarse pass), else from its second (a small tile's detection, which can be a false one)."""

    region: Region
    box: np.ndarray
    followed: bool = False
    trusted: bool = False
    points: np.ndarray | None = None   # [33, 3] the landmarks of the frame before (followed people)


def _tile_starts(length_px: int, side_px: float) -> np.ndarray:
    """Starts of the fewest squares of ``side_px`` covering ``length_px`` with at least
    :data:`TILE_OVERLAP` overlap, evenly spaced (pixels)."""
    if length_px <= side_px:
        return np.array([(length_px - side_px) / 2.0])
    count = math.ceil((length_px - side_px) / (side_px * (1.0 - TILE_OVERLAP))) + 1
    return np.linspace(0.0, length_px - side_px, count)


def scan_tiles(width_px: int, height_px: int) -> tuple[np.ndarray, int]:
    """The squares the person detector scans ``[T, 3]`` (x0, y0, side; pixels) and how many of them
    make the coarse pass: the whole frame (centred, padded), squares of its shorter side, then
    squares of half that (people a few hundred pixels tall)."""
    longer, shorter = max(width_px, height_px), min(width_px, height_px)
    tiles: list[tuple[float, float, float]] = [((width_px - longer) / 2.0, (height_px - longer) / 2.0, longer)]
    counts = []
    for side in (shorter, shorter / 2.0):
        xs, ys = _tile_starts(width_px, side), _tile_starts(height_px, side)
        tiles += [(x, y, side) for y in ys for x in xs]
        counts.append(len(xs) * len(ys))
    return np.array(tiles), 1 + counts[0]


class BlazePose:
    """BlazePose on the consecutive frames of one video → :class:`~mocapdb.detect.model.Detections`
    (module docstring). ``detector_path`` and ``landmark_path``: the converted ONNX models;
    ``max_people``: the people followed at most; ``scan_every``: the detector's schedule (frames).
    ``fps`` is the rate sustained (frames per second of detection time). ``world_landmarks``: compute
    the world landmarks too (:attr:`Detections.world <mocapdb.detect.model.Detections>`; else None).
    ``threads``: each model's intra-op threads (:func:`~mocapdb.detect.model.load_session`)."""

    keypoint_layout = "mediapipe33"

    def __init__(self, detector_path: Path, landmark_path: Path, *, max_people: int | None = None,
                 scan_every: int = DEFAULT_SCAN_EVERY, name: str = "BlazePose", world_landmarks: bool = True,
                 threads: int | None = None) -> None:
        self.path = Path(landmark_path)
        self._detector = load_session(Path(detector_path), threads=threads)
        self._outputs = LANDMARK_OUTPUTS + ((WORLD_OUTPUT,) if world_landmarks else ())
        self._landmarks = load_session(self.path, self._outputs, threads=threads)
        self.world_landmarks = world_landmarks
        self.max_people, self.scan_every, self.name = max_people, scan_every, name
        self.people: list[_Person] = []
        self.frames, self.seconds, self.detector_runs, self.landmark_runs = 0, 0.0, 0, 0
        self._tiles: np.ndarray | None = None
        self._tiles_for = (0, 0)
        self._coarse = 0
        self._next_tile = 0
        self._lost = False

    @property
    def fps(self) -> float:
        """Frames per second of detection time so far (0 before the first frame)."""
        return self.frames / self.seconds if self.seconds > 0 else 0.0

    def describe(self) -> str:
        """The model and how often each part ran."""
        return (f"{self.name} (person detector {DETECTOR_PX} px on one tile every {self.scan_every} frames, on the "
                f"whole frame when someone is lost; landmarks {LANDMARK_PX} px per person); detector runs "
                f"{self.detector_runs}, landmark runs {self.landmark_runs}")

    def __call__(self, image: np.ndarray) -> Detections:
        """The people in ``image [H, W, 3]`` (uint8 BGR), the frame after the one of the last call."""
        started = time.perf_counter()
        height, width = image.shape[:2]
        if self._tiles is None or self._tiles_for != (width, height):
            (self._tiles, self._coarse), self._tiles_for = scan_tiles(width, height), (width, height)
        if self._lost or not self.people:
            self._add_people([r for tile in self._tiles[:self._coarse] for r in self.detect(image, tile)], True)
        elif self.frames % self.scan_every == 0 and not self._full:
            self._add_people(self.detect(image, self._tiles[self._next_tile % len(self._tiles)]))
            self._next_tile += 1
        found = self._follow(image)
        self.frames += 1
        self.seconds += time.perf_counter() - started
        return found

    def detect(self, image: np.ndarray, tile: np.ndarray) -> list[tuple[Region, float]]:
        """The person detector on the square ``tile`` (x0, y0, side; frame pixels) of ``image [H, W, 3]``
        (uint8 BGR; beyond its edges black) → each person's region and score (0–1), best first."""
        x0, y0, side = tile
        scale = DETECTOR_PX / side
        matrix = np.array([[scale, 0.0, -x0 * scale], [0.0, scale, -y0 * scale]])
        canvas = cv2.warpAffine(image, matrix, (DETECTOR_PX, DETECTOR_PX), flags=cv2.INTER_LINEAR,
                                borderMode=cv2.BORDER_CONSTANT, borderValue=(0, 0, 0))
        blob = model_input(canvas, 1.0 / 127.5, -1.0)[None]
        raw_boxes, raw_logits = self._detector.run(None, {self._detector.get_inputs()[0].name: blob})
        self.detector_runs += 1
        _, scores, points = decode_people(raw_boxes[0], raw_logits[0])
        points = points / scale + tile[:2]
        return [(region_from_points(p[0], p[1]), float(score)) for p, score in zip(points, scores)]

    def landmarks(self, image: np.ndarray, region: Region
                  ) -> tuple[np.ndarray, float, Region, np.ndarray | None]:
        """The landmark model in ``region`` of ``image`` (uint8 BGR): points ``[33, 3]`` (x, y frame px,
        visibility), the person flag (0–1), the region of the next frame and the world landmarks
        ``[33, 3]`` (:func:`world_from_output`; None unless computed)."""
        forward = region.to_input(LANDMARK_PX)
        crop = cv2.warpAffine(image, forward, (LANDMARK_PX, LANDMARK_PX), flags=cv2.INTER_LINEAR,
                              borderMode=cv2.BORDER_CONSTANT, borderValue=(0, 0, 0))
        blob = model_input(crop, 1.0 / 255.0)[None]
        raw, flag, *world = self._landmarks.run(list(self._outputs), {self._landmarks.get_inputs()[0].name: blob})
        self.landmark_runs += 1
        values = raw.reshape(N_OUTPUT_POINTS, 5).astype(np.float64)
        frame_xy = region.to_frame(values[:, :2], LANDMARK_PX)
        points = np.concatenate([frame_xy[:N_LANDMARKS], _sigmoid(values[:N_LANDMARKS, 3:4])], axis=1)
        following = region_from_points(frame_xy[REGION_POINTS[0]], frame_xy[REGION_POINTS[1]])
        return points, float(np.ravel(flag)[0]), following, world_from_output(world[0], region) if world else None

    @property
    def _full(self) -> bool:
        """Whether ``max_people`` are followed."""
        return self.max_people is not None and len(self.people) >= self.max_people

    def _add_people(self, found: list[tuple[Region, float]], trusted: bool = False) -> None:
        """Starts following each detected region (and its score) whose centre (the hips) is in no followed
        person's box, the best scored first (of overlapping detections from several tiles, the one the
        detector is surest of); with ``max_people``, the most prominent first, while fewer are followed."""
        rank = prominence if self.max_people is not None else (lambda _, score: score)
        found = sorted(found, key=lambda region_score: -rank(*region_score))
        for region, _ in found:
            if self._full:
                break
            boxes = np.array([p.box for p in self.people]).reshape(-1, 4)
            inside = (boxes[:, :2] <= region.centre).all(axis=1) & (region.centre <= boxes[:, 2:]).all(axis=1)
            if not inside.any():
                box = np.concatenate([region.centre - region.side / 4.0, region.centre + region.side / 4.0])
                self.people.append(_Person(region, box, trusted=trusted))

    def _follow(self, image: np.ndarray) -> Detections:
        """One landmark run per followed person; the lost ones (a low flag; for a new detection also
        landmarks spanning less than :data:`MIN_FILL` of its region: not a body) and duplicates are
        dropped; the people reported: the ones followed before and the trusted new ones."""
        points, worlds, flags, regions, reported, lost = [], [], [], [], [], False
        for person in self.people:
            landmarks, flag, following, world = self.landmarks(image, person.region)
            if person.points is not None:
                order = side_order(landmarks, person.points)
                landmarks, world = landmarks[order], None if world is None else world[order]
            span = np.ptp(landmarks[:, :2], axis=0).max()
            if flag >= PRESENCE and (person.followed or span >= MIN_FILL * person.region.side):
                points.append(landmarks)
                worlds.append(world)
                flags.append(flag)
                regions.append(following)
                reported.append(person.followed or person.trusted)
            else:
                lost |= person.followed   # a new detection that is no body is not someone lost
        self._lost = lost
        keypoints = np.array(points).reshape(-1, N_LANDMARKS, 3)
        boxes = np.concatenate([keypoints[:, :, :2].min(axis=1), keypoints[:, :, :2].max(axis=1)], axis=1)
        unique = _distinct(boxes, np.array(flags))
        self.people = [_Person(regions[i], boxes[i], True, points=keypoints[i]) for i in unique]
        shown = unique[np.array(reported, dtype=bool)[unique]] if len(unique) else unique
        world = np.array(worlds).reshape(-1, N_LANDMARKS, 3)[shown] if self.world_landmarks else None
        return Detections(boxes[shown], np.array(flags)[shown], keypoints[shown], world)


def world_from_output(raw: np.ndarray, region: Region) -> np.ndarray:
    """The landmark model's world output (``[1, 117]``: 39 points' x, y, z in metres, in the crop's
    axes, origin at the hips' centre) → the 33 landmarks ``[33, 3]`` in the frame's axes: x, y turned
    by the region's rotation (as MediaPipe's ``WorldLandmarkProjectionCalculator``), so x points right
    and y down along the image's axes; z (away from the camera) unchanged."""
    values = np.asarray(raw, dtype=np.float64).reshape(N_OUTPUT_POINTS, 3)[:N_LANDMARKS]
    cos, sin = math.cos(region.rotation), math.sin(region.rotation)
    turned = values.copy()
    turned[:, 0] = cos * values[:, 0] - sin * values[:, 1]
    turned[:, 1] = sin * values[:, 0] + cos * values[:, 1]
    return turned


def _mirror_order() -> np.ndarray:
    """Each mediapipe33 landmark's index in the mirror image (left ↔ right; the nose stays)."""
    names = LAYOUTS["mediapipe33"]
    swap = {"left": "right", "right": "left"}
    mirrored = [n.replace(n.split("_")[0], swap[n.split("_")[0]], 1) if n.split("_")[0] in swap else
                n.replace("_left", "_right") if n.endswith("_left") else
                n.replace("_right", "_left") if n.endswith("_right") else n for n in names]
    return np.array([names.index(m) for m in mirrored])


MIRROR = _mirror_order()
SIDED = np.flatnonzero(MIRROR != np.arange(len(MIRROR)))   # the landmarks that have a mirror twin
SWAP_RATIO = 0.5   # the sides are swapped back when the swapped landmarks lie this much closer to the last frame's


def keep_sides(points: np.ndarray, previous: np.ndarray) -> np.ndarray:
    """``points [33, 3]`` with left and right exchanged when the model swapped them since ``previous``
    (a body seen from behind is often read as facing the camera): the swapped landmarks' median
    distance from the frame before is under :data:`SWAP_RATIO` of the unswapped ones'."""
    order = side_order(points, previous)
    return points if order is IDENTITY else points[order]


IDENTITY = np.arange(len(MIRROR))


def side_order(points: np.ndarray, previous: np.ndarray) -> np.ndarray:
    """The order putting ``points [33, ≥2]`` on the sides of ``previous`` (:func:`keep_sides`):
    :data:`MIRROR` when the model swapped them, else :data:`IDENTITY` (the same for the world landmarks)."""
    same = np.median(np.linalg.norm(points[SIDED, :2] - previous[SIDED, :2], axis=1))
    swapped = np.median(np.linalg.norm(points[MIRROR[SIDED], :2] - previous[SIDED, :2], axis=1))
    return MIRROR if swapped < SWAP_RATIO * same else IDENTITY


def _share_of_smaller(boxes: np.ndarray) -> np.ndarray:
    """``[P, P]``: the share of the smaller of each two boxes (x1, y1, x2, y2) that lies in the other."""
    area = np.maximum(box_area(boxes), 1e-9)
    return box_intersection(boxes, boxes) / np.minimum(area[:, None], area[None, :])


def _distinct(boxes: np.ndarray, scores: np.ndarray) -> np.ndarray:
    """Indices of the people kept when two followed regions drifted onto one body (more than
    :data:`SAME_PERSON_SHARE` of the smaller box inside the other): the better flag stays; order kept."""
    overlaps = _share_of_smaller(boxes) > SAME_PERSON_SHARE
    keep = np.ones(len(scores), dtype=bool)
    for i in np.argsort(-scores, kind="stable"):
        if keep[i]:
            drop = overlaps[i].copy()
            drop[i] = False
            keep &= ~drop
    return np.flatnonzero(keep)
