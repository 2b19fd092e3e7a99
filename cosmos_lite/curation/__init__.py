"""Video curation: shot splitting, clip filters, H.264 transcoding, local or Ray runners, resumable output."""

from .filters import FILTERS, Clip, Filter, build_filters
from .pipeline import CurateConfig, curate
from .runners import Stage, run_local, run_ray
from .split import SPLITTERS, Detection, Splitter, build_splitter, combine, detect, detect_frames, evaluate

__all__ = [
    "FILTERS",
    "SPLITTERS",
    "Clip",
    "CurateConfig",
    "Detection",
    "Filter",
    "Splitter",
    "Stage",
    "build_filters",
    "build_splitter",
    "combine",
    "curate",
    "detect",
    "detect_frames",
    "evaluate",
    "run_local",
    "run_ray",
]
