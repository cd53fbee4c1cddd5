"""Simulated missions with ground truth: scenes, trajectories, sensor models."""
