"""The bottom floor: errors, what a solver did (`SolveStatus`), signal handling, and small
utilities (lazy imports, quiet native output, append-only JSON-lines files). It imports
nothing else of mpclab."""
