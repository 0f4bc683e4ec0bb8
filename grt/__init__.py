"""GRT: geometric red-teaming of robot manipulation policies."""

__version__ = "0.1.0"
