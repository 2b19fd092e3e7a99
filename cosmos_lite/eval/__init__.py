"""Physics-alignment evaluation: metrics (the one home of every metric), the benchmark runner and its reports.

`run_physics_eval(cfg) -> results` is imported from `cosmos_lite.eval.physics` (it needs torch and the models).
"""
