"""Online localization against a semantic map (no gtsam here)."""
