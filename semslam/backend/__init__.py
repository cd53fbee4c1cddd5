"""Graph back-end: iSAM2 online and batch estimation, keyframes, data association, landmarks."""
