"""cosmos-lite: world foundation models for physical AI, small enough for a laptop CPU."""

__version__ = "0.1.0"
