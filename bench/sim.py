"""Simulator throughput on one core: episodes/s and frames/s at 64x64 and 256x256, physics vs rendering share.

Also episodes/s including write_episode (H.264 encode). Baseline, same run: the same states drawn with
PIL.ImageDraw (C rasteriser, one call per shape) into the same id map and palette lookup; the ratio is
ours / PIL render frames/s. Target: >= 2,000 frames/s end to end at 64x64. Frames per CPU-second are printed
too: other jobs sharing the core lower frames/s, much less frames per CPU-second.

    .venv/bin/python bench/sim.py [--episodes 4] [--frames 33]
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time

os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np  # noqa: E402
from PIL import Image, ImageDraw  # noqa: E402

from cosmos_lite.sim import SCENARIOS, simulate, write_episode  # noqa: E402
from cosmos_lite.sim.render import box_corners, palette, render, rod_corners  # noqa: E402
from cosmos_lite.sim.scenarios import BUILDERS, WORLD_H, sample_params, step  # noqa: E402


def pil_render(scene, states: np.ndarray, size: tuple[int, int], scale: float, background) -> np.ndarray:
    """Baseline: PIL draws each shape into an 'L' id image per frame; same palette lookup as ours."""
    h, w = size
    scenery = len(scene.bodies) + 1
    base = Image.new("L", (w, h), 0)
    for poly in scene.static:
        ImageDraw.Draw(base).polygon([tuple(p) for p in np.asarray(poly) * scale], fill=scenery)
    labels = np.empty((len(states), h, w), np.uint8)
    for t in range(len(states)):
        img = base.copy()
        draw = ImageDraw.Draw(img)
        for pivot, i, width in scene.rods:
            quad = rod_corners(np.multiply(pivot, scale), states[t, i, :2] * scale, width * scale)
            draw.polygon([tuple(p) for p in quad], fill=scenery)
        for i, b in enumerate(scene.bodies):
            x, y = states[t, i, 0] * scale, states[t, i, 1] * scale
            if b.kind == "circle":
                r = b.size[0] * scale
                draw.ellipse([x - r, y - r, x + r, y + r], fill=i + 1)
            else:
                corners = box_corners(x, y, states[t, i, 4], b.size[0] * scale, b.size[1] * scale)
                draw.polygon([tuple(p) for p in corners], fill=i + 1)
        labels[t] = np.asarray(img)
    frames = palette(scene, background).take(labels, axis=0)
    labels[labels == scenery] = 0
    return frames


def run(size: int, episodes: int, frames: int, fps: float = 16.0, substeps: int = 16) -> dict:
    scale = size / WORLD_H
    t_phys = t_ours = t_pil = 0.0
    for scenario in SCENARIOS:
        for seed in range(episodes):
            rng = np.random.default_rng(seed)
            t0 = time.perf_counter()
            setup = BUILDERS[scenario](sample_params(scenario, "id", rng, {}), rng, size / scale, frames, fps)
            states = step(setup, frames, fps, substeps)
            t1 = time.perf_counter()
            render(setup.scene, states, (size, size), scale, (24, 24, 28))
            t2 = time.perf_counter()
            pil_render(setup.scene, states, (size, size), scale, (24, 24, 28))
            t3 = time.perf_counter()
            t_phys, t_ours, t_pil = t_phys + t1 - t0, t_ours + t2 - t1, t_pil + t3 - t2
    n = episodes * len(SCENARIOS)
    total = write = cpu = 0.0
    with tempfile.TemporaryDirectory() as out:
        for scenario in SCENARIOS:
            for seed in range(episodes):
                t0, c0 = time.perf_counter(), time.process_time()
                ep = simulate(scenario, seed, size=size, frames=frames, fps=fps, substeps=substeps)
                t1, cpu = time.perf_counter(), cpu + time.process_time() - c0
                write_episode(ep, out, f"{scenario}_{seed}")
                total, write = total + t1 - t0, write + time.perf_counter() - t1
    return {"episodes_s": n / total, "frames_s": n * frames / total, "frames_cpu_s": n * frames / cpu,
            "physics": t_phys / (t_phys + t_ours),
            "render_fps": n * frames / t_ours, "pil_fps": n * frames / t_pil, "write_episodes_s": n / (total + write)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--episodes", type=int, default=4, help="episodes per scenario")
    ap.add_argument("--frames", type=int, default=33)
    a = ap.parse_args()
    os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})  # one core
    print(f"{len(SCENARIOS)} scenarios x {a.episodes} episodes x {a.frames} frames, one core, substeps 16")
    for size in (64, 256):
        r = run(size, a.episodes, a.frames)
        print(f"{size}x{size}: {r['episodes_s']:.1f} episodes/s, {r['frames_s']:.0f} frames/s end to end "
              f"({r['frames_cpu_s']:.0f} per CPU-second); "
              f"physics {100 * r['physics']:.0f}% / render {100 * (1 - r['physics']):.0f}%; render "
              f"{r['render_fps']:.0f} frames/s vs PIL {r['pil_fps']:.0f} (ratio {r['render_fps'] / r['pil_fps']:.2f}); "
              f"with writing mp4+npz+json {r['write_episodes_s']:.1f} episodes/s")
        if size == 64:
            verdict = "met" if r["frames_s"] >= 2000 else "NOT met"
            print(f"target >= 2000 frames/s at 64x64: {verdict} (ratio {r['frames_s'] / 2000:.2f})")


if __name__ == "__main__":
    main()
