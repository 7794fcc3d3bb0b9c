"""Offline mapping: the GTSAM factor graph (gtsam is imported only inside this package)."""
