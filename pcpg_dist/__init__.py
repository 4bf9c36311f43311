"""pcpg-dist: play-style-centric policy generation at scale."""

__version__ = "0.1.0"
