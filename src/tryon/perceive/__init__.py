"""Perception: people in photos (`person`: mask and keypoints by MediaPipe BlazePose)."""
