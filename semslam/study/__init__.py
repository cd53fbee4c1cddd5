"""Many missions as Dask tasks: `semslam study` (simulated worlds over seeds, or a campaign of bags).

One module per job:

- :mod:`~semslam.study.plan` — the missions as plain data (:class:`~semslam.study.plan.MissionTask`):
  seeds, bags, configurations resolved and validated on the client;
- :mod:`~semslam.study.task` — the Dask task: one mission in a child process, with its timeout;
- :mod:`~semslam.study.compute` — that child: simulate (if needed) and compare, as the commands do;
- :mod:`~semslam.study.store` — the study folder: staging and renaming, records, failures, lock;
- :mod:`~semslam.study.cluster` — a client on a LocalCluster or the user's scheduler; results as they come;
- :mod:`~semslam.study.summary`, :mod:`~semslam.study.stats` — what a study keeps of each mission,
  distributions and paired ratios with bootstrap confidence intervals;
- :mod:`~semslam.study.output`, :mod:`~semslam.study.report` — ``study.json`` and ``report.html``;
- :mod:`~semslam.study.run` — :func:`~semslam.study.run.run_study`, which ties them together.

Nothing here is imported by estimation, evaluation or mission I/O; the study imports the simulator
(to resolve a scenario's configuration) and the comparison (inside each mission's process).
"""
