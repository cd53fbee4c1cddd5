"""Test scaffolding, importable by the tests and the experiments (from the repository root):
small synthetic missions with ground truth and reference implementations the production code is
checked against. Nothing in ``semslam``, ``factors`` or ``frontends`` imports it."""
