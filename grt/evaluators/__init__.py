"""Evaluation: candidate meshes -> collision parts -> simulated trials -> a score per candidate."""
