"""Perception: pure functions of images and the rig (detectors behind adapters)."""
