"""The real-time engine: 2D keypoints in, retrieved 3D skeletons and BVH out (docs/guide_video.md)."""
