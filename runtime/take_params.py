"""The whole-take fit's settings (:class:`TakeParams`): smoothing, contacts, the root path, the
floor, the re-fit (what each does: :mod:`mocapdb.runtime.take`)."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mocapdb.core import domains as D


@dataclass(frozen=True)
class TakeParams:
    """Whole-take fit settings (see the module docstring); lengths in metres, times in seconds."""

    smoothing_hz: float = D.SMOOTHING_HZ.default          # zero-phase cut-off of the rotations; 0: not smoothed
    pop_frames: int = 5                # running-median window (frames; 1: no pop removal)
    planted_box_per_s: float = 0.25    # image speed of a planted ankle keypoint, box heights per second
    planted_height_m: float = 0.05     # a planted ankle is at most this much above the other
    carrying_box_per_s: float = 0.5    # ... up to this image speed when the other foot is off the floor
    root_across_m: float = 0.01        # root across the viewing ray: the image's precision
    root_depth_m: float = 0.15         # root along the viewing ray: the depth's
    root_accel_mps2: float = 4.0       # root acceleration SD
    contact_m: float = 0.005           # a planted ankle's spread over its contact, across the viewing ray
    contact_depth_m: float = 0.05      # ... and along it (the pose's depth of the legs)
    floor: bool = True                 # keep ankles above the floor found from the contacts
    refit_prior: float = 20.0          # the re-fit's pull to the smoothed pose, × the per-frame fit's (0: none)

    def __post_init__(self) -> None:
        D.SMOOTHING_HZ.check(self.smoothing_hz, "smoothing_hz")
        positive = (self.planted_box_per_s, self.carrying_box_per_s, self.planted_height_m, self.root_across_m,
                    self.root_depth_m, self.root_accel_mps2, self.contact_m, self.contact_depth_m)
        if self.pop_frames < 1 or not all(np.isfinite(v) and v > 0 for v in positive) \
                or not (np.isfinite(self.refit_prior) and self.refit_prior >= 0):
            raise ValueError(f"whole-take settings out of range: {self}")
        if self.carrying_box_per_s < self.planted_box_per_s:
            raise ValueError(f"carrying_box_per_s {self.carrying_box_per_s} is below planted_box_per_s "
                             f"{self.planted_box_per_s}: a foot carrying the body is planted at least as readily")
