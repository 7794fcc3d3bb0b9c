"""The seeded garage simulator: worlds, drives, sensors and rendered images."""
