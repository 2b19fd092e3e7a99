"""Physics simulator: 2D rigid-body scenarios on pymunk with exact masks, states, actions and captions.

`simulate(scenario, seed, **params) -> Episode`; `write_episode` / `read_episode` for NAME.mp4/.npz/.json
(`cosmos_lite.core.dataset.VideoWindows` serves fixed-length training windows of them).
"""

from .episode import Episode, read_episode, simulate, write_episode
from .scenarios import SCENARIOS, SPECS

__all__ = ["SCENARIOS", "SPECS", "Episode", "read_episode", "simulate", "write_episode"]
