"""The runner: one run from a composed config to its run record: the objects (`single_run`),
the closed loop (`loop`), its progress line (`progress`) and the components a sweep worker
keeps between runs (`component_cache`)."""
