#!/usr/bin/env bash
# Set everything up on a fresh machine and run the main job on the bundled sample data.
set -euo pipefail
cd "$(dirname "$0")/.."
bash tools/setup.sh
mkdir -p demo
.venv/bin/mocapdb build data/sample_bvh --out demo/sample.db
# Camera 1 of the bundled take as the built-in detector saw it (2D and its own 3D; data/sample_keypoints).
.venv/bin/mocapdb reconstruct data/sample_keypoints/blazepose_cam01 --db demo/sample.db \
    --out demo/reconstruction --preview
# Two of the same take's cameras, no extrinsics used: 3D motion, both cameras and a BVH.
.venv/bin/mocapdb stereo data/sample_keypoints/pose2sim_cam01 data/sample_keypoints/pose2sim_cam04 \
    --calibration data/sample_keypoints/calibration.toml --cameras cam_01 cam_04 \
    --camera-distance 5.24 --out demo/stereo
