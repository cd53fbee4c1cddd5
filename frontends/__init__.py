"""Sensor front-ends (laser, sonar, odometry, oracle), found by semslam through the
``semslam.frontends`` entry-point group. Front-ends never touch GTSAM."""
