"""Keyword spotting, in subpackages that import one way: `data` (speech data sets, synthetic
corpus, pre-processing, tasks) -> `features` (digital or mass-spring filterbanks, Phi) ->
`training` (linear classifiers, weight transfer, model folders) -> `evaluation` (test splits,
cross-validation, energy, classifying recordings) -> `tuning` (refit and gradient tuning)."""
