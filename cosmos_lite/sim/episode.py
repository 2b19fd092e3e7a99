"""Episodes: simulate a scenario into frames, masks, states and actions; write and read NAME.mp4/.npz/.json."""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import ConfigError, InputError
from ..files import atomic_path, write_text
from ..video import read_frames, write_video
from .captions import caption
from .render import BACKGROUNDS, SCENERY_COLOR, render
from .scenarios import BUILDERS, SCENARIOS, STATE_FIELDS, WORLD_H, sample_params, step


@dataclass
class Episode:
    """One simulated clip. States and actions are in pixels and pixels/s of the rendered frame (y down)."""

    frames: np.ndarray  # (T, H, W, 3) uint8 RGB
    masks: np.ndarray  # (T, H, W) uint8 object ids, 0 = background
    states: np.ndarray  # (T, n_objects, 6) float32: x, y, vx, vy, angle (rad, clockwise on screen), angular vel.
    actions: np.ndarray  # (T, 2) float32: the agent's velocity for frame t -> t+1 (zeros without an agent)
    meta: dict  # scenario, params, split, caption, fps, seed, palette {id: [r, g, b]}, objects, ...


def _size(size: int | tuple[int, int] | list[int]) -> tuple[int, int]:
    h, w = (size, size) if isinstance(size, int) else (int(size[0]), int(size[1]))
    if h < 8 or w < 8:
        raise ConfigError(f"sim size must be at least 8x8 pixels, got {h}x{w}")
    return h, w


def _texture(rng: np.random.Generator, base: tuple[int, int, int], h: int, w: int, scale: float) -> np.ndarray:
    """A static, low-contrast checkerboard with per-tile jitter around the background colour."""
    tile = max(int(round(8 * scale)), 1)
    ty, tx = np.arange(h) // tile, np.arange(w) // tile
    jitter = rng.integers(-5, 6, (ty[-1] + 1, tx[-1] + 1))
    level = 8 * ((ty[:, None] + tx[None, :]) % 2) + jitter[ty][:, tx]
    return np.clip(np.array(base)[None, None] + level[..., None], 0, 255).astype(np.uint8)


def simulate(
    scenario: str,
    seed: int,
    *,
    split: str = "id",
    frames: int = 33,
    fps: float = 16.0,
    size: int | tuple[int, int] = 64,
    substeps: int = 16,
    background: str = "plain",
    actions: np.ndarray | None = None,
    **params,
) -> Episode:
    """Simulate and render one episode, deterministic in (scenario, seed, arguments).

    params fix scenario parameters (a number) or narrow their range ([lo, hi]); the rest are drawn from
    `split` ("id" or "ood"). actions (pusher only): (T, 2) or (T-1, 2) agent velocities in pixels/s.
    """
    if scenario not in BUILDERS:
        raise ConfigError(f"unknown scenario {scenario!r}; choose one of {', '.join(SCENARIOS)}")
    if split not in ("id", "ood"):
        raise ConfigError(f"split must be 'id' or 'ood', got {split!r}")
    if background not in ("plain", "textured"):
        raise ConfigError(f"background must be 'plain' or 'textured', got {background!r}")
    if frames < 1 or fps <= 0 or substeps < 1:
        raise ConfigError(f"need frames >= 1, fps > 0, substeps >= 1; got {frames}, {fps}, {substeps}")
    h, w = _size(size)
    scale = h / WORLD_H
    rng = np.random.default_rng(seed)
    p = sample_params(scenario, split, rng, params)
    setup = BUILDERS[scenario](p, rng, w / scale, frames, fps)
    if actions is not None:
        if setup.actions is None:
            raise ConfigError(f"scenario {scenario!r} has no agent; actions apply to 'pusher' only")
        a = np.asarray(actions, np.float64)
        if a.ndim != 2 or a.shape[1] != 2 or len(a) not in (frames, frames - 1):
            raise ConfigError(f"actions must be ({frames}, 2) or ({frames - 1}, 2), got {a.shape}")
        setup.actions = np.zeros((frames, 2))
        setup.actions[: len(a)] = a / scale
        setup.actions[-1] = 0.0
    states = step(setup, frames, fps, substeps)
    bg = BACKGROUNDS[rng.integers(len(BACKGROUNDS))]
    texture = _texture(rng, bg, h, w, scale) if background == "textured" else None
    video, masks = render(setup.scene, states, (h, w), scale, bg, texture)
    pixel_states = states.copy()
    pixel_states[..., :4] *= scale
    bodies = setup.scene.bodies
    meta = {
        "scenario": scenario,
        "params": p,
        "split": split,
        "caption": caption(scenario, p, setup.scene, states, rng),
        "fps": float(fps),
        "seed": int(seed),
        "frames": int(frames),
        "size": [h, w],
        "substeps": int(substeps),
        "background": background,
        "scale": scale,  # pixels per world unit; params are in world units (the frame is 64 units tall)
        "palette": {0: list(bg), **{i + 1: list(b.rgb) for i, b in enumerate(bodies)}},
        "scenery_color": list(SCENERY_COLOR),
        "objects": [b.name for b in bodies],
        "shapes": [{"kind": b.kind, "size": [s * scale for s in b.size], "color": b.color} for b in bodies],
        "state_fields": STATE_FIELDS,
    }
    act = np.zeros((frames, 2)) if setup.actions is None else setup.actions * scale
    return Episode(video, masks, pixel_states.astype(np.float32), act.astype(np.float32), meta)


def write_episode(ep: Episode, out_dir: str | os.PathLike, name: str, crf: int = 4) -> Path:
    """Write NAME.npz (masks, states, actions), NAME.mp4 (near-lossless 4:4:4 H.264) and NAME.json (meta), each
    atomically, the JSON last so its presence marks a complete episode. Returns the .mp4 path."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    with atomic_path(out / f"{name}.npz") as tmp:  # the temp name ends in .npz, so numpy adds no suffix
        np.savez_compressed(tmp, masks=ep.masks, states=ep.states, actions=ep.actions)
    mp4 = write_video(out / f"{name}.mp4", ep.frames, ep.meta["fps"], crf=crf, pix_fmt="yuv444p")
    write_text(out / f"{name}.json", json.dumps(ep.meta, indent=1))
    return mp4


def episode_stem(path: str | os.PathLike) -> Path:
    """NAME from NAME, NAME.mp4, NAME.npz or NAME.json."""
    p = Path(path)
    return p.with_suffix("") if p.suffix in (".mp4", ".npz", ".json") else p


def read_meta(path: str | os.PathLike) -> dict:
    """An episode's JSON meta with integer palette keys."""
    f = episode_stem(path).with_suffix(".json")
    try:
        meta = json.loads(f.read_text())
    except FileNotFoundError:
        raise InputError(f"{f}: no such episode meta; pass NAME, NAME.mp4 or NAME.json of a written episode") from None
    except json.JSONDecodeError as e:
        raise InputError(f"{f}: not valid JSON ({e}); re-run `cosmos-lite sim` to rewrite it") from None
    meta["palette"] = {int(k): v for k, v in meta.get("palette", {}).items()}
    return meta


def read_arrays(path: str | os.PathLike) -> dict[str, np.ndarray]:
    """An episode's masks, states and actions from NAME.npz."""
    f = episode_stem(path).with_suffix(".npz")
    try:
        with np.load(f, allow_pickle=False) as z:
            return {k: z[k] for k in ("masks", "states", "actions")}
    except (FileNotFoundError, OSError, KeyError, ValueError) as e:
        raise InputError(f"{f}: missing or unreadable episode arrays ({e}); re-run `cosmos-lite sim`") from None


def read_episode(path: str | os.PathLike) -> Episode:
    """Read an episode written by `write_episode` (give NAME or any of its three files)."""
    stem = episode_stem(path)
    meta = read_meta(stem)
    arrays = read_arrays(stem)
    h, w = meta["size"]
    frames = read_frames(stem.with_suffix(".mp4"))[:, :h, :w]  # drop the even-size padding, if any
    return Episode(frames, arrays["masks"], arrays["states"], arrays["actions"], meta)
