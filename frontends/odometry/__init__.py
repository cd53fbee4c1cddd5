"""The odometry front-end."""
