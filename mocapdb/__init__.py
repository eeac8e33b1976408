"""mocapdb: motion capture from ordinary cameras by retrieval in a database of real motion."""

__version__ = "0.1.0"
