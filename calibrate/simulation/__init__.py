"""Synthetic trials with a known truth: squats, gait, overhead motion, soft-tissue artefact; seed 000's synthetic
chains."""
