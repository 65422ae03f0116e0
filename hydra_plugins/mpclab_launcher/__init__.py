"""mpclab's Hydra plugin: the warm-worker pool launcher (see pool_launcher.py)."""
