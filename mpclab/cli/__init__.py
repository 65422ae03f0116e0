"""The command lines, on the top floor: `python -m mpclab` (`app`, its `--help` and the check
before Hydra acts, `preflight`), and the tools `python -m mpclab.cli.tables` (tables and
figure of run records), `python -m mpclab.cli.merge` (recordings side by side) and
`python -m mpclab.cli.board` (the scheduled controller as a folder for a board)."""
