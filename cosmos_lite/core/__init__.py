"""The floor under tokenizers, models, guardrails and eval: the training engine, the video-window dataset,
frame <-> tensor conversion, LoRA and the metrics."""
