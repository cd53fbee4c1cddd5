"""What both estimators share to build their map: association (JCBB), tentative tracks and promotion,
pipe extents, duplicate merging, class fusion with connectivity. Each estimator keeps only its own
state, prediction, update and marginalisation."""
