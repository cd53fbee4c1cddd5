"""GTSAM factors for underwater semantic SLAM (DVL, AHRS, depth, object point, pipe line, structure).

This package knows only gtsam and numpy.
"""
