"""Object recognition from CAD models (Himri et al. 2018; Vallicrosa et al. 2021).

A segmented object cloud (sensor frame, metres) becomes a class likelihood vector P(Z | X):

- ``esf.py``, ``vfh.py``, ``cvfh.py`` — global descriptors (ESF 640 bins, VFH 308, CVFH one VFH
  per stable smooth region), vectorised numpy re-implementations of PCL's, deviations documented;
  ``normals.py`` — normals and curvature.
- ``views.py`` — the view database: partial views of every CAD model rendered by a virtual laser
  (Open3D ``RaycastingScene``), described once and cached by content hash; ``add_model`` makes a
  user's STL/OBJ/PLY recognisable.
- ``matching.py`` — chi-square nearest neighbour, RBF SVM (``svm.py``: scikit-learn, imported only
  when an SVM is made), leave-one-out, and a metric size cue (principal extents).
- ``recognizer.py`` — :class:`Recognizer` (``classify(cloud, connectivity) -> dict[str, float]``,
  ``classify_many`` for a scan's segments together,
  ``recognise``, ``pose``, ``calibrate``) and :func:`default_recognizer` (built-in library + user
  models, SYN confusion cached); ``config.py`` — its configuration section.
- ``pose.py`` — 6-DoF pose by ICP against the recognised model.

Fusion of the likelihoods per landmark, the connectivity constraints and the recognition metrics
live in :mod:`semslam.semantics` (no front-end imports there).
"""
