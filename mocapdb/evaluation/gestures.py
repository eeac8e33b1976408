"""Hand gestures from finger flexion angles, for evaluating the hand landmarks (not used at run time).

A finger (index to pinky) is **straight** when its curl (the sum of its MCP, PIP and DIP flexions,
:func:`mocapdb.core.fingers.curl_deg`) is below :data:`STRAIGHT_DEG` and **curled** above
:data:`CURLED_DEG`; the thumb is **out** when its curl (CMC + MCP + IP) is below :data:`THUMB_OUT_DEG`.
The thresholds sit in the gaps measured on MediaPipe's own test photos (``tools/eval_fingers.py``):
straight fingers 6–37°, curled ones 150–260°; a thumb held out 27–72°, one folded into the palm or
round a fist 100–145°.

| gesture | rule |
|---|---|
| ``fist`` | four fingers curled, thumb not out |
| ``thumb_up`` / ``thumb_down`` | four fingers curled, thumb out, its MCP → tip within 60° of the image's up / down |
| ``pointing`` | index straight, middle, ring and pinky curled |
| ``open_palm`` | four fingers straight (the thumb either way) |
| ``other`` | anything else |
"""
from __future__ import annotations

import numpy as np

from mocapdb.core.fingers import curl_deg, flexion_deg

STRAIGHT_DEG = 60.0     # a finger whose curl is below this is straight
CURLED_DEG = 120.0      # a finger whose curl is above this is curled
THUMB_OUT_DEG = 85.0    # a thumb whose curl is below this is held out
THUMB_CONE_DEG = 60.0   # thumb up/down: its MCP → tip direction within this of the image's vertical
GESTURES = ("fist", "thumb_up", "thumb_down", "pointing", "open_palm", "other")


def thumb_vertical_deg(points: np.ndarray) -> float:
    """The angle between the thumb's MCP → tip (points 2 → 4, image x right, y down) and the image's up
    (degrees; 0: straight up, 180: straight down)."""
    direction = np.asarray(points, dtype=np.float64)[4, :2] - np.asarray(points, dtype=np.float64)[2, :2]
    return float(np.degrees(np.arctan2(abs(direction[0]), -direction[1])))


def classify(points: np.ndarray) -> str:
    """The gesture (:data:`GESTURES`) of one hand's ``points [21, 3]`` (x, y image px, z depth in px)."""
    curls = curl_deg(flexion_deg(points))
    thumb, fingers = curls[0], curls[1:]
    if (fingers > CURLED_DEG).all():
        if thumb >= THUMB_OUT_DEG:
            return "fist"
        vertical = thumb_vertical_deg(points)
        if vertical <= THUMB_CONE_DEG:
            return "thumb_up"
        return "thumb_down" if vertical >= 180.0 - THUMB_CONE_DEG else "other"
    if fingers[0] < STRAIGHT_DEG and (fingers[1:] > CURLED_DEG).all():
        return "pointing"
    if (fingers < STRAIGHT_DEG).all():
        return "open_palm"
    return "other"


CLOSE_UP_ROUNDS = 3   # a photo with no body: the hand model on the whole image, then on its own points' crop this often


def photo_hands(image: np.ndarray, pose_paths: tuple, hand_path) -> list[tuple[str, np.ndarray, float]]:
    """The hands found in one photo ``image`` (uint8 BGR): ``(label, points [21, 3], presence)`` each.
    BlazePose finds the people and each hand is cropped from the pose (``label``: ``person<i>_<side>``);
    a photo without a body (a close-up of a hand) gets the hand model on the whole image, then
    :data:`CLOSE_UP_ROUNDS` times on the crop around the points it found (``label``: ``close-up``)."""
    from mocapdb.detect.blazepose import BlazePose, Region
    from mocapdb.detect.hands import MIN_PRESENCE, SIDES, HandLandmarker, region_from_hand
    from mocapdb.detect.with_landmarks import WithLandmarks

    detector = WithLandmarks(BlazePose(*pose_paths), hands=HandLandmarker(hand_path))
    found = detector(image)
    if len(found.scores):
        return [(f"person{p}_{side}", found.hands.points[p, s, :, :3], float(found.hands.presence[p, s]))
                for p in range(len(found.scores)) for s, side in enumerate(SIDES) if not found.hands.absent[p][s]]
    height, width = image.shape[:2]
    region = Region(np.array([width / 2.0, height / 2.0]), float(max(width, height)), 0.0)
    model = HandLandmarker(hand_path)
    for _ in range(CLOSE_UP_ROUNDS + 1):
        points, presence, _ = model.landmarks(image, region)
        region = region_from_hand(points)
    return [("close-up", points, presence)] if presence >= MIN_PRESENCE else []
