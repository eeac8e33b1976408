"""From video to 2D keypoints: `mocapdb detect` and the video input of `mocapdb live`.

A video file or a camera is decoded with OpenCV, an ONNX pose model (YOLO-pose or RTMO export) runs
on each frame with onnxruntime (CPU), and the people found are written as one OpenPose
``--write_json`` file per frame in the COCO-18 layout (or handed to the live engine by
``mocapdb.runtime.stream.video_input``). Modules, each imported on its own (this package imports nothing,
so the command-line parser stays fast):

- :mod:`mocapdb.detect.options`: the defaults the command-line parser shows (light);
- :mod:`mocapdb.detect.errors`: :class:`~mocapdb.detect.errors.DetectError`;
- :mod:`mocapdb.detect.model`: pre- and post-processing (letterbox, NMS, model layouts) and
  :class:`~mocapdb.detect.model.PoseModel`;
- :mod:`mocapdb.detect.video`: :class:`~mocapdb.detect.video.VideoReader`, decoded frames;
- :mod:`mocapdb.detect.tracked`: :class:`~mocapdb.detect.tracked.TrackedDetector`, the model on
  crops around the people of the frame before, the whole frame now and then, optical flow between
  (what both `detect` and `live --model` run);
- :mod:`mocapdb.detect.openpose_out`: the OpenPose JSON files and the detect loop
  (:func:`~mocapdb.detect.openpose_out.detect_video`).

Layouts, pre-processing and the files written: ``data_specs/pose_models.md``.
"""
