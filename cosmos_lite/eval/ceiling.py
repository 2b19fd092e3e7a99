"""The physical ceiling: what a perfect generative world model would score. Such a model knows the simulator, but
not the parameters the given frames, the caption and the actions leave open (a ball's restitution, gravity, ...);
its samples are re-simulations with those parameters drawn again and kept only if they agree with everything shown.
The physics-alignment score puts copy-last-frame at 0 and this ceiling at 100, as Physics-IQ normalises by the
variance of physical reality itself.
"""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np

from ..core.metrics import nanmean, object_iou_per_frame
from ..sim import SPECS, Episode, simulate

# Parameters a model sees in the first frame (positions and colours come from the seed, so they stay too).
VISIBLE = {
    "bounce": ("radius", "height"),
    "projectile": ("radius",),
    "collision": ("radius1", "radius2"),
    "uniform": ("extent", "box"),
    "ramp": ("slope", "extent"),
    "pendulum": ("length", "angle", "radius"),
    "pusher": ("objects", "extent", "agent_speed"),  # the agent's speed only shapes the given actions
}
AGREEMENT = 0.9  # mean object IoU of the given frames' masks a re-simulation needs to count as consistent


def resimulations(ep: Episode, num_given: int, rng: np.random.Generator, proposals: int
                  ) -> Iterator[tuple[Episode, float]]:
    """`proposals` re-simulations of `ep` and how well each agrees with what a world model is shown: the hidden
    parameters are drawn again from the episode's own split (visible ones, positions and colours stay), the agent gets
    the true actions. Agreement: the mean object IoU of the first `num_given` frames' masks, -1 if the caption
    differs."""
    m = ep.meta
    hidden = {n: p for n, p in SPECS[m["scenario"]].items() if n not in VISIBLE[m["scenario"]]}
    actions = ep.actions if "agent" in m["objects"] else None
    for _ in range(proposals):
        params = {n: p.sample(rng, m["split"]) for n, p in hidden.items()}
        draw = simulate(m["scenario"], m["seed"], split=m["split"], frames=m["frames"], fps=m["fps"],
                        size=tuple(m["size"]), substeps=m["substeps"], background=m["background"], actions=actions,
                        **params)
        same_caption = draw.meta["caption"] == m["caption"]
        yield draw, float(nanmean(object_iou_per_frame(draw.masks[:num_given], ep.masks[:num_given]))) \
            if same_caption else -1.0


def consistent_resimulations(ep: Episode, num_given: int, rng: np.random.Generator, proposals: int,
                             tau: float = AGREEMENT) -> Iterator[Episode]:
    """The re-simulations that agree with all a world model is shown: same caption, mean object IoU of the given
    frames' masks >= tau."""
    return (draw for draw, agreement in resimulations(ep, num_given, rng, proposals) if agreement >= tau)


def ceiling(ep: Episode, num_given: int, proposals: int, rng: np.random.Generator, horizon: int = 16,
            tau: float = AGREEMENT) -> tuple[float, int]:
    """Mean object IoU over the `horizon` frames after `num_given`, averaged over every consistent re-simulation of
    `proposals` draws: a perfect generative model's expected score. Returns (IoU, draws kept); NaN if none was."""
    span = slice(num_given, num_given + horizon)
    ious = [float(nanmean(object_iou_per_frame(d.masks[span], ep.masks[span])))
            for d in consistent_resimulations(ep, num_given, rng, proposals, tau)]
    return (float(np.mean(ious)) if ious else float("nan")), len(ious)


class PerfectModel:
    """A perfect generative model's sample: the first consistent re-simulation; if none of `proposals` is (with many
    given frames the agreement test is strict), the one that agrees best, close to the true parameters. It uses the
    caption and the actions, as the text+actions world model does. None only if no draw keeps the caption."""

    name, conditioned, kind = "perfect model", False, "ceiling"

    def __init__(self, horizon: int, proposals: int, seed: int):
        self.horizon, self.proposals, self.seed = horizon, proposals, seed

    def predict(self, ep: Episode, num_given: int, use_text: bool, use_actions: bool) -> np.ndarray | None:
        rng = np.random.default_rng([self.seed, ep.meta["seed"], num_given])
        best, best_agreement = None, -1.0
        for draw, agreement in resimulations(ep, num_given, rng, self.proposals):
            if agreement > best_agreement:
                best, best_agreement = draw, agreement
            if agreement >= AGREEMENT:
                break
        return None if best is None else best.frames[num_given : num_given + self.horizon]
