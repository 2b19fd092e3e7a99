"""Physics-alignment evaluation: the benchmark runner and its reports (metrics: `cosmos_lite.core.metrics`).

`run_physics_eval(cfg) -> results` is imported from `cosmos_lite.eval.physics` (it needs torch and the models).
"""
