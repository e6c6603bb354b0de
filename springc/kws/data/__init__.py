"""Keyword-spotting data: the GSCD-layout reader and its held-out protocols (`dataset`), the
paper's clip pre-processing (`preprocess`), the tasks' clips and classes (`task`), and the
offline synthetic corpus (`synth`, spoken by `voices`). Imports nothing else from `kws`."""
