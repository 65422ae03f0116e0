"""The run record and its files: `steps.parquet`, `horizons.parquet` and `summary.json`
(`files`), the figures (`figures`, `figure_file`), the stamp under result tables
(`provenance`) and the intervals the tables report (`stats`)."""
