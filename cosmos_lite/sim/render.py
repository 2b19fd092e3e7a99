"""Vectorised numpy rasteriser: flat-coloured discs and convex polygons into an id map, then a palette lookup.

Shapes are hard-edged (no anti-aliasing) so every pixel belongs to exactly one object id, which makes the
instance masks exact and lets eval recover masks from colours. Each shape touches only its bounding box.
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


class Canvas:
    """A label image (H, W) of int ids with pixel-centre coordinates, drawn into in painter's order."""

    def __init__(self, height: int, width: int):
        self.labels = np.zeros((height, width), np.uint8)
        self.ys = np.arange(height, dtype=np.float32)[:, None] + 0.5
        self.xs = np.arange(width, dtype=np.float32)[None, :] + 0.5

    def _box(self, x0: float, y0: float, x1: float, y1: float) -> tuple[slice, slice] | None:
        h, w = self.labels.shape
        i0, i1 = max(int(np.floor(y0)), 0), min(int(np.ceil(y1)) + 1, h)
        j0, j1 = max(int(np.floor(x0)), 0), min(int(np.ceil(x1)) + 1, w)
        return (slice(i0, i1), slice(j0, j1)) if i0 < i1 and j0 < j1 else None

    def disc(self, cx: float, cy: float, r: float, value: int) -> None:
        box = self._box(cx - r, cy - r, cx + r, cy + r)
        if box:
            inside = (self.ys[box[0]] - cy) ** 2 + (self.xs[:, box[1]] - cx) ** 2 <= r * r
            self.labels[box][inside] = value

    def polygon(self, pts: np.ndarray, value: int) -> None:
        """Fill a convex polygon (k, 2) of (x, y) pixel coordinates, either winding."""
        box = self._box(*pts.min(0), *pts.max(0))
        if not box:
            return
        nxt = pts[[*range(1, len(pts)), 0]]
        x, y = pts[:, 0, None, None], pts[:, 1, None, None]
        dx, dy = nxt[:, 0, None, None] - x, nxt[:, 1, None, None] - y
        sign = 1.0 if (dx * (nxt[:, 1, None, None] + y)).sum() <= 0 else -1.0  # shoelace: orientation
        side = dx * (self.ys[box[0]] - y) - dy * (self.xs[:, box[1]] - x)  # (k, h, w) edge half-planes
        self.labels[box][(sign * side).min(0) >= 0] = value


def box_corners(x: float, y: float, angle: float, w: float, h: float) -> np.ndarray:
    """Corners (4, 2) of a w x h box centred at (x, y), rotated by angle (radians)."""
    c, s = np.cos(angle), np.sin(angle)
    local = np.array([[-w, -h], [w, -h], [w, h], [-w, h]], np.float64) / 2
    return local @ np.array([[c, s], [-s, c]]) + (x, y)


def rod_corners(p: tuple[float, float], q: tuple[float, float], width: float) -> np.ndarray:
    """A thin quad (4, 2) from point p to point q."""
    p, q = np.asarray(p, np.float64), np.asarray(q, np.float64)
    d = q - p
    n = np.array([-d[1], d[0]]) / max(np.hypot(*d), 1e-9) * width / 2
    return np.stack([p + n, q + n, q - n, p - n])


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
    base = Canvas(h, w)
    for poly in scene.static:
        base.polygon(np.asarray(poly) * scale, scenery)
    labels = np.empty((t_len, h, w), np.uint8)
    canvas = Canvas(h, w)
    for t in range(t_len):
        canvas.labels = labels[t]
        canvas.labels[:] = base.labels
        for pivot, i, width in scene.rods:
            canvas.polygon(rod_corners(np.multiply(pivot, scale), states[t, i, :2] * scale, width * scale), scenery)
        for i, b in enumerate(scene.bodies):
            x, y, angle = states[t, i, 0] * scale, states[t, i, 1] * scale, states[t, i, 4]
            if b.kind == "circle":
                canvas.disc(x, y, b.size[0] * scale, i + 1)
            else:
                canvas.polygon(box_corners(x, y, angle, b.size[0] * scale, b.size[1] * scale), i + 1)
    frames = palette(scene, background).take(labels, axis=0)
    if texture is not None:
        np.copyto(frames, texture[None], where=(labels == 0)[..., None])
    labels[labels == scenery] = 0
    return frames, labels
