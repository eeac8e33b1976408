"""Defaults of the pose detector (light: the command-line parser reads them)."""

DEFAULT_CONF = 0.25        # a person is kept when its model score is at least this
DEFAULT_IOU = 0.65         # NMS drops a person whose box overlaps a better one's by more than this IoU
DEFAULT_INPUT_SIZE = 640   # model input side in pixels when the export leaves it dynamic
DEFAULT_CROP_PX = 256      # largest model input side in pixels for a person crop (dynamic exports)
DEFAULT_FULL_EVERY = 30    # following people in crops, the whole frame is searched at least every this many frames
DETECTORS = ("full", "crops")   # the model on every whole frame; or on crops around the people followed
BLAZEPOSE_VARIANTS = ("lite", "full", "heavy")   # landmark models; the person detector is shared
DEFAULT_BLAZEPOSE = "full"
FETCH_COMMAND = "mocapdb models fetch"          # prepares the BlazePose models (mocapdb.detect.model_store)
HANDS = "hands"   # `mocapdb models fetch hands` also prepares the hand landmark models (detect/live --hands)
HAND_MODELS = ("full", "lite")   # MediaPipe's hand landmark models (`--hand-model`), both from `models fetch hands`
DEFAULT_HAND_MODEL = "full"      # lite: half the CPU a hand, but finds fewer small hands (data_specs/pose_models.md)
FACE = "face"     # `mocapdb models fetch face` also prepares the face landmark model (detect --face)
