"""The play-style zoo: real games, each played by scripted styles, as pcpg step tables.

One folder per game (``<game>/generator.py`` with a :class:`~benchmarks.zoo.common.Game` named
``GAME``, and ``<game>/README.md`` with its styles and ceiling); ``python -m benchmarks.zoo.build``
writes the tables, ``python -m benchmarks.zoo.evaluate`` scores the clusterers on them.
"""
