"""Robustness profiles (``python -m grt.profile``): how much shape change breaks a policy.

:mod:`grt.profile.shapes` makes deformations of a given size (the largest surface displacement, mm), random or
along a CrashShape's direction; :mod:`grt.profile.measure` scores them on fresh episodes and computes the random
and adversarial margins; :mod:`grt.profile.command` is the command's work (a run folder or an object, the
checks, the files); :mod:`grt.profile.plot` draws ``profile.png``.
"""

#: The files of a profile's folder (``RUN/profile/<time>/`` with a run).
PROFILE_JSON, PROFILE_PNG, PROFILE_JOURNAL = "profile.json", "profile.png", "profile.jsonl"
