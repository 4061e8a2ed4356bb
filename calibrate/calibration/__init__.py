"""The pipeline (seed, start, solve, outliers, learnt noise), its result, and the report."""
