"""Video curation: shot splitting, clip filters, H.264 transcoding, local or Ray runners, resumable output."""

from .filters import FILTERS, Clip, Filter, build_filters
from .pipeline import CurateConfig, curate
from .runners import Stage, run_local, run_ray
from .split import SPLITTERS, Detection, Splitter, build_splitter, detect, evaluate

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
    "curate",
    "detect",
    "evaluate",
    "run_local",
    "run_ray",
]
