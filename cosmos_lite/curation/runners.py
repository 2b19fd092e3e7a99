"""Stages and the two runners that execute them: sequential in-process, or Ray actors.

A stage declares its resources, loads models once in `setup`, and maps a batch of items to a
batch of results. The local runner calls it in a loop; the Ray runner starts `workers` actors
(each set up once; a worker that dies is restarted and its task retried) and streams results
back in completion order, so a long job never holds more than one video per worker in memory.
An item whose worker dies on every try goes to the stage's `failed` hook, and the job goes on.
"""

from __future__ import annotations

import os
from abc import ABC, abstractmethod
from collections.abc import Iterable, Iterator
from typing import Any

from ..log import get_logger

log = get_logger("curation.runners")


class Stage(ABC):
    """One step of a pipeline: `resources` (Ray num_cpus/num_gpus per worker), `setup()`, `process(batch)`."""

    resources: dict[str, float] = {"num_cpus": 1, "num_gpus": 0}

    def setup(self) -> None:  # noqa: B027 - an optional hook, not every stage loads something
        """Load models and other per-worker state (called once per worker)."""

    @abstractmethod
    def process(self, batch: list[Any]) -> list[Any]:
        """Turn a batch of items into a batch of results."""

    def failed(self, item: Any, error: Exception) -> list[Any]:
        """Results for an item whose worker died on every try (a crash in native code, out of memory)."""
        raise error


def run_local(stage: Stage, items: Iterable[Any]) -> Iterator[Any]:
    """Run `stage` over `items` one at a time in this process."""
    stage.setup()
    for item in items:
        yield from stage.process([item])


def limit_threads(num_cpus: float, rank: int | None = None) -> None:
    """Make this process use about `num_cpus` cores; with `rank`, pin it to its own cores.

    FFmpeg's and x264's automatic thread counts follow the CPU affinity, so pinning is what keeps
    two workers on a 2-core machine from each starting two encoder threads. Torch (TransNetV2 only)
    takes its thread count from OMP_NUM_THREADS when first imported; importing it here would cost
    every worker ~2 CPU-seconds at start.
    """
    import cv2

    n = max(1, int(num_cpus))
    os.environ["OMP_NUM_THREADS"] = str(n)
    cv2.setNumThreads(n)
    if rank is not None and hasattr(os, "sched_setaffinity"):
        cpus = sorted(os.sched_getaffinity(0))
        first = (rank * n) % len(cpus)
        os.sched_setaffinity(0, {cpus[(first + k) % len(cpus)] for k in range(min(n, len(cpus)))})


class _Worker:
    """Ray actor body: holds one set-up stage."""

    def __init__(self, stage: Stage, num_cpus: float, rank: int | None):
        limit_threads(num_cpus, rank)
        self.stage = stage
        self.stage.setup()

    def process(self, batch: list[Any]) -> list[Any]:
        return self.stage.process(batch)


def run_ray(stage: Stage, items: list[Any], workers: int, ray_cfg) -> Iterator[Any]:
    """Run `stage` on `workers` Ray actors (one item per task), yielding results as they finish.

    ray_cfg: `address` (None starts a local Ray without dashboard and shuts it down after),
    `num_cpus` per worker, `max_retries` (per task; a dead worker is always restarted), `pin_cpus`.
    """
    os.environ.setdefault("RAY_AUTH_MODE", "disabled")
    import ray

    started = not ray.is_initialized()
    if started:
        local = ray_cfg.address is None
        ray.init(
            address=ray_cfg.address,
            include_dashboard=False,
            num_cpus=max(os.cpu_count() or 1, workers * ray_cfg.num_cpus) if local else None,
            log_to_driver=False,
            configure_logging=False,
        )
    try:
        resources = {"num_cpus": ray_cfg.num_cpus, "num_gpus": stage.resources.get("num_gpus", 0)}
        actor = ray.remote(**resources, max_restarts=-1, max_task_retries=ray_cfg.max_retries)(_Worker)
        pin = ray_cfg.pin_cpus and ray_cfg.address is None
        idle = [actor.remote(stage, ray_cfg.num_cpus, r if pin else None) for r in range(max(1, workers))]
        todo, running = list(reversed(items)), {}  # task -> (actor, item)
        while todo or running:
            while idle and todo:
                a, item = idle.pop(), todo.pop()
                running[a.process.remote([item])] = (a, item)
            (task,), _ = ray.wait(list(running), num_returns=1)
            a, item = running.pop(task)
            idle.append(a)
            try:
                results = ray.get(task)
            except ray.exceptions.RayActorError as e:
                log.warning("a worker died on every try of %s: %s", item, e)
                results = stage.failed(item, e)
            yield from results
    finally:
        if started:
            ray.shutdown()
