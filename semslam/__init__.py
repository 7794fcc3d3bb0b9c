"""semslam: semantic SLAM for parking garages.

Maps slot corners with their painted IDs, fiducial tags and painted line
markings from a drive, and localizes a vehicle against that map.
"""

__version__ = "0.1.0"
