"""The real-time engine: 2D keypoints in, retrieved 3D skeletons and BVH out (see issue 3)."""
