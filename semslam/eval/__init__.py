"""Evaluation: metrics, figures, reports."""
