"""Vectorised numpy rasteriser: flat-coloured discs and convex polygons into an id map, then a palette lookup.

Shapes are hard-edged (no anti-aliasing) so every pixel belongs to exactly one object id, which makes the
instance masks exact and lets eval recover masks from colours. Each shape is drawn in all frames at once,
touching only a fixed-size window around it per frame.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

# Flat, mutually distant object colours; the name is what captions say.
COLORS: dict[str, tuple[int, int, int]] = {
    "red": (230, 40, 40),
    "green": (40, 200, 60),
    "blue": (50, 90, 240),
    "yellow": (240, 220, 40),
    "magenta": (220, 50, 220),
    "cyan": (40, 220, 230),
    "orange": (250, 140, 20),
}
AGENT_COLOR = ("white", (245, 245, 245))
BACKGROUNDS = [(24, 24, 28), (36, 30, 26), (20, 32, 30)]
SCENERY_COLOR = (128, 128, 128)


@dataclass(frozen=True)
class Body:
    """A rendered object: a circle (size = (radius,)) or a box (size = (width, height)), in world units."""

    name: str
    kind: str
    size: tuple[float, ...]
    color: str
    rgb: tuple[int, int, int]


@dataclass
class Scene:
    """What to draw besides the bodies: static convex polygons and rods from a fixed pivot to a body's centre."""

    bodies: list[Body]
    static: list[np.ndarray] = field(default_factory=list)  # (k, 2) world-unit vertices
    rods: list[tuple[tuple[float, float], int, float]] = field(default_factory=list)  # (pivot, body index, width)


def _windows(lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """Per-frame pixel indices (T, K) of a fixed-size window covering [lo, hi] in each frame."""
    first = np.floor(lo).astype(np.int64)
    k = int(np.ceil((hi - first).max())) + 1
    return first[:, None] + np.arange(max(k, 1))


def _stamp(labels: np.ndarray, rows: np.ndarray, cols: np.ndarray, inside: np.ndarray, value: int) -> None:
    """Write `value` where inside (T, Kh, Kw) is true, into per-frame windows rows (T, Kh), cols (T, Kw)."""
    h, w = labels.shape[1:]
    inside &= ((rows >= 0) & (rows < h))[:, :, None] & ((cols >= 0) & (cols < w))[:, None, :]
    t, i, j = np.nonzero(inside)
    labels[t, rows[t, i], cols[t, j]] = value


def fill_discs(labels: np.ndarray, centres: np.ndarray, r: float, value: int) -> None:
    """Fill a disc of radius r centred at centres (T, 2) (x, y pixels) in every frame of labels (T, H, W)."""
    x, y = centres[:, 0], centres[:, 1]
    rows, cols = _windows(y - r, y + r), _windows(x - r, x + r)
    dy = rows + 0.5 - y[:, None]
    dx = cols + 0.5 - x[:, None]
    _stamp(labels, rows, cols, dy[:, :, None] ** 2 + dx[:, None, :] ** 2 <= r * r, value)


def fill_polygons(labels: np.ndarray, pts: np.ndarray, value: int) -> None:
    """Fill a convex polygon pts (T, k, 2) (x, y pixels, either winding) in every frame of labels (T, H, W)."""
    rows, cols = _windows(pts[:, :, 1].min(1), pts[:, :, 1].max(1)), _windows(pts[:, :, 0].min(1), pts[:, :, 0].max(1))
    x, y = pts[:, :, 0, None, None], pts[:, :, 1, None, None]
    nxt = np.roll(pts, -1, axis=1)
    dx, dy = nxt[:, :, 0, None, None] - x, nxt[:, :, 1, None, None] - y
    sign = np.where((dx * (nxt[:, :, 1, None, None] + y)).sum(1) <= 0, 1.0, -1.0)  # shoelace: orientation
    side = dx * (rows[:, None, :, None] + 0.5 - y) - dy * (cols[:, None, None, :] + 0.5 - x)  # (T, k, Kh, Kw)
    _stamp(labels, rows, cols, (sign[:, None] * side).min(1) >= 0, value)


def box_corners(x, y, angle, w: float, h: float) -> np.ndarray:
    """Corners (..., 4, 2) of w x h boxes centred at (x, y) and rotated by angle (radians); scalars or (T,) arrays."""
    c, s = np.cos(angle)[..., None], np.sin(angle)[..., None]
    lx, ly = np.array([-w, w, w, -w]) / 2, np.array([-h, -h, h, h]) / 2
    return np.stack([np.asarray(x)[..., None] + lx * c - ly * s, np.asarray(y)[..., None] + lx * s + ly * c], -1)


def rod_corners(p, q, width: float) -> np.ndarray:
    """Thin quads (..., 4, 2) from points p to points q, (2,) or (T, 2) each."""
    p, q = np.asarray(p, np.float64), np.asarray(q, np.float64)
    d = q - p
    n = np.stack([-d[..., 1], d[..., 0]], -1) / np.maximum(np.hypot(d[..., 0], d[..., 1]), 1e-9)[..., None] * width / 2
    p, q = np.broadcast_arrays(p, q)
    return np.stack([p + n, q + n, q - n, p - n], -2)


def palette(scene: Scene, background: tuple[int, int, int]) -> np.ndarray:
    """Lookup table: row 0 background, rows 1..n the bodies, row n+1 the scenery."""
    return np.array([background, *(b.rgb for b in scene.bodies), SCENERY_COLOR], np.uint8)


def render(
    scene: Scene,
    states: np.ndarray,
    size: tuple[int, int],
    scale: float,
    background: tuple[int, int, int],
    texture: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Draw frames (T, H, W, 3) uint8 and masks (T, H, W) uint8 from world-unit states (T, n, >=5).

    scale: pixels per world unit. texture: optional (H, W, 3) uint8 background image (else flat `background`).
    """
    t_len, n = states.shape[:2]
    h, w = size
    scenery = n + 1
    base = np.zeros((1, h, w), np.uint8)
    for poly in scene.static:
        fill_polygons(base, np.asarray(poly, np.float64)[None] * scale, scenery)
    labels = np.repeat(base, t_len, axis=0)
    for pivot, i, width in scene.rods:
        fill_polygons(labels, rod_corners(np.multiply(pivot, scale), states[:, i, :2] * scale, width * scale), scenery)
    for i, b in enumerate(scene.bodies):
        centres = states[:, i, :2] * scale
        if b.kind == "circle":
            fill_discs(labels, centres, b.size[0] * scale, i + 1)
        else:
            corners = box_corners(centres[:, 0], centres[:, 1], states[:, i, 4], b.size[0] * scale, b.size[1] * scale)
            fill_polygons(labels, corners, i + 1)
    frames = palette(scene, background).take(labels, axis=0)
    if texture is not None:
        np.copyto(frames, texture[None], where=(labels == 0)[..., None])
    labels[labels == scenery] = 0
    return frames, labels
