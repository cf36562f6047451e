"""Parameter sweeps of a scene (``cvj-sim sweep``): spec parsing and expansion
(:mod:`.spec`), execution on local processes or Dask (:mod:`.run`), result files
(:mod:`.results`) and maps (:mod:`.plots`). docs/sweeps.md describes the options."""
