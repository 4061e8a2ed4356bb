"""The starting point: closed-form geometry on marker trajectories, which marker rides on which segment (seed 002),
MTB joint-centre estimation (seed 000)."""
