"""The EKF-SLAM of Vallicrosa et al. 2021 and dead reckoning."""
