"""Blue-teaming: PPO fine-tuning of a red-teamed policy on its CrashShapes (``python -m grt.blueteam``)."""
