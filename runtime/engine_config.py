"""The engine's parameters: :class:`EngineConfig` (search, choice, refinement, filters, camera,
tracking) and :class:`TrackLimits` (the tracking work a stream can cause), each number checked
against its domain (:mod:`mocapdb.core.domains`)."""
from __future__ import annotations

from dataclasses import dataclass, field, replace

from mocapdb.core import domains as D
from mocapdb.core.formats.keypoints import CONFIDENCE_THRESHOLD
from mocapdb.runtime.filters import (
    REFINED_ROOT_DEFAULTS,
    REFINED_ROTATION_DEFAULTS,
    ROOT_DEFAULTS,
    KeypointFilterParams,
    OneEuroParams,
)
from mocapdb.runtime.refine import RefineParams
from mocapdb.runtime.tracker import TrackerConfig


@dataclass(frozen=True)
class TrackLimits:
    """Bounds on the tracking work a stream can cause (0: no limit; data_specs/stream_output.md).

    ``max_tracks``: tracks alive at once, tentative ones included; a further detection starts none.
    ``max_new_per_min``: tracks confirmed in any 60 s (of :meth:`Engine.step`'s ``now_s``); a
    further one waits unconfirmed, without output. Detections held back are counted in
    :class:`EngineStats`.
    """

    max_tracks: int = D.MAX_TRACKS.default
    max_new_per_min: int = D.MAX_NEW_TRACKS_PER_MIN.default

    def __post_init__(self) -> None:
        D.MAX_TRACKS.check(self.max_tracks, "max_tracks")
        D.MAX_NEW_TRACKS_PER_MIN.check(self.max_new_per_min, "max_new_per_min")


@dataclass
class EngineConfig:
    """Runtime parameters (defaults: the method's j=10, w=4; i=5 on its K = 500 clusters, more for more clusters)."""

    search: str = "clustered"            # "clustered" (the method) or "exact" (brute force)
    n_clusters: int | None = None        # i: clusters searched; None: search_rules.clusters_searched_for(K)
    per_cluster: int = D.PER_CLUSTER.default  # j: projections taken from each
    grid_descents: int = D.GRID_DESCENTS.default  # best candidates moved to better grid neighbours (0: none)
    subclusters: int | None = None       # sub-clusters searched per cluster; None: search_rules' for the size
    window_weights: tuple[float, ...] = D.WINDOW_WEIGHTS.default  # w = 4, most recent first
    joint_weights: tuple[float, ...] | None = None            # per rig joint; default all 1
    weight_2d: float = D.WEIGHT_2D.default               # added to Eq. 2: this × the candidate's Eq. 1 distance
    world_prior: float = 10.0            # added too (refining): this × the candidate's disagreement with the
                                         # detector's world landmarks, when given (world/detector_prior.py); 0: not used
    confidence_threshold: float = CONFIDENCE_THRESHOLD
    min_joints: int = 6                  # fewer confident joints: the person is skipped
    focal_px: float = 1000.0             # input camera focal length, pixels
    image_size: tuple[int, int] = (1920, 1080)  # input image width, height in pixels
    fps: float = D.INPUT_FPS_HZ.default  # frame rate assumed when frames carry no time
    max_gap_s: float = 1.0               # a longer jump in time (or frame number / fps) ends every track
    translation: bool = True             # estimate the root translation from the image
    refine_yaw: bool = True              # refine the matched yaw between the database's yaws
    upright_search: bool = True          # search the keypoints turned upright by the track's roll estimate
    refine: bool = True                  # 2D refinement after retrieval (False: the method as published)
    refinement: RefineParams = field(default_factory=RefineParams)
    own_body: bool = True                # estimate each track's bone proportions from its 2D (needs refine)
    keep_take: bool = False              # recordings keep the per-frame fits and keypoints (whole-take fit)
    subject_height_m: float | None = None  # the person's height; None: the universal 1.75 m (or from the floor)
    camera_height_m: float | None = None   # camera above a flat floor: metric depth and size from the feet
    smoothing: bool = True
    rotation_filter: OneEuroParams | None = None  # None: the defaults for refined or retrieved poses
    keypoint_filter: KeypointFilterParams | None = None  # 2D clean-up; None: on when refining
    root_filter: OneEuroParams | None = None
    tracker: TrackerConfig = field(default_factory=TrackerConfig)
    limits: TrackLimits = field(default_factory=TrackLimits)  # read at every step: may be replaced

    def __post_init__(self) -> None:
        if self.search not in ("clustered", "exact"):
            raise ValueError(f"search must be 'clustered' or 'exact', not {self.search!r}")
        self.rotation_filter, self.root_filter = self.one_euro_params()
        if self.keypoint_filter is None and self.refine and self.smoothing:
            self.keypoint_filter = KeypointFilterParams()
        self._check_domains()
        if self.camera_height_m is not None and not self.refine:
            raise ValueError("a camera height needs the refinement (it levels the floor): drop --no-refine")

    def one_euro_params(self) -> tuple[OneEuroParams, OneEuroParams]:
        """The 1€ parameters of the rotations and of the root: as given, else the defaults for
        refined or retrieved poses (``__post_init__`` fills the fields with them)."""
        rotation = self.rotation_filter
        if rotation is None:
            rotation = REFINED_ROTATION_DEFAULTS if self.refine else OneEuroParams()
        root = self.root_filter
        if root is None:
            root = REFINED_ROOT_DEFAULTS if self.refine else ROOT_DEFAULTS
        return rotation, root

    def for_track_files(self) -> EngineConfig:
        """This configuration as ``reconstruct`` and ``live`` run it for their track files: the
        per-frame fits kept (``keep_take``) and not smoothed, neither the keypoints nor the rotations
        (the online and whole takes smooth them)."""
        return replace(self, keep_take=True, smoothing=False, keypoint_filter=None)

    @property
    def center_px(self) -> tuple[float, float]:
        """The image's centre (pixels), taken as the camera's principal point."""
        return self.image_size[0] / 2.0, self.image_size[1] / 2.0

    def _check_domains(self) -> None:
        """Every number given within its domain (:mod:`mocapdb.core.domains`), DomainError otherwise."""
        D.CLUSTERS_SEARCHED.check_optional(self.n_clusters, "n_clusters")
        D.PER_CLUSTER.check(self.per_cluster, "per_cluster")
        D.GRID_DESCENTS.check(self.grid_descents, "grid_descents")
        D.SUBCLUSTERS_SEARCHED.check_optional(self.subclusters, "subclusters")
        D.WINDOW_WEIGHTS.check(self.window_weights, "window_weights")
        D.WEIGHT_2D.check(self.weight_2d, "weight_2d")
        D.WEIGHT_2D.check(self.world_prior, "world_prior")
        D.FOCAL_PX.check(self.focal_px, "focal_px")
        for side in self.image_size:
            D.IMAGE_SIDE_PX.check(side, "image_size")
        D.FPS_HZ.check(self.fps, "fps")
        D.SUBJECT_HEIGHT_M.check_optional(self.subject_height_m, "subject_height_m")
        D.CAMERA_HEIGHT_M.check_optional(self.camera_height_m, "camera_height_m")
