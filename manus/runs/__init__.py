"""The `manus` command: each sub-command (`cmd_*`) parses its options (`args`), calls the library
or an experiment (`manus.experiments`), returns a dict and renders it (`text`); figures are drawn
by `figures`, the discovery report by `report`, benchmarks live in `bench`."""
