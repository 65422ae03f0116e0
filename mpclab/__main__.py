"""``python -m mpclab +experiment=NAME [group=choice ...] [key=value ...]``: the command
(:mod:`mpclab.cli.app`)."""

import gc

from mpclab.cli.app import cli, exit_now

# what the imports built lives as long as the process: out of the collector's way, so that
# its full passes while composing and running do not walk it again (0.08 s)
gc.freeze()
exit_now(cli())
