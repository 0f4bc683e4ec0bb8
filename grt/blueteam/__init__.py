"""Blue-teaming: PPO fine-tuning of a red-teamed policy on its CrashShapes (``python -m grt.blueteam``).

:mod:`grt.blueteam.study` runs one study (:func:`~grt.blueteam.study.blueteam`), :mod:`grt.blueteam.finetune`
the fine-tune, :mod:`grt.blueteam.guard` its validation (:class:`~grt.blueteam.guard.NominalGuard`),
:mod:`grt.blueteam.core` the pieces they share (the run's geometry, CrashShape choice, the guard's test,
Table 3), and :mod:`grt.blueteam.spec` the study's settings (:class:`~grt.blueteam.spec.StudySpec`).
"""
