"""Keyword-spotting features of a clip: the digital filterbank (`digital`), the SVM feature
vector Phi (`phi`), the simulated mass-spring network (`massspring`, integrated as
`integration` chooses, on Dask through `distributed`), the log-Mel baseline (`baseline`), and
the on-disk feature cache (`cache`). Imports from `kws.data` only."""
