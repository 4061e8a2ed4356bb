"""Solvers: Levenberg-Marquardt with the Schur complement over frames, its compiled per-frame kernels, frame-wise
inverse kinematics."""
