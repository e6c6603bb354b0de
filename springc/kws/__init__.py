"""Keyword spotting: speech data (GSCD reader, offline synthetic corpus, pre-processing),
features from mass-spring or digital filterbanks, linear classifiers and their evaluation."""
