"""Benchmarks: ``python -m grt.bench {deform,grasp}``; each prints figures, last line one JSON object."""
