"""Evaluating trained keyword spotters: on a test split (`evaluate`), speaker-grouped
cross-validation (`crossval`), accuracy against energy (`sweep`, `energy`), and what a model
hears in recordings (`classify`, `stream`). Imports from `kws.data`, `kws.features` and
`kws.training` only."""
