"""mpclab's Hydra plugin: the tolerant sweeper (see tolerant_sweeper.py)."""
