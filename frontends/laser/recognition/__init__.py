"""Object recognition from CAD models: global descriptors (ESF, VFH, CVFH), a view database
rendered from CAD meshes, nearest-neighbour / SVM matching, ICP pose, and the ``Recognizer`` that
turns a segmented object cloud into a class likelihood vector P(Z | X)."""
