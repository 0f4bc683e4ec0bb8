"""Old name of :mod:`grt.evaluators`, kept so that run folders written before the rename (their
``.hydra/config.yaml`` names ``grt.eval.evaluator.SimEvaluator``) still resume and blue-team."""
